"""Single-instance robust solvers run sequentially: the multi-instance baselines pointclm is
compared with on the same correspondences.

Each loop fits one pose, removes the correspondences it explains, and fits again, until a fit
explains fewer than ``min_inliers`` correspondences, the solver gives up, or ``max_instances``
poses are found. Both need optional packages (``pip install ".[bench]"``, or
``pip install kiss-matcher open3d-cpu``); they are imported on first use so that importing
this module costs nothing. A benchmark checks for them before it starts
(:func:`require_peers`): a missing peer is named up front, not after the first scenes ran.

- :func:`sequential_kiss`: KISS-Matcher's ``prune_and_solve`` (graph-theoretic outlier pruning
  then a GNC-TLS-style solver), the strongest single-instance solver on low-inlier
  correspondences (SPEC section 5).
- :func:`sequential_ransac`: Open3D's ``registration_ransac_based_on_correspondence``
  (3-point samples), seeded through ``open3d.utility.random.seed`` so reruns agree.
- :func:`sequential_ransac_fpfh`: Open3D's ``registration_ransac_based_on_feature_matching``
  on the clouds themselves (its own FPFH matches), then ICP, in a loop (the bins' peer).
"""

from __future__ import annotations

import importlib.util
from collections.abc import Mapping

import numpy as np

__all__ = [
    "PEER_PACKAGES",
    "missing_peers",
    "require_peers",
    "residuals",
    "sequential_kiss",
    "sequential_ransac",
]

#: The module each peer imports, and the pip package that provides it (the ``[bench]`` extra
#: of pyproject.toml installs them where PyPI has them).
PEER_PACKAGES = {"kiss_matcher": "kiss-matcher", "open3d": "open3d-cpu"}


def missing_peers(methods: Mapping[str, str]) -> dict[str, str]:
    """Of `methods` (a method's name -> the module it imports), those whose module cannot be
    imported here, with that module. Nothing is imported (only looked up)."""
    return {
        method: module
        for method, module in methods.items()
        if importlib.util.find_spec(module) is None
    }


def require_peers(methods: Mapping[str, str], skip_flag: str) -> None:
    """Stop with a message naming every method of `methods` whose module is missing, the
    package to install and `skip_flag`, the option that leaves them out; nothing if none
    is missing. Called before any scene is built, so a run never fails half-way."""
    missing = missing_peers(methods)
    if not missing:
        return
    wanted = sorted({PEER_PACKAGES.get(m, m) for m in missing.values()})
    raise SystemExit(
        "missing peer(s): "
        + "; ".join(f"{method} needs the module {module!r}" for method, module in missing.items())
        + f". Install them with `pip install '.[bench]'` (or `pip install {' '.join(wanted)}`),"
        f" or pass {skip_flag} to run without them."
    )


def residuals(corr: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``||R x + t - y||`` per correspondence row ``(x | y)``."""
    return np.linalg.norm(corr[:, :3] @ pose[:3, :3].T + pose[:3, 3] - corr[:, 3:], axis=1)


def _sequential(corr: np.ndarray, threshold: float, min_inliers: int, max_instances: int, fit):
    corr = np.ascontiguousarray(corr, dtype=np.float64)
    remaining = np.arange(len(corr))
    poses: list[np.ndarray] = []
    while len(poses) < max_instances and len(remaining) >= max(3, min_inliers):
        pose = fit(corr[remaining])
        if pose is None:
            break
        inl = residuals(corr[remaining], pose) < threshold
        if inl.sum() < min_inliers:
            break
        poses.append(pose)
        remaining = remaining[~inl]
    return poses


def sequential_kiss(
    corr: np.ndarray, noise_bound: float, min_inliers: int, max_instances: int = 10
) -> list[np.ndarray]:
    """KISS-Matcher in a loop. ``noise_bound`` is the inlier radius (KISS-Matcher's
    ``voxel_size`` argument, from which it derives its pruning and solver noise bounds)."""
    import kiss_matcher

    def fit(c: np.ndarray) -> np.ndarray | None:
        solver = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(float(noise_bound)))
        src = [p.reshape(3, 1) for p in c[:, :3].astype(np.float32)]
        tgt = [p.reshape(3, 1) for p in c[:, 3:].astype(np.float32)]
        sol = solver.prune_and_solve(src, tgt)
        if not sol.valid:
            return None
        pose = np.eye(4)
        pose[:3, :3] = np.asarray(sol.rotation, dtype=np.float64)
        pose[:3, 3] = np.asarray(sol.translation, dtype=np.float64).ravel()
        return pose

    return _sequential(corr, noise_bound, min_inliers, max_instances, fit)


def sequential_ransac(
    corr: np.ndarray,
    threshold: float,
    min_inliers: int,
    iterations: int = 20_000,
    max_instances: int = 10,
    seed: int = 0,
) -> list[np.ndarray]:
    """Open3D's correspondence RANSAC in a loop (``iterations`` 3-point samples per fit,
    confidence 0.999), seeded for repeatable runs."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)

    def fit(c: np.ndarray) -> np.ndarray:
        src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(c[:, :3]))
        tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(c[:, 3:]))
        pairs = np.repeat(np.arange(len(c))[:, None], 2, axis=1).astype(np.int32)
        res = reg.registration_ransac_based_on_correspondence(
            src,
            tgt,
            o3d.utility.Vector2iVector(pairs),
            threshold,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [],
            reg.RANSACConvergenceCriteria(iterations, 0.999),
        )
        return np.asarray(res.transformation)

    return _sequential(corr, threshold, min_inliers, max_instances, fit)


def _o3d_cloud(points: np.ndarray, voxel: float, towards: np.ndarray | None):
    import open3d as o3d

    reg = o3d.pipelines.registration
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    if towards is None:
        # The model's normals point away from its centroid.
        pc.orient_normals_towards_camera_location(np.asarray(pc.points).mean(0))
        pc.normals = o3d.utility.Vector3dVector(-np.asarray(pc.normals))
    else:
        pc.orient_normals_towards_camera_location(towards)
    feat = reg.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )
    return pc, np.asarray(feat.data)


def sequential_ransac_fpfh(
    model: np.ndarray,
    scan: np.ndarray,
    voxel: float,
    sensor: np.ndarray,
    max_fits: int,
    min_fitness: float = 0.2,
    seed: int = 0,
) -> list[np.ndarray]:
    """Open3D's feature-matching RANSAC on clouds, in a loop: the loop a user writes with
    Open3D alone (`benchmarks.bins.run`'s peer). Both clouds are downsampled at `voxel`, with
    normals (the scan's towards `sensor`) and FPFH at pointclm's radii; each fit is refined by
    ICP and kept while it explains at least `min_fitness` of the model, and the scan points it
    explains are removed before the next, at most `max_fits` fits."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    src, fsrc = _o3d_cloud(model, voxel, None)
    tgt, ftgt = _o3d_cloud(scan, voxel, sensor)
    src_pts = np.asarray(src.points)
    tgt_pts = np.asarray(tgt.points)
    source_feature = reg.Feature()
    source_feature.data = fsrc
    left = np.arange(len(tgt_pts))
    dist = 1.5 * voxel
    poses: list[np.ndarray] = []
    while len(poses) < max_fits and len(left) >= 3:
        sub = tgt.select_by_index(left.tolist())
        feature = reg.Feature()
        feature.data = np.ascontiguousarray(ftgt[:, left])
        res = reg.registration_ransac_based_on_feature_matching(
            src,
            sub,
            source_feature,
            feature,
            True,
            dist,
            reg.TransformationEstimationPointToPoint(False),
            3,
            [
                reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
                reg.CorrespondenceCheckerBasedOnDistance(dist),
            ],
            reg.RANSACConvergenceCriteria(100_000, 0.999),
        )
        icp = reg.registration_icp(
            src, sub, dist, res.transformation, reg.TransformationEstimationPointToPoint()
        )
        if icp.fitness < min_fitness:
            break
        pose = np.asarray(icp.transformation).copy()
        poses.append(pose)
        near, _ = cKDTree(src_pts @ pose[:3, :3].T + pose[:3, 3]).query(
            tgt_pts[left], distance_upper_bound=dist
        )
        left = left[~np.isfinite(near)]
    return poses
