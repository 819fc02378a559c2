"""Realistic training scenes: a bank of seeded range-sensor scenes, and samples drawn from it.

A realistic scene costs about a second to build (FPFH on some 20,000 scene points dominates),
against milliseconds for a synthetic one, so training cannot build them on the fly. The bank
builds each once, from seeds derived from the run's seed, in worker processes, and keeps only
what training reads: the correspondences, their labels, the voxel, and the cues a network may
take besides coordinates (the normals at both ends and the descriptor similarity of each
match, :mod:`pointclm.cues`). It is saved as one
``.npz`` so that a machine without the data folder (a GPU box) trains on exactly the same
scenes.

A sample is a bank scene in the network's units (lengths over ``3 voxels / sigma_d``, the
ratio that ``Config.for_voxel`` and ``pointclm.embedding`` use at inference), each side centred and
turned by its own random rotation (its normals with it): spatial consistency and labels are
unchanged, and the network cannot learn a scene's frame instead of its geometry.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..cues import check_inputs, pack, similarity
from ..embedding import network_units
from ..io.arrays import read_npz_members
from ..io.files import read_checked
from ..point_clouds import scaled_config
from .config import VAL_SHAPES

__all__ = [
    "SceneBank",
    "bank_cues",
    "bank_scene",
    "near_misses",
    "realistic_sample",
    "scene_seed",
    "score_bank",
]


def scene_seed(base: int, model_index: int, k: int) -> int:
    """Seed of the k-th bank scene of a model: disjoint from the benchmark's seeds 0..n."""
    ss = np.random.SeedSequence([base, 5, model_index, k])
    return int(ss.generate_state(1, np.uint64)[0] % 2**62)


def bank_scene(model: str, seed: int, data_dir: str | None) -> Any:
    """The realistic scene of `model` a bank holds for `seed`, clouds included."""
    from ..datasets.scenes import DEFAULT_CLUTTER, SceneParams, make_realistic_scene

    # Clutter never includes a model registered in validation or test, so no split leaks.
    held_out = (*VAL_SHAPES, "stanford/bunny", "bunny")
    clutter = tuple(m for m in DEFAULT_CLUTTER if m not in held_out)
    return make_realistic_scene(
        seed, SceneParams(model=model, data_dir=data_dir, clutter_models=clutter)
    )


def _build_one(job: tuple[str, int, str | None]) -> tuple[Any, ...]:
    scene = bank_scene(*job)
    return (
        scene.correspondences.astype(np.float32),
        scene.labels.astype(np.int16),
        scene.voxel_size,
        scene.diameter,
        scene.poses,
        scene.pair_normals.astype(np.float32),
        similarity(scene.match_distance).astype(np.float32),
    )


@dataclass
class SceneBank:
    """Realistic scenes reduced to correspondences, labels, voxel, diameter and true poses
    (validation scores with them), grouped by model, with each row's cues: the normals at
    both ends and the similarity of its match (None in banks saved before they were kept)."""

    correspondences: list[np.ndarray]
    labels: list[np.ndarray]
    voxels: np.ndarray
    diameters: np.ndarray
    poses: list[np.ndarray]
    models: list[str]
    model_of: np.ndarray
    normals: list[np.ndarray] | None = None
    similarities: list[np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.correspondences)

    @classmethod
    def build(
        cls,
        models: Sequence[str],
        scenes_per_model: int | Sequence[int],
        seed: int,
        data_dir: str | None = None,
        workers: int | None = None,
        progress: bool = False,
    ) -> SceneBank:
        """`scenes_per_model` scenes of each model (one count, or one per model), built in
        `workers` processes (default: every core)."""
        counts = (
            [int(scenes_per_model)] * len(models)
            if isinstance(scenes_per_model, int)
            else [int(c) for c in scenes_per_model]
        )
        if len(counts) != len(models):
            raise ValueError(f"need one scene count per model: {len(models)} models")
        jobs = [
            (m, scene_seed(seed, i, k), data_dir)
            for i, m in enumerate(models)
            for k in range(counts[i])
        ]
        workers = workers or os.cpu_count() or 1
        if workers > 1:
            import multiprocessing as mp

            with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn")) as pool:
                results = pool.map(_build_one, jobs, chunksize=4)
                built = _collect(results, len(jobs), progress)
        else:
            built = _collect(map(_build_one, jobs), len(jobs), progress)
        return cls(
            [b[0] for b in built],
            [b[1] for b in built],
            np.array([b[2] for b in built]),
            np.array([b[3] for b in built]),
            [b[4] for b in built],
            list(models),
            np.repeat(np.arange(len(models)), counts),
            [b[5] for b in built],
            [b[6] for b in built],
        )

    @classmethod
    def concat(cls, banks: Sequence[SceneBank]) -> SceneBank:
        """Banks of the same model list built in parts (e.g. some models' counts 0 in each)
        joined in order: the bank one build of all the parts would give."""
        if not banks or any(b.models != banks[0].models for b in banks):
            raise ValueError("need at least one bank, all built over the same model list")
        with_cues = all(b.normals is not None and b.similarities is not None for b in banks)
        return cls(
            [c for b in banks for c in b.correspondences],
            [y for b in banks for y in b.labels],
            np.concatenate([b.voxels for b in banks]),
            np.concatenate([b.diameters for b in banks]),
            [p for b in banks for p in b.poses],
            list(banks[0].models),
            np.concatenate([b.model_of for b in banks]),
            [n for b in banks for n in b.normals or []] if with_cues else None,
            [s for b in banks for s in b.similarities or []] if with_cues else None,
        )

    @classmethod
    def load(cls, path: str | Path) -> SceneBank:
        """A bank saved by :meth:`save`; read without pickle, every size checked.

        Raises FileNotFoundError for a missing file, ValueError for anything else wrong."""
        file, raw = read_checked(path, "scene bank")
        try:
            z, _ = read_npz_members(raw, None, kinds="biufU")
            return cls._from_arrays(z)
        except (ValueError, KeyError) as e:
            raise ValueError(f"{file}: not a scene bank ({e})") from None

    @classmethod
    def _from_arrays(cls, z: dict[str, np.ndarray]) -> SceneBank:
        counts, instances = z["counts"], z["instances"]
        corr, labels, poses = z["correspondences"], z["labels"], z["poses"]
        n = len(counts)
        ok = (
            counts.ndim == 1
            and instances.shape == (n,)
            and counts.dtype.kind in "iu"
            and instances.dtype.kind in "iu"
            and (counts >= 0).all()
            and (instances >= 0).all()
            and corr.ndim == 2
            and corr.shape[1] == 6
            and int(counts.sum()) == len(corr)
            and labels.shape == (len(corr),)
            and poses.ndim == 3
            and poses.shape[1:] == (4, 4)
            and int(instances.sum()) == len(poses)
            and all(z[k].shape == (n,) for k in ("voxels", "diameters", "model_of"))
            and z["models"].ndim == 1
            and z["model_of"].dtype.kind in "iu"
            and (n == 0 or (0 <= z["model_of"].min() and z["model_of"].max() < len(z["models"])))
        )
        if not ok:
            raise ValueError("its arrays have inconsistent shapes")
        split = np.cumsum(counts)[:-1]
        pose_split = np.cumsum(instances)[:-1]
        normals = sims = None
        if "normals" in z and "similarities" in z:
            if z["normals"].shape != (len(corr), 6) or z["similarities"].shape != (len(corr),):
                raise ValueError("its cues do not match its correspondences")
            normals = list(np.split(z["normals"].astype(np.float32), split))
            sims = list(np.split(z["similarities"].astype(np.float32), split))
        return cls(
            list(np.split(corr, split)),
            list(np.split(labels, split)),
            z["voxels"],
            z["diameters"],
            list(np.split(poses, pose_split)),
            [str(m) for m in z["models"]],
            z["model_of"],
            normals,
            sims,
        )

    def save(self, path: str | Path) -> None:
        # Cues in half precision: a normal to 1e-3 is finer than FPFH's estimate of it, and
        # the bank must fit on a GPU machine that cannot build it.
        cues: dict[str, Any] = (
            {}
            if self.normals is None or self.similarities is None
            else {
                "normals": np.concatenate(self.normals).astype(np.float16),
                "similarities": np.concatenate(self.similarities).astype(np.float16),
            }
        )
        np.savez_compressed(
            path,
            **cues,
            correspondences=np.concatenate(self.correspondences),
            labels=np.concatenate(self.labels),
            counts=np.array([len(c) for c in self.correspondences]),
            voxels=self.voxels,
            diameters=self.diameters,
            poses=np.concatenate(self.poses),
            instances=np.array([len(p) for p in self.poses]),
            models=np.array(self.models),
            model_of=self.model_of,
        )


def _collect(results: object, total: int, progress: bool) -> list:
    from tqdm import tqdm

    return list(tqdm(results, total=total, desc="scenes", disable=not progress))  # type: ignore[call-overload]


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def near_misses(
    corr: np.ndarray, labels: np.ndarray, poses: np.ndarray, radius: float
) -> np.ndarray:
    """Outliers that some instance's true pose maps within `radius` of their scene point."""
    if len(poses) == 0:
        return np.zeros(len(labels), dtype=bool)
    moved = np.einsum("kij,nj->kni", poses[:, :3, :3], corr[:, :3]) + poses[:, None, :3, 3]
    err = np.linalg.norm(moved - corr[None, :, 3:], axis=2).min(axis=0)
    return (labels < 0) & (err < radius)


def realistic_sample(
    bank: SceneBank,
    rng: np.random.Generator,
    sigma_d: float,
    max_correspondences: int,
    ignore_voxels: float = 0.0,
    inputs: Sequence[str] = (),
) -> tuple[np.ndarray, np.ndarray]:
    """One scene of the bank in network units, augmented: (N, C) float32 rows packed as
    :func:`pointclm.cues.pack` packs them for `inputs` (C = 6 without cues), (N,) int64.

    Outliers within `ignore_voxels` of an instance under its true pose (beyond the label's 2
    voxels: near misses, as many as the inliers with FPFH) are labelled `IGNORE`: the pose
    stage counts them as support, so the loss should neither pull nor push them."""
    from ..model.loss import IGNORE

    inputs = check_inputs(inputs)
    i = int(rng.integers(len(bank)))
    corr = bank.correspondences[i].astype(np.float64)
    labels = bank.labels[i].astype(np.int64)
    normals, sims = bank_cues(bank, i, inputs)
    if ignore_voxels > 0:
        near = near_misses(corr, labels, bank.poses[i], ignore_voxels * float(bank.voxels[i]))
        labels[near] = IGNORE
    if len(corr) > max_correspondences:
        keep = np.sort(rng.choice(len(corr), max_correspondences, replace=False))
        corr, labels = corr[keep], labels[keep]
        normals = None if normals is None else normals[keep]
        sims = None if sims is None else sims[keep]
    x = network_units(corr, scaled_config(float(bank.voxels[i])).sigma_d, sigma_d)
    rs, rt = _random_rotation(rng), _random_rotation(rng)
    x = np.hstack([x[:, :3] @ rs.T, x[:, 3:] @ rt.T])
    if normals is not None:
        normals = np.hstack([normals[:, :3] @ rs.T, normals[:, 3:] @ rt.T])
    return pack(x, inputs, normals, sims).astype(np.float32), labels


def bank_cues(
    bank: SceneBank, i: int, inputs: Sequence[str]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Scene `i`'s normals and similarities where `inputs` name them (float64), else None;
    ValueError when the bank lacks a cue the network takes."""
    if inputs and (bank.normals is None or bank.similarities is None):
        raise ValueError(
            f"the network takes {', '.join(inputs)}, but this scene bank holds no cues "
            "(saved before they were kept): build it again"
        )
    normals = bank.normals[i].astype(np.float64) if "normals" in inputs else None  # type: ignore[index]
    sims = bank.similarities[i].astype(np.float64) if "similarity" in inputs else None  # type: ignore[index]
    return normals, sims


def score_bank(
    bank: SceneBank,
    features: Sequence[np.ndarray | None],
    config: Any,
    normals: Sequence[np.ndarray | None] | None = None,
) -> dict:
    """Paper MR/MP/MF and strict F1 over the bank's scenes, registered in real units as
    `register_point_clouds(refine=False)` runs them (a bank keeps no clouds to refine on):
    `config` (synthetic units, default `Config()`) scaled to each scene's voxel, the TE
    threshold 10 % of the model's diagonal; each scene's `normals` (if given) go to the
    pipeline."""
    from ..metrics import score_scene, summarize
    from ..registration import register

    scores = []
    for i in range(len(bank)):
        corr = bank.correspondences[i].astype(np.float64)
        cfg = scaled_config(float(bank.voxels[i]), config)
        n = None if normals is None else normals[i]
        r = register(corr, features[i], cfg, seed=0, normals=n)
        scores.append(
            score_scene(r.transformations, bank.poses[i], max_translation=0.1 * bank.diameters[i])
        )
    return summarize(scores).as_dict()
