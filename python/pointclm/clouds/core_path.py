"""The scene pipeline, run whole in the Rust core.

`register_point_clouds` calls the core's scene pipeline (``pointclm::scene::register_point_clouds``:
sensor and viewpoint, description, matching, the correspondence stage, verification, peeling,
turned alternatives, ranking) in one call, and this module turns its answer into a
:class:`PointCloudRegistration`. A learned model's embedding is called back from the core for
every pass (either backend).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import numpy as np

from .. import _core
from ..config import Config
from ..covariance import PoseCovariances, pose_covariances
from ..embedding import Embedding
from ..preprocessing import as_count
from ..refinement import RefinementContext
from ..registration import as_config, as_seed
from ..scene_rules import SceneRules
from ..symmetry import Symmetry, as_core
from .diagnosis import _diagnose
from .results import CloudInstance, Pass, PointCloudRegistration
from .sensor import warn_disputed


@dataclass(frozen=True)
class CoreCall:
    """What the core's pipeline is asked, checked."""

    voxel: float
    #: The correspondence stage's config, in the clouds' units; None: ``cloud_config`` (that
    #: of the learned model when there is one).
    config: Config | dict[str, Any] | None
    seed: int
    viewpoint: tuple[float, float, float] | None
    top_k: int
    mutual: bool
    n_samples: int | None
    heap_rank: int | None
    heap: bool | None
    peel: bool
    flips: bool
    scene: SceneRules
    num_threads: int | None
    #: Who states `viewpoint` when the caller did not: the scan file's VIEWPOINT, or the
    #: origin of an organised frame (the words the result and the warning use); "" for the
    #: caller's own.
    stated_by: str = ""
    #: The learned embedding of every pass's correspondences; None: training-free.
    model: Embedding | None = None
    #: Whether the correspondence stage gets the normals at both ends of each pair.
    normals: bool = False
    #: ICP and verification of the poses (then peeling, turns and ranking); False: the
    #: correspondence stage's poses, scored only.
    refine: bool = True
    #: Model points matched to each scan point.
    k: int = 1
    #: The windowed mutual check: a side in model diagonals, "auto" or None (checked).
    mutual_window: float | str | None = None
    #: The model's symmetries as given (:func:`pointclm.symmetry.resolve`); checked: "auto",
    #: the core's symmetry dict, or None.
    symmetry: Any = None
    #: Which poses verification judges: "auto", "descriptors" or "faces" (checked).
    proposals: str = "auto"
    #: The learned descriptor's weights file; None: FPFH (checked:
    #: :func:`pointclm.descriptors.descriptor_weights`).
    descriptor: str | None = None
    #: How the learned descriptor is used: "learned" (alone), "fpfh+learned" (beside FPFH)
    #: or "auto" (decided by the model's shape).
    descriptor_kind: str = "learned"

    def checked(self) -> CoreCall:
        """The call with its seed and matching counts checked (the core takes unsigned
        ints)."""
        # Imported here: the module that declares the config calls this one.
        from ..point_clouds import _config

        as_count(self.top_k, "top_k", 1)
        samples = None if self.n_samples is None else as_count(self.n_samples, "n_samples", 1)
        level = self.scene.peel_cluster_level
        config = _config(self.config, self.voxel, self.model, self.refine, self.peel, level)
        k = as_count(self.k, "k", 1)
        sym = as_core(self.symmetry)
        return replace(
            self, seed=as_seed(self.seed), n_samples=samples, config=config, k=k, symmetry=sym
        )


def register_in_core(src: np.ndarray, tgt: np.ndarray, call: CoreCall) -> PointCloudRegistration:
    """`register_point_clouds` on loaded clouds, in the core; ``timings["load"]`` and
    ``["total"]`` are left for the caller."""
    out = _core.register_scan(
        src,
        tgt,
        voxel_size=call.voxel,
        viewpoint=call.viewpoint,
        seed=call.seed,
        peel=call.peel,
        heap=call.heap,
        heap_rank=call.heap_rank or 0,
        flips=call.flips,
        top_k=call.top_k,
        mutual=call.mutual,
        n_samples=call.n_samples,
        config=as_config(call.config),
        scene=call.scene.to_dict(),
        num_threads=call.num_threads,
        pair_normals=call.normals,
        embed=None if call.model is None else _embedding(call.model, call),
        embed_inputs=[] if call.model is None else list(call.model.inputs),
        refine=call.refine,
        k=call.k,
        mutual_window=call.mutual_window,
        symmetry=call.symmetry,
        proposals=call.proposals,
        descriptor=call.descriptor,
        descriptor_kind=call.descriptor_kind,
    )
    passes = [_pass(p) for p in out["passes"]]
    judged = _CoreJudged(out, call.num_threads)
    instances = _instances(out, out, passes, judged)
    ambiguous = _instances(out["ambiguous"], out, passes, judged)
    return PointCloudRegistration(
        result=passes[0].result,
        correspondences=passes[0].correspondences,
        source_points=out["source_points"],
        target_points=out["target_points"],
        voxel_size=out["voxel_size"],
        config=Config.from_dict(out["config"]),
        instances=instances,
        timings=_timings(out["timings"], passes[0]),
        passes=passes,
        viewpoint=None if out["viewpoint"] is None else np.array(out["viewpoint"]),
        orientation=out["orientation"] + _recorded(call),
        viewpoint_disputed=_disputed(out, call),
        diagnosis=_diagnose(judged, len(instances), out["by_visibility"], passes),
        ambiguous=ambiguous,
        symmetry=None if out["symmetry"] is None else Symmetry._from_core(out["symmetry"]),
        descriptor=out["descriptor"],
    )


def _embedding(model: Embedding, call: CoreCall) -> Callable[..., np.ndarray]:
    """The core's embedding callback: a pass's correspondences (clouds' units) and the cues
    the network takes, embedded in its training units."""

    def embed(corr: np.ndarray, normals: np.ndarray | None, similarity: np.ndarray | None):
        return model.embed(
            corr,
            as_config(call.config)["sigma_d"],
            num_threads=call.num_threads,
            normals=normals,
            similarity=similarity,
        )

    return embed


def _disputed(out: dict[str, Any], call: CoreCall) -> bool:
    """Whether the scan disputes the viewpoint given (or recorded), said with a warning."""
    if out["viewpoint_disputed"] and call.viewpoint is not None:
        warn_disputed(call.viewpoint, call.stated_by, stacklevel=5)  # register_point_clouds' caller
    return bool(out["viewpoint_disputed"])


def _recorded(call: CoreCall) -> str:
    """What the orientation adds when the scan itself stated the viewpoint."""
    return f" ({call.stated_by})" if call.stated_by and call.viewpoint is not None else ""


def _pass(p: dict[str, Any]) -> Pass:
    return Pass(
        p["correspondences"],
        p["result"],
        p["scan_points"],
        p["added"],
        voted=p["voted"],
        faces=p["faces"],
        duplicates=p["duplicates"],
        matches=int(p["matches"]),
    )


def _instances(
    copies: dict[str, Any], out: dict[str, Any], passes: list[Pass], judged: _CoreJudged
) -> list[CloudInstance]:
    """Each of `copies` (the core's columns), with the correspondence stage's instance it
    came from (None for a pose that point pair voting or a face proposed), and its information
    and covariance."""
    covariances = None
    if len(copies["transformations"]):
        covariances = pose_covariances(
            out["source_points"],
            out["target_points"],
            copies["transformations"],
            judged.voxel,
            num_threads=judged.num_threads,
            context=judged.refiner,
        )
    found = []
    origins = zip(copies["pass_index"], copies["instance"], strict=True)
    for i, (pass_index, instance) in enumerate(origins):
        result = passes[pass_index].result
        found.append(
            CloudInstance(
                copies["transformations"][i],
                float(copies["fitness"][i]),
                float(copies["inlier_rmse"][i]),
                result.instances[instance] if instance < len(result) else None,
                float(copies["confidence"][i]),
                float(copies["visible_fitness"][i]),
                float(copies["contradiction"][i]),
                pass_index,
                float(copies["visible_rmse"][i]),
                *_covariance_of(covariances, i),
                slid_fitness=float(copies["slid_fitness"][i]),
            )
        )
    return found


def _covariance_of(
    covariances: PoseCovariances | None, i: int
) -> tuple[np.ndarray | None, np.ndarray | None, int]:
    if covariances is None:
        return None, None, 0
    return (
        covariances.information[i],
        covariances.covariance[i],
        int(covariances.unobservable[i]),
    )


def _timings(core: dict[str, float], first: Pass) -> dict[str, float]:
    """Seconds per stage, in the order and with the names of the Python stages."""
    stage = dict(first.result.timings)
    return {
        "load": 0.0,
        **{s: core[s] for s in ("downsample", "normals", "fpfh", "matching")},
        "embedding": core["embedding"],
        **{s: stage.get(s, 0.0) for s in ("pruning", "clustering", "poses")},
        **{s: core[s] for s in ("registration", "refinement", "peeling", "flips")},
        "total": 0.0,
    }


class _CoreJudged:
    """Where the core judged the poses from, for the diagnosis; the refinement context is
    built only when a diagnosis asks why every candidate was rejected."""

    def __init__(self, out: dict[str, Any], num_threads: int | None) -> None:
        self._out = out
        self.num_threads = num_threads
        self.voxel = float(out["voxel_size"])
        self.viewpoint = _point(out["viewpoint"])
        self.unconfirmed = _point(out["unconfirmed_viewpoint"])
        self.face_proposals = bool(out["face_proposals"])

    @cached_property
    def refiner(self) -> RefinementContext:
        return RefinementContext(
            self._out["source_points"],
            self._out["target_points"],
            self.voxel,
            viewpoint=self.viewpoint,
            target_normals=self._out["target_normals"],
            num_threads=self.num_threads,
        )


def _point(v: list[float] | None) -> tuple[float, float, float] | None:
    return None if v is None else (float(v[0]), float(v[1]), float(v[2]))
