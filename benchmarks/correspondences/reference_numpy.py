"""Training-free PointCLM pipeline in plain numpy / scipy / scikit-learn.

Why: the Rust core must be measured against something. This is a fair, vectorised
implementation of the same training-free pipeline (SPEC section 2, steps 1 and 4-6 with
``S = beta``, plus the refit and duplicate merging the product adds), written the way a
competent Python user would write it. It is the speed and accuracy reference of the
benchmarks; it is not part of the package (it needs scipy and scikit-learn).

Steps: spatial consistency ``beta``; density pruning (paper form); normalised-Laplacian
eigengap for the number of instances; scikit-learn spectral clustering; per-cluster RANSAC on
3-point Kabsch hypotheses; refit on all inliers; merging of duplicate poses.

Run ``python -m benchmarks.correspondences.reference_numpy`` for a 20-scene accuracy and timing
check.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh
from scipy.spatial.distance import cdist
from sklearn.cluster import SpectralClustering

__all__ = ["kabsch", "register_reference"]


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rigid transforms mapping ``src`` onto ``dst``, batched.

    Parameters
    ----------
    src, dst : numpy.ndarray
        (..., K, 3) paired points, K >= 3.

    Returns
    -------
    numpy.ndarray
        (..., 4, 4) poses ``T`` with ``T src ~ dst`` (proper rotations: reflections fixed).
    """
    cs, cd = src.mean(axis=-2, keepdims=True), dst.mean(axis=-2, keepdims=True)
    h = np.swapaxes(src - cs, -1, -2) @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    fix = np.ones(h.shape[:-2] + (3,))
    fix[..., 2] = d
    rot = np.swapaxes(vt, -1, -2) @ (fix[..., :, None] * np.swapaxes(u, -1, -2))
    t = cd[..., 0, :] - np.einsum("...ij,...j->...i", rot, cs[..., 0, :])
    out = np.zeros(h.shape[:-2] + (4, 4))
    out[..., :3, :3] = rot
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def _residuals(poses: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``||R x + t - y||`` for each pose (K, 4, 4) and row: (K, N)."""
    warped = np.einsum("kij,nj->kni", poses[:, :3, :3], x) + poses[:, None, :3, 3]
    return np.linalg.norm(warped - y[None], axis=2)


def _ransac(
    x: np.ndarray, y: np.ndarray, iterations: int, threshold: float, rng: np.random.Generator
) -> np.ndarray:
    """Best 3-point Kabsch hypothesis on one cluster, refit on its inliers."""
    n = len(x)
    trip = np.stack([rng.choice(n, 3, replace=False) for _ in range(iterations)])
    xs, ys = x[trip], y[trip]  # (I, 3, 3)
    pairs = ([0, 0, 1], [1, 2, 2])
    ls = np.linalg.norm(xs[:, pairs[0]] - xs[:, pairs[1]], axis=2)
    lt = np.linalg.norm(ys[:, pairs[0]] - ys[:, pairs[1]], axis=2)
    valid = np.all(np.abs(ls - lt) <= 2 * threshold, axis=1)
    if not valid.any():
        return kabsch(x, y)
    hyps = kabsch(xs[valid], ys[valid])
    inl = _residuals(hyps, x, y) < threshold
    best = inl[np.argmax(inl.sum(axis=1))]
    return kabsch(x[best], y[best]) if best.sum() >= 3 else hyps[np.argmax(inl.sum(axis=1))]


def _merge(
    poses: list[np.ndarray], inliers: list[np.ndarray], x: np.ndarray, threshold: float
) -> list[int]:
    """Indices of the poses kept after dropping duplicates (largest inlier sets first)."""
    order = np.argsort([-m.sum() for m in inliers], kind="stable")
    kept: list[int] = []
    for a in order:
        dup = False
        for b in kept:
            pts = x[inliers[a] | inliers[b]]
            pa = pts @ poses[a][:3, :3].T + poses[a][:3, 3]
            pb = pts @ poses[b][:3, :3].T + poses[b][:3, 3]
            if np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=1))) < threshold:
                dup = True
                break
        if not dup:
            kept.append(int(a))
    return kept


def register_reference(
    correspondences: np.ndarray,
    *,
    sigma_d: float = 0.05,
    tau_s: float = 0.85,
    tau_n: int = 10,
    affinity_sigma: float = 0.1,
    min_cluster_size: int = 10,
    ransac_iterations: int = 50,
    inlier_threshold: float = 0.1,
    seed: int = 0,
) -> list[np.ndarray]:
    """Find the rigid instances in a set of correspondences, training-free.

    Parameters
    ----------
    correspondences : numpy.ndarray
        (N, 6) rows ``(x, y)``.
    sigma_d : float, default 0.05
        Scale of the spatial consistency ``beta_ij = [1 - d_ij^2 / sigma_d^2]_+``.
    tau_s : float, default 0.85
        A pair is consistent if ``beta_ij > tau_s``.
    tau_n : int, default 10
        Row i is kept if it has more than ``tau_n`` consistent partners (itself included).
    affinity_sigma : float, default 0.1
        Scale of the soft affinity used for the eigengap and the clustering.
    min_cluster_size : int, default 10
        Smallest cluster, and smallest final inlier set, that gives an instance.
    ransac_iterations : int, default 50
        3-point hypotheses per cluster.
    inlier_threshold : float, default 0.1
        Residual ``||R x + t - y||`` under which a row is an inlier; also the RMS distance
        under which two poses are duplicates.
    seed : int, default 0
        Seed of RANSAC and of the k-means in the spectral clustering.

    Returns
    -------
    list of numpy.ndarray
        4x4 ``T_target_source`` poses, largest inlier set first.
    """
    corr = np.asarray(correspondences, dtype=np.float64)
    x, y = corr[:, :3], corr[:, 3:]
    rng = np.random.default_rng(seed)

    # a. spatial consistency
    d = np.abs(cdist(x, x) - cdist(y, y))
    beta = np.maximum(0.0, 1.0 - d**2 / sigma_d**2)
    # b. density pruning
    kept = np.flatnonzero((beta > tau_s).sum(axis=1) > tau_n)
    if len(kept) < min_cluster_size:
        return []
    # c. affinity, normalised Laplacian, eigengap
    dk = d[np.ix_(kept, kept)]
    aff = np.maximum(0.0, 1.0 - dk**2 / affinity_sigma**2) + 1e-7
    inv_sqrt = 1.0 / np.sqrt(aff.sum(axis=1))
    lap = np.eye(len(kept)) - inv_sqrt[:, None] * aff * inv_sqrt[None, :]
    lam = eigh(lap, eigvals_only=True)
    n_clusters = int(np.argmax(np.diff(lam))) + 1
    # d. spectral clustering
    if n_clusters == 1:
        labels = np.zeros(len(kept), dtype=np.int64)
    else:
        labels = SpectralClustering(
            n_clusters=n_clusters,
            affinity="precomputed",
            assign_labels="kmeans",
            random_state=seed,
        ).fit_predict(aff)
    # e. RANSAC per cluster
    poses = []
    for c in range(n_clusters):
        members = kept[labels == c]
        if len(members) >= min_cluster_size:
            poses.append(_ransac(x[members], y[members], ransac_iterations, inlier_threshold, rng))
    if not poses:
        return []
    # f. final inliers over all rows, refit, merge duplicates
    inl = _residuals(np.stack(poses), x, y) < inlier_threshold
    refit = [kabsch(x[m], y[m]) if m.sum() >= 3 else p for p, m in zip(poses, inl, strict=True)]
    inl = _residuals(np.stack(refit), x, y) < inlier_threshold
    masks = list(inl)
    keep = _merge(refit, masks, x, inlier_threshold)
    return [refit[k] for k in keep if masks[k].sum() >= min_cluster_size]


def _main() -> None:
    import time

    from pointclm.datasets import make_scenes
    from pointclm.metrics import score_scene, summarize

    scores, times = [], []
    for scene in make_scenes(20, seed=0):
        t0 = time.perf_counter()
        poses = register_reference(scene.correspondences)
        times.append(time.perf_counter() - t0)
        scores.append(score_scene(poses, scene.poses))
    summary = summarize(scores)
    print(summary.table_header())
    print(summary.as_row("reference_numpy"))
    print(f"median {np.median(times):.3f} s per scene (mean {np.mean(times):.3f} s)")


if __name__ == "__main__":
    _main()
