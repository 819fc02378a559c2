"""A small scan of posed copies of the packaged bunny, for the tests of what surrounds a result
(Open3D objects, pose forms, BOP CSV, JSON schema): fast, and with no data folder."""

from __future__ import annotations

import numpy as np
from pointclm.datasets import load_shape
from scipy.spatial.transform import Rotation


def posed_copies(n_copies: int = 2, cut: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model (3000 points), a scan of `n_copies` copies two diagonals apart, and their
    (n_copies, 4, 4) true poses. `cut`: the first copy keeps only its points with x above
    its centre's, so the model is not wholly explained there (fitness below 1)."""
    model = load_shape("bunny", 3000)
    d = float(np.linalg.norm(np.ptp(model, axis=0)))
    poses, parts = [], []
    for k in range(n_copies):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=k).as_matrix()
        T[:3, 3] = [2 * d * k, 0.3 * d * k, 0.0]
        copy = model @ T[:3, :3].T + T[:3, 3]
        if cut and k == 0:
            copy = copy[copy[:, 0] > T[0, 3] - 0.15 * d]
        poses.append(T)
        parts.append(copy)
    return model, np.vstack(parts), np.stack(poses)
