"""Type stubs for the compiled `pointclm._core` extension (checked with mypy.stubtest).

Its errors are the classes of :mod:`pointclm.errors` (defined there in Python and raised by
the extension), MemoryError and KeyboardInterrupt; it defines no exception class itself.
"""

import os
from collections.abc import Callable
from typing import Any, final

import numpy as np
import numpy.typing as npt

__all__ = [
    "__version__",
    "MAX_ROTATION_DEVIATION",
    "SIGMA_D_VOXELS",
    "INLIER_VOXELS",
    "MAX_TERRACED_SHARE",
    "cloud_base_config",
    "scan_scales",
    "Instance",
    "Network",
    "PpfModel",
    "RefineContext",
    "RegistrationResult",
    "config_schema",
    "default_config",
    "density_counts",
    "eigh",
    "kabsch",
    "normalized_laplacian",
    "register",
    "register_batch",
    "spatial_consistency",
    "spectral_clustering",
    "validate_config",
    "scene_rules_schema",
    "refine_params_schema",
    "validate_scene_rules",
    "unexplained_points",
    "loose_poses",
    "fit_tightness",
    "stability_factor",
    "register_scan",
    "symmetry_group",
    "detect_symmetries",
    "canonical_poses",
    "resolve_model_symmetry",
    "flip_turns",
    "quarter_turns",
    "bounding_diagonal",
    "default_voxel_size",
    "voxel_downsample",
    "isolated_points",
    "estimate_normals",
    "terraced_share",
    "compute_fpfh",
    "describe",
    "learned_descriptors",
    "match_features",
    "nearest_descriptors",
    "nearest_neighbours",
    "judge_jointly",
    "refine_poses",
    "looks_like_one_view",
    "estimate_sensor",
    "edge_on_scores",
]

__version__: str
#: How far from a rotation a 3x3 block may be (``||R^T R - I||_F``) and still be taken for one
#: (and replaced by the nearest rotation): rounding of poses written with 6-8 digits.
MAX_ROTATION_DEVIATION: float
#: Config.sigma_d on clouds, in voxels (``pointclm::scene::SIGMA_D_VOXELS``).
SIGMA_D_VOXELS: float
#: Config()'s inlier threshold on clouds, in voxels (``pointclm::scene::INLIER_VOXELS``).
INLIER_VOXELS: float
#: Above this terraced share the scan's normals are fitted within twice the radius
#: (``pointclm::pointcloud::terraces::MAX_TERRACED_SHARE``).
MAX_TERRACED_SHARE: float

@final
class Instance:
    """One registered copy of the source in the target."""

    @property
    def transformation(self) -> npt.NDArray[np.float64]: ...
    @property
    def inliers(self) -> npt.NDArray[np.int64]: ...
    @property
    def correspondence_set(self) -> npt.NDArray[np.int64]: ...
    @property
    def fitness(self) -> float: ...
    @property
    def inlier_rmse(self) -> float: ...
    def __len__(self) -> int: ...

@final
class RegistrationResult:
    """Every instance found in one scene, plus a label per correspondence."""

    @property
    def instances(self) -> list[Instance]: ...
    @property
    def transformations(self) -> npt.NDArray[np.float64]: ...
    @property
    def labels(self) -> npt.NDArray[np.int64]: ...
    @property
    def kept(self) -> npt.NDArray[np.int64]: ...
    @property
    def n_clusters(self) -> int: ...
    @property
    def timings(self) -> dict[str, float]: ...
    def __len__(self) -> int: ...
    def __getitem__(self, index: int, /) -> Instance: ...

@final
class RefineContext:
    """What `refine_poses` derives from the clouds alone, built once for many calls against
    one scan."""

    def __new__(
        cls,
        source: npt.NDArray[np.float64],
        target: npt.NDArray[np.float64],
        voxel_size: float,
        viewpoint: tuple[float, float, float] | None,
        target_normals: npt.NDArray[np.float64] | None = None,
        num_threads: int | None = None,
    ) -> RefineContext: ...
    def refine(
        self,
        transformations: npt.NDArray[np.float64],
        icp: bool,
        rules: dict[str, Any] | None = None,
        num_threads: int | None = None,
    ) -> tuple[
        npt.NDArray[np.float64],
        list[npt.NDArray[np.float64]],
        npt.NDArray[np.int64],
        bool,
        list[tuple[int, str, float, float]],
        tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]], npt.NDArray[np.int64]],
    ]: ...
    def near_shares(
        self,
        transformations: npt.NDArray[np.float64],
        points: npt.NDArray[np.float64],
        radius: float,
        num_threads: int | None = None,
    ) -> npt.NDArray[np.float64]: ...
    def pose_stability(
        self,
        transformations: npt.NDArray[np.float64],
        source_normals: npt.NDArray[np.float64],
        radius: float,
        num_threads: int | None = None,
    ) -> npt.NDArray[np.float64]: ...
    def pose_covariances(
        self,
        transformations: npt.NDArray[np.float64],
        radius: float,
        num_threads: int | None = None,
    ) -> tuple[
        npt.NDArray[np.float64],
        npt.NDArray[np.float64],
        npt.NDArray[np.int64],
        npt.NDArray[np.float64],
    ]: ...
    def near_mask(
        self, points: npt.NDArray[np.float64], radius: float, num_threads: int | None = None
    ) -> npt.NDArray[np.bool_]: ...
    def explained_scan_points(
        self, transformation: npt.NDArray[np.float64], radius: float
    ) -> npt.NDArray[np.int64]: ...
    def not_duplicates(
        self,
        transformations: npt.NDArray[np.float64],
        radius: float,
        max_shared: float,
        taken: npt.NDArray[np.bool_],
        num_threads: int | None = None,
    ) -> tuple[list[int], npt.NDArray[np.bool_]]: ...
    def resolve_flips(
        self,
        transformations: npt.NDArray[np.float64],
        columns: list[npt.NDArray[np.float64]],
        origin: npt.NDArray[np.int64],
        by_visibility: bool,
        rotations: npt.NDArray[np.float64],
        scene: dict[str, Any] | None = None,
        num_threads: int | None = None,
    ) -> tuple[
        tuple[
            npt.NDArray[np.float64],
            list[npt.NDArray[np.float64]],
            npt.NDArray[np.int64],
            bool,
            list[tuple[int, str, float, float]],
        ],
        npt.NDArray[np.int64],
    ]: ...

@final
class PpfModel:
    """A model's point pair features tabled for voting (Drost et al., CVPR 2010): pose
    hypotheses of the copies in a scan. The model is sampled one point per cube of a
    twentieth of `diameter`; pairs farther apart than `diameter` are ignored. `normals` must
    face outwards, as the scan's face its sensor."""

    def __new__(
        cls,
        points: npt.NDArray[np.float64],
        normals: npt.NDArray[np.float64],
        diameter: float,
        max_poses: int = 200,
        reference_stride: int = 5,
    ) -> PpfModel: ...
    def __len__(self) -> int: ...
    def poses(
        self,
        points: npt.NDArray[np.float64],
        normals: npt.NDArray[np.float64],
        rows: npt.ArrayLike,
        offset: int = 0,
        num_threads: int | None = None,
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
        """Poses `T_scan_model` (K, 4, 4) voted by the scan points `rows` (every
        `reference_stride`-th sampled point from `offset` a reference), and their votes,
        most voted first."""
        ...

@final
class Network:
    """A trained SCNonlocal embedding network (a ``.safetensors`` file and the ``.json``
    beside it), evaluated in Rust."""

    def __new__(cls, path: str | os.PathLike[str]) -> Network: ...
    @property
    def path(self) -> os.PathLike[str]: ...
    @property
    def depth(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def sigma_d(self) -> float: ...
    @property
    def inputs(self) -> tuple[str, ...]: ...
    @property
    def normal_tolerance(self) -> float: ...
    @property
    def normalization(self) -> str: ...
    def recommended_config(self) -> dict[str, Any]: ...
    def embed(
        self,
        correspondences: npt.NDArray[np.float64],
        normals: npt.NDArray[np.float64] | None = None,
        similarity: npt.NDArray[np.float64] | None = None,
        num_threads: int | None = None,
    ) -> npt.NDArray[np.float64]: ...

def register(
    correspondences: npt.NDArray[np.float64],
    features: npt.NDArray[np.float64] | None = None,
    config: dict[str, Any] | None = None,
    seed: int = 0,
    num_threads: int | None = None,
    network: Network | None = None,
) -> RegistrationResult: ...
def register_batch(
    scenes: list[tuple[npt.NDArray[np.float64], npt.NDArray[np.float64] | None]],
    config: dict[str, Any] | None = None,
    seed: int = 0,
    num_threads: int | None = None,
    network: Network | None = None,
) -> list[RegistrationResult]: ...
def spatial_consistency(
    correspondences: npt.NDArray[np.float64], sigma_d: float
) -> npt.NDArray[np.float64]: ...
def density_counts(
    correspondences: npt.NDArray[np.float64],
    features: npt.NDArray[np.float64] | None = None,
    config: dict[str, Any] | None = None,
    num_threads: int | None = None,
) -> npt.NDArray[np.int64]: ...
def normalized_laplacian(affinity: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
def eigh(
    matrix: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
def spectral_clustering(
    affinity: npt.NDArray[np.float64],
    n_clusters: int | None = None,
    max_clusters: int | None = None,
    assignment: str = "kmeans",
    restarts: int = 10,
    seed: int = 0,
) -> tuple[npt.NDArray[np.int64], int, npt.NDArray[np.float64]]: ...
def kabsch(
    source: npt.NDArray[np.float64], target: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]: ...
def config_schema() -> list[dict[str, Any]]: ...
def default_config() -> dict[str, Any]: ...
def validate_config(config: dict[str, Any]) -> None: ...
def scene_rules_schema() -> list[dict[str, Any]]: ...
def refine_params_schema() -> list[dict[str, Any]]: ...
def validate_scene_rules(params: dict[str, Any]) -> None: ...
def unexplained_points(
    target: npt.NDArray[np.float64],
    source: npt.NDArray[np.float64],
    transformations: npt.NDArray[np.float64],
    radius: float,
    num_threads: int | None = None,
) -> npt.NDArray[np.bool_]: ...
def loose_poses(
    visible_rmse: npt.NDArray[np.float64], max_relative: float, min_poses: int
) -> npt.NDArray[np.bool_]: ...
def fit_tightness(
    visible_rmse: npt.NDArray[np.float64], min_poses: int
) -> npt.NDArray[np.float64]: ...
def flip_turns(
    points: npt.NDArray[np.float64], voxel_size: float, min_change: float
) -> npt.NDArray[np.float64]: ...
def quarter_turns(
    points: npt.NDArray[np.float64], voxel_size: float, min_change: float, max_change: float
) -> npt.NDArray[np.float64]: ...
def register_scan(
    model: npt.NDArray[np.float64],
    scan: npt.NDArray[np.float64],
    voxel_size: float | None = None,
    viewpoint: tuple[float, float, float] | None = None,
    seed: int = 0,
    peel: bool = True,
    heap: bool | None = None,
    heap_rank: int = 64,
    flips: bool = True,
    top_k: int = 10_000,
    mutual: bool = True,
    n_samples: int | None = 1000,
    config: dict[str, Any] | None = None,
    scene: dict[str, Any] | None = None,
    num_threads: int | None = None,
    pair_normals: bool = False,
    embed: Callable[..., npt.NDArray[np.float64]] | None = None,
    embed_inputs: list[str] = ...,
    refine: bool = True,
    k: int = 1,
    mutual_window: float | str | None = None,
    symmetry: str | dict[str, npt.NDArray[np.float64]] | None = None,
    proposals: str = "auto",
    descriptor: str | os.PathLike[str] | None = None,
    descriptor_kind: str = "learned",
) -> dict[str, Any]:
    """The core's scene pipeline; ``descriptor`` a learned descriptor's weights file (None:
    FPFH), used as ``descriptor_kind`` says: "learned" alone, "fpfh+learned" joined to FPFH
    (each of unit length), "auto" joined for a model below ``scene.min_planar_share``, FPFH
    alone for a mostly planar one (the key ``descriptor`` says which ran);
    ``embed(correspondences, normals, similarity)`` computes each pass's learned embedding
    (the cues ``embed_inputs`` names given, else None);
    ``refine=False`` scores the correspondence stage's poses without ICP or verification;
    ``k`` model points matched per scan point; ``mutual_window`` a side in model diagonals
    or ``"auto"`` (the windowed mutual check); ``proposals`` "auto", "descriptors" or
    "faces" (model faces laid on the scan's planar patches join the proposals). Keys:
    ``transformations`` (M, 4, 4) surest first, and per copy ``confidence``, ``fitness``,
    ``inlier_rmse``, ``visible_fitness``, ``contradiction``, ``seen``, ``visible_rmse``
    (M,), ``pass_index`` and ``instance`` (lists); ``passes`` (dicts: ``correspondences``
    (N, 6), ``matches`` (N, or how few survived matching when under 3: then no
    correspondences and an empty ``result``), ``result``, ``scan_points``, ``added``,
    ``voted``, ``faces`` and ``duplicates`` (K, 4, 4));
    ``source_points``, ``source_normals``, ``target_points``, ``target_normals``; ``config``
    (a dict); ``timings`` (seconds per stage); ``voxel_size``, ``by_visibility``,
    ``viewpoint``, ``unconfirmed_viewpoint`` (lists or None) and ``orientation``;
    ``face_proposals`` (whether faces were proposed) and ``planar_share`` (the model's share
    in large flat faces, NaN when neither proposals nor the descriptor need it);
    ``descriptor`` (the one matched by: "fpfh", "learned" or "fpfh+learned"); ``symmetry``
    (the symmetry dict the poses were made canonical by, or None)."""

def symmetry_group(
    discrete: npt.NDArray[np.float64],
    axes: npt.NDArray[np.float64],
    offsets: npt.NDArray[np.float64],
) -> dict[str, npt.NDArray[np.float64]]: ...
def detect_symmetries(
    points: npt.NDArray[np.float64],
    tolerance: float | None = None,
    num_threads: int | None = None,
) -> dict[str, Any]: ...
def canonical_poses(
    transformations: npt.NDArray[np.float64], symmetry: dict[str, npt.NDArray[np.float64]]
) -> npt.NDArray[np.float64]: ...
def resolve_model_symmetry(
    model: npt.NDArray[np.float64],
    described: npt.NDArray[np.float64],
    symmetry: str | dict[str, npt.NDArray[np.float64]],
    num_threads: int | None = None,
) -> dict[str, npt.NDArray[np.float64]]: ...
def bounding_diagonal(points: npt.NDArray[np.float64]) -> float: ...
def cloud_base_config() -> dict[str, Any]: ...
def scan_scales(
    points: npt.NDArray[np.float64], scale: float | None = None
) -> tuple[float, float]: ...
def default_voxel_size(
    model: npt.NDArray[np.float64],
    scan: npt.NDArray[np.float64] | None = None,
    scene: dict[str, Any] | None = None,
) -> float: ...
def stability_factor(
    stability: npt.NDArray[np.float64], min_poses: int
) -> npt.NDArray[np.float64]: ...
def voxel_downsample(
    points: npt.NDArray[np.float64], voxel_size: float
) -> npt.NDArray[np.float64]: ...
def isolated_points(
    points: npt.NDArray[np.float64],
    radius: float,
    min_neighbours: int = 3,
    num_threads: int | None = None,
) -> npt.NDArray[np.bool_]: ...
def estimate_normals(
    points: npt.NDArray[np.float64],
    radius: float,
    max_nn: int = 30,
    towards: tuple[float, float, float] | None = None,
    away_from: tuple[float, float, float] | None = None,
    num_threads: int | None = None,
) -> npt.NDArray[np.float64]: ...
def terraced_share(
    points: npt.NDArray[np.float64],
    radius: float,
    eye: tuple[float, float, float],
    num_threads: int | None = None,
) -> float: ...
def compute_fpfh(
    points: npt.NDArray[np.float64],
    normals: npt.NDArray[np.float64],
    radius: float,
    max_nn: int = 100,
    variant: str = "open3d",
    num_threads: int | None = None,
) -> npt.NDArray[np.float64]: ...
def learned_descriptors(
    points: npt.NDArray[np.float64],
    normals: npt.NDArray[np.float64],
    voxel_size: float,
    weights: str | os.PathLike[str],
    num_threads: int | None = None,
) -> npt.NDArray[np.float64]: ...
def describe(
    points: npt.NDArray[np.float64],
    voxel_size: float | None = None,
    normals: npt.NDArray[np.float64] | None = None,
    towards: tuple[float, float, float] | None = None,
    away_from: tuple[float, float, float] | None = None,
    normal_radius: float | None = None,
    normal_max_nn: int = 30,
    feature_radius: float | None = None,
    feature_max_nn: int = 100,
    variant: str = "open3d",
    num_threads: int | None = None,
) -> tuple[
    npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64], dict[str, float]
]: ...
def match_features(
    source: npt.NDArray[np.float64],
    target: npt.NDArray[np.float64],
    top_k: int = 10000,
    mutual: bool = False,
    n_samples: int | None = ...,
    seed: int = 0,
    num_threads: int | None = None,
    k: int = 1,
    nearest: tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]] | None = None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.float64]]: ...
def nearest_descriptors(
    source: npt.NDArray[np.float64],
    target: npt.NDArray[np.float64],
    k: int = 1,
    num_threads: int | None = None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]: ...
def nearest_neighbours(
    reference: npt.NDArray[np.float64],
    queries: npt.NDArray[np.float64],
    num_threads: int | None = None,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]: ...
def estimate_sensor(
    points: npt.NDArray[np.float64],
    voxel_size: float,
    towards: tuple[float, float, float] | None,
) -> tuple[tuple[float, float, float], float, int]: ...
def edge_on_scores(
    points: npt.NDArray[np.float64],
    normals: npt.NDArray[np.float64],
    eyes: npt.NDArray[np.float64],
    rank: int,
    num_threads: int | None = None,
) -> npt.NDArray[np.float64]: ...
def looks_like_one_view(
    points: npt.NDArray[np.float64],
    viewpoint: tuple[float, float, float] | None,
    voxel_size: float,
) -> bool: ...
def judge_jointly(
    scan: npt.NDArray[np.float64],
    models: list[
        tuple[
            npt.NDArray[np.float64],
            float,
            npt.NDArray[np.float64],
            npt.NDArray[np.float64],
            npt.NDArray[np.float64],
            npt.NDArray[np.float64],
        ]
    ],
    max_shared: float,
    num_threads: int | None = None,
) -> tuple[list[list[bool]], list[list[bool]]]: ...
def refine_poses(
    source: npt.NDArray[np.float64],
    target: npt.NDArray[np.float64],
    transformations: npt.NDArray[np.float64],
    voxel_size: float,
    icp: bool,
    viewpoint: tuple[float, float, float] | None,
    rules: dict[str, Any] | None = None,
    target_normals: npt.NDArray[np.float64] | None = None,
    num_threads: int | None = None,
) -> tuple[
    npt.NDArray[np.float64],
    list[npt.NDArray[np.float64]],
    npt.NDArray[np.int64],
    bool,
    list[tuple[int, str, float, float]],
    tuple[npt.NDArray[np.float64], list[npt.NDArray[np.float64]], npt.NDArray[np.int64]],
]: ...
