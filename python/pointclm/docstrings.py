"""The parameter descriptions of the public registration functions, written once.

`pointclm.register` and `pointclm.register_point_clouds` take many parameters, some of them
the same (``num_threads``), and the point-cloud options are the ones `register_files` and the
command line forward. Their numpydoc entries live here, in :data:`PARAMETERS`; a function's
docstring names each by a placeholder line ``%(name)s``, and :func:`fill` (a decorator) puts
the entry there at import, indented as the placeholder, so ``help(pointclm.register)`` and IDEs
show the whole documentation while each function's source stays short.

Entries whose meaning differs between the paths keep separate names: a correspondence
``seed`` seeds clustering and RANSAC, a point-cloud one (``cloud_seed``) the sampling of
correspondences too; a correspondence ``config`` is in the correspondences' units, a
point-cloud one (``cloud_config``) in the clouds'.
"""

from __future__ import annotations

import re
import textwrap
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["PARAMETERS", "fill"]

F = TypeVar("F", bound=Callable[..., Any])


def _entries(**texts: str) -> dict[str, str]:
    return {name: textwrap.dedent(text).strip("\n") for name, text in texts.items()}


#: Numpydoc entries by placeholder name: a ``name : type`` line, then its description
#: indented by four spaces (more lines may follow the placeholder at that indentation).
PARAMETERS: dict[str, str] = _entries(
    # --- shared ---------------------------------------------------------------------------
    num_threads="""
        num_threads : int, optional
            Threads for this call (default: all cores).
        """,
    # --- `register`: correspondences -------------------------------------------------------
    config="""
        config : Config or dict, optional
            Thresholds, lengths in the units of the correspondences; `Config()` by default (the
            synthetic protocol's units; ``Config().scaled(f)`` for coordinates `f` times larger).
        """,
    seed="""
        seed : int
            Seeds clustering and RANSAC; the same seed gives the same result whatever
            `num_threads`.
        """,
    model="""
        model : str, path, pointclm.Network or torch module, optional
            The learned embedding computes `features` (PointCLM proper): "default" (compact,
            shipped), "paper" (paper-size, shipped), a weight file (``.safetensors`` with its
            ``.json``), a loaded `pointclm.Network`, or (with ``backend="torch"``) a torch module.
            Without a `config`, the pruning thresholds chosen with that network on its validation
            shapes are used. The network sees the correspondences in the units it was trained in
            (converted when the config's ``sigma_d`` differs from the network's; see
            :mod:`pointclm.embedding`). None (default) is the training-free pipeline.
            The Rust forward pass takes any N when few pairs of correspondences are
            length-consistent (its sparse attention); when more than 1/16 of them (or more
            than 50 million) are, its dense attention runs, whose time grows as N^2, and more
            than 32,768 correspondences are refused up front with an InputError (a
            ValueError) saying so.
        """,
    backend="""
        backend : {"rust", "torch"}
            Where the embedding is computed: "rust" (default; the core's own forward pass on the
            CPU, no torch needed, its time in ``timings["embedding"]``) or "torch" (needs torch;
            runs on `device`).
        """,
    device="""
        device : str, optional
            The torch device of ``backend="torch"`` (default "cpu"), e.g. "cuda".
        """,
    normals="""
        normals : array_like, optional
            (N, 6) rows ``(source normal | target normal)``: a surface normal at both ends of each
            correspondence (any length, any sign). A rigid motion preserves the angle between two
            normals and each point's distance from the other's tangent plane, so spatial
            consistency also asks these to agree, which makes pruning and clustering far sharper.
            :func:`pointclm.register_point_clouds` passes its clouds' normals. A network that
            takes normals (``model.inputs``) reads them too, and needs them.
        """,
    similarity="""
        similarity : array_like, optional
            (N,) descriptor similarity of each match (:func:`pointclm.cues.similarity` of the
            descriptor distances), for a network that takes it (``model.inputs``); ignored
            otherwise. :func:`pointclm.register_point_clouds` computes it from its matches.
        """,
    # --- `register_point_clouds`: a model and a scan (also `register_files`' options) -------
    voxel_size="""
        voxel_size : float, optional
            Downsampling voxel, in the clouds' units; default: the model's bounding-box diagonal
            / 40, or 1.4 times the scan's point spacing or 2.5 times its noise where that is
            larger (:func:`default_voxel_size`). Normals use 2 voxels (4 on a scan whose depth
            steps make flat terraces at 2), FPFH 5 voxels.
        """,
    cloud_config="""
        config : Config or dict, optional
            Pipeline settings in the clouds' units, used as given (``Config.for_voxel(voxel,
            base)`` makes one from synthetic-unit settings). Default: :meth:`Config.for_voxel`,
            with the thresholds chosen for refined poses (`REFINED_THRESHOLDS`, or a `model`'s
            ``recommended_point_cloud_config``), and with `peel` a cluster count of at least
            `PEEL_CLUSTER_LEVEL`'s; with ``refine=False``, `Config()`'s (or the model's
            ``recommended_point_cloud_config_no_refine``).
        """,
    cloud_seed="""
        seed : int
            Seeds the sampling of correspondences, clustering and RANSAC.
        """,
    cloud_model="""
        model : str, path, pointclm.Network or torch module, optional
            The learned embedding ("default", "paper", a weight file, a loaded network):
            PointCLM proper (:func:`pointclm.embedding.resolve`). The correspondences are
            converted to the network's training units (by sigma_d) first.
        """,
    clouds_in="""
        source, target : array_like or path
            (N, 3) points, or a file :func:`pointclm.io.load_points` reads (meshes are
            sampled); `target` may also be an organised frame, a numpy array (H, W, 3) in its
            sensor's coordinates: its pixels without a return (NaN, infinite or all zero)
            are dropped and its sensor, the origin, is the default viewpoint.
        """,
    viewpoint="""
        viewpoint : array_like, optional
            The scan's sensor position: scan normals point towards it, and verification judges
            each pose by what the sensor there could see of it. Default: the origin for an
            organised frame (an (H, W, 3) `target` array, or an organised PCD file: a depth
            frame is in its sensor's coordinates); the ``VIEWPOINT`` a PCD `target` file
            records (:func:`file_viewpoint`); else, for a scan in its sensor's
            frame (one view from the origin, every point in front of it, as depth cameras
            write frames), the origin, kept when verification from there keeps the pose the
            model share ranks first; else the sensor's position is estimated on each side of
            the scan (:func:`pointclm.preprocessing.estimate_viewpoint` finds a point that
            orients the normals consistently; the other side is its mirror image): the point
            from which the scan hides the fewest of its own points
            (:func:`pointclm._core.estimate_sensor`). In a scan reaching beyond two model radii,
            the side that hides clearly fewer gives the normals their sign (else the sign whose
            descriptors lie nearer the model's), and
            its estimate is kept as above when the scan looks like one view from there; else
            none, and poses are judged by the share of the model they explain.
            ``PointCloudRegistration.viewpoint`` says which was used. Pass it for scenes where
            copies hide one another. The model's normals point away from its centroid.
        """,
    matching="""
        top_k, mutual, n_samples, k
            Correspondence building (paper appendix): each scan point's `k` most similar model
            points, the `top_k` most similar of these matches kept (only mutual ones if `mutual`),
            then `n_samples` sampled (None: all); see :func:`pointclm.preprocessing.match_features`.
        """,
    proposals="""
        proposals : {"auto", "descriptors", "faces"}, default "auto"
            Which poses verification judges. "descriptors": the clusters of FPFH matches (and,
            in a heap, point pair voting). "faces": those, and every model face laid on every
            planar patch of the scan (region growing with tolerances from the scan's measured
            noise; the face's normal on the patch's, its sides along the patch's rectangle,
            centred on each tile of a patch that flush copies fill, else cornered in the
            patch's corners): on a flat face every FPFH descriptor is the same, while its size
            and outline are not. "auto": faces when at least ``scene.min_planar_share`` (0.5)
            of the downsampled model lies in planar faces wider than a disc of the FPFH radius
            (5 voxels), as on boxes (0.89-0.99) and the bracket (0.99); the fandisk (0.43),
            the rocker arm (0.16), the bunny (0.03) and the dragon (0.00) keep the descriptors
            alone. Either way every pose is judged by the same
            verification; nothing is accepted for being proposed.
        descriptor : {"auto", "fpfh", "learned", "fpfh+learned"} or path, default "auto"
            The local descriptor both clouds are matched by: FPFH, the learned descriptor
            shipped with the package, both side by side, or a descriptor file written by
            ``pointclm train-descriptor`` (see :mod:`pointclm.descriptors`). "auto": FPFH
            alone for a mostly planar model (the rule and threshold of `proposals` "auto"),
            FPFH and the learned one for any other; the result's ``descriptor`` says which
            ran. Each is computed over the same points and normals; every later stage is the
            same.
        """,
    mutual_window="""
        mutual_window : float, "auto" or None, default None
            For heaps of identical parts (bin picking): the mutual check is made within
            overlapping cubes of this side, in model diagonals (the model's bounding-box
            diagonal), instead of over the whole scan (needs `mutual` and ``k=1``;
            :meth:`pointclm.preprocessing.DescriptorMatcher.match`'s ``window``). Why: a model
            point has one true match per visible copy, and the scene-wide check keeps at most one
            of them, so most copies keep too few matches to be found; ``mutual=False`` keeps them
            but floods the copies with false matches. "auto": the scene-wide check until peeling
            has accepted `pointclm.point_clouds.HEAP_MIN_COPIES` (10) copies, then windows of
            `HEAP_WINDOW` (2) with every match kept (``n_samples=None``) in the later passes,
            instead of `heap_rank`'s ranked check (with other matching, or without peeling,
            "auto" changes nothing). On the validation bins it finds 0.32 of the half-visible
            copies (by ADD-S 0.42 at precision 0.988), the ranked check 0.34 (0.45 at 0.995).
            2 (with ``n_samples=None``) from the first pass: 0.34 (ADD-S 0.48 at 0.982), 2.2
            times the time of the scene-wide check, but realistic validation F1 0.84 against
            0.87. None (the default): the scene-wide check, relaxed by `heap_rank` in a heap.
        """,
    heap_rank="""
        heap_rank : int or None, default 64
            For heaps: once peeling has accepted `pointclm.point_clouds.HEAP_MIN_COPIES` (10)
            copies, the later passes keep a pair when the scan point's best model match is that
            model point and the scan point is among the model point's `heap_rank` most similar
            scan points still unexplained (the mutual check, relaxed by rank; needs `mutual`
            and ``k=1``, and gives way to `mutual_window`). A model point has one true match per
            visible copy, and the scene-wide check keeps one. A scan with fewer copies (a room)
            is matched as before. None (or 1): the mutual nearest check in every pass.
        """,
    heap="""
        heap : bool or None, default None
            Whether `target` is a heap of identical parts. None: judged by the count, once
            peeling has accepted `HEAP_MIN_COPIES` (10) copies. True (a bin-picking cell knows
            its scans are heaps): every pass matches as in a heap (`heap_rank`, or the windows
            of ``mutual_window="auto"``), so a part whose scene-wide passes stall below 10
            copies, or find none, gets the heap's matching too (not for a room scan: there it
            costs precision and time: realistic validation F1 0.880 -> 0.821 in three times the
            time). True also makes every peeling round propose poses voted by point pair
            features over the unexplained scan points (`HEAP_VOTED_POSES`, Drost et al. 2010),
            verified like the others: copies whose descriptor matches drown among their
            neighbours' are found, at several times the time. False: never.
        """,
    cloud_normals="""
        normals : bool
            Give the pipeline the clouds' normals at both ends of each correspondence, so spatial
            consistency also checks the angles a rigid motion preserves (`register`'s
            ``normals=``).
        """,
    refine="""
        refine : bool
            Refine each pose by ICP on the clouds and keep those the scan supports, judged by
            what the sensor at `viewpoint` could see of each (:func:`pointclm.refinement.
            refine_poses` with its defaults; without a viewpoint, or when the scan does not look
            like one view from it, by the share of the model explained). False: the
            correspondence stage's poses as they are (their fitness is still measured).
        """,
    peel="""
        peel : bool
            With `refine`: after the first pass, set aside the scan points the accepted copies
            explain (within 2 voxels), run the correspondence stage again on the rest, and verify
            the new poses with the accepted ones; repeat until a pass adds no copy (at most
            `MAX_PEEL_ROUNDS`). This finds the copies of a heap whose matches the first copies
            crowd out of the sample. False: one pass (the paper's pipeline).
        """,
    flips="""
        flips : bool
            With `refine`: also try each accepted pose turned half a turn about each principal
            axis of the model through its centroid, and a quarter turn either way about those
            that leave most of the model in place, and (with `peel`) the rotations at which
            peeling's duplicates settled on an accepted copy, relative to its pose (the scene's
            own alternatives, the three most frequent), and keep a turned pose the scan supports
            better (:func:`pointclm.refinement.resolve_flips`): near-symmetric parts are often
            posed turned, and ICP and verification alone cannot tell. On the validation sets
            (half turns): realistic scenes F1 0.814 -> 0.871, bins precision 0.744 ->
            0.754, at 1.13 and 1.04 times the time; quarter turns judged by the points that
            tell the turns apart: bins heap=True precision 0.646 -> 0.658, at the
            same time; the scene's own alternatives: bins heap=True first five right
            in 68 -> 69 of 72 validation scenes. False: the poses as verified.
        """,
    symmetry="""
        symmetry : dict, pointclm.symmetry.Symmetry or "auto", optional
            The model's proper symmetries, as one BOP ``models_info.json`` entry gives them
            (``symmetries_discrete``: 4 x 4 transforms, 16 numbers row-major;
            ``symmetries_continuous``: ``{"axis", "offset"}``), in the **model's units** (BOP
            writes mm: :func:`pointclm.symmetry.from_bop` with ``scale=0.001`` for a model in
            metres; a symmetry moving the model's centroid by over a tenth of its diagonal is a
            ValueError); or ``"auto"``: detected on the downsampled model
            (:func:`pointclm.symmetry.detect`, tolerance 3 point spacings). Every returned pose
            is then the canonical one among its equivalents ``T @ S``: the one whose rotation
            is nearest the identity (:meth:`pointclm.symmetry.Symmetry.canonical`), so equal
            copies get equal answers; and `flips` does not try a turn that is a symmetry.
            None: no symmetry declared.
        """,
    scene="""
        scene : pointclm.SceneRules or dict, optional
            The scene-wide rules (the voxel's floor, stray points, peeling, heaps, turned
            alternatives, the final ranking), or a dict of some of them by name; None: the
            defaults. Each rule's default, range and reason: ``help(pointclm.SceneRules)``.
        """,
    cloud_returns="""
        Returns
        -------
        PointCloudRegistration
            Its ``instances`` are the refined and verified copies, surest first. The result's
            ``diagnosis`` says why nothing was found (or why a result is doubtful) and what to
            try; ``print(result)`` shows a summary.
        """,
)

#: A line holding only a placeholder, and its indentation.
_PLACEHOLDER = re.compile(r"^(?P<indent>[ ]*)%\((?P<name>\w+)\)s[ ]*$", re.M)


def fill(func: F) -> F:
    """`func` with each placeholder line ``%(name)s`` of its docstring replaced by
    ``PARAMETERS[name]``, every line indented as the placeholder (a KeyError at import names
    an unknown one). Nothing else of the docstring changes; under ``python -OO`` (no
    docstrings) nothing does."""
    if func.__doc__ is not None:

        def entry(m: re.Match[str]) -> str:
            text = PARAMETERS[m["name"]]
            return "\n".join(m["indent"] + line if line else line for line in text.split("\n"))

        func.__doc__ = _PLACEHOLDER.sub(entry, func.__doc__)
    return func
