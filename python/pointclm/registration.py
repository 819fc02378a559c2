"""`register` and `register_batch`: input checking and conversion in front of the Rust core."""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from . import _core
from ._core import RegistrationResult
from .config import Config
from .docstrings import fill
from .embedding import check_backend, resolve
from .errors import ConfigError, InputError

__all__ = ["default_config", "register", "register_batch"]

MIN_CORRESPONDENCES = 3


def as_matrix(x: ArrayLike, name: str, columns: int | None) -> np.ndarray:
    """A C-contiguous float64 (N, columns) copy-if-needed of `x`, or a ValueError naming the
    problem. The caller's array is never written to."""
    try:
        a = np.asarray(x)
    except Exception as e:  # ragged lists and the like
        raise InputError(f"{name} could not be read as an array: {e}") from None
    if a.dtype == object or not (
        np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)
    ):
        raise InputError(f"{name} must hold real numbers, got dtype {a.dtype}")
    if a.ndim != 2 or (columns is not None and a.shape[1] != columns):
        want = f"(N, {columns})" if columns is not None else "(N, D)"
        raise InputError(f"{name} must have shape {want}, got {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float64)
    if not np.isfinite(a).all():
        row = int(np.argwhere(~np.isfinite(a))[0, 0])
        raise InputError(f"{name} has a non-finite value (NaN or inf) in row {row}")
    return a


def as_correspondences(first: ArrayLike, second: ArrayLike | None) -> tuple[np.ndarray, bool]:
    """(N, 6) rows from either (N, 6) correspondences or two (N, 3) point arrays; the flag
    says whether `second` was consumed as target points."""
    try:
        a = np.asarray(first) if not isinstance(first, np.ndarray) else first
    except Exception as e:  # ragged lists and the like
        raise InputError(f"correspondences could not be read as an array: {e}") from None
    if getattr(a, "ndim", 0) == 2 and a.shape[1] == 3:
        if second is None:
            raise InputError(
                "got (N, 3) points but no target: pass register(source_points, target_points) "
                "or (N, 6) correspondences"
            )
        src = as_matrix(first, "source_points", 3)
        dst = as_matrix(second, "target_points", 3)
        if len(src) != len(dst):
            raise InputError(
                f"source_points and target_points must have the same length, "
                f"got {len(src)} and {len(dst)}"
            )
        corr = np.hstack([src, dst])
        used = True
    else:
        corr = as_matrix(first, "correspondences", 6)
        used = False
    if len(corr) < MIN_CORRESPONDENCES:
        raise InputError(f"need at least {MIN_CORRESPONDENCES} correspondences, got {len(corr)}")
    return corr, used


def with_normals(corr: np.ndarray, normals: ArrayLike) -> np.ndarray:
    """(N, 12) rows: the correspondences then their (N, 6) normals, checked non-zero."""
    n = as_matrix(normals, "normals", 6)
    if len(n) != len(corr):
        raise InputError(
            f"normals must have one row (source normal | target normal) per correspondence: "
            f"{len(corr)}, got {len(n)}"
        )
    for side, cols in (("source", n[:, :3]), ("target", n[:, 3:])):
        zero = np.flatnonzero(~(np.linalg.norm(cols, axis=1) > 0))
        if len(zero):
            raise InputError(f"normals: the {side} normal of row {int(zero[0])} is zero")
    return np.ascontiguousarray(np.hstack([corr, n]))


def as_features(features: ArrayLike | None, n: int) -> np.ndarray | None:
    if features is None:
        return None
    f = as_matrix(features, "features", None)
    if len(f) != n:
        raise InputError(f"features must have one row per correspondence: {n}, got {len(f)}")
    if f.shape[1] == 0:
        raise InputError("features must have at least one column")
    return f


@functools.cache
def _default_config_dict() -> dict[str, Any]:
    """`Config()` as the core's dict, built once: the defaults never change, and building
    and validating a Config costs about as much as pruning a small scene."""
    return Config().to_dict()


def as_config(config: Config | dict[str, Any] | None) -> dict[str, Any]:
    if config is None:
        return _default_config_dict().copy()
    if isinstance(config, dict):
        return Config.from_dict(config).to_dict()
    if isinstance(config, Config):
        return config.to_dict()
    raise ConfigError(f"config must be a pointclm.Config, a dict or None, got {type(config)}")


def default_config(model: Any = None, overrides: Mapping[str, Any] | None = None) -> Config:
    """The config `register` and `register_batch` use when given none: the thresholds
    recommended with `model` (:meth:`pointclm.embedding.Embedding.recommended_config`), else
    (no model, or one that carries none) `Config()`; then `overrides` (field values in the
    same, synthetic, units: the command line's method flags) in place of its own."""
    recommended = None if model is None else resolve(model).recommended_config()
    return (recommended or Config()).with_overrides(overrides)


@fill
def register(
    correspondences: ArrayLike,
    features: ArrayLike | None = None,
    config: Config | dict[str, Any] | None = None,
    seed: int = 0,
    *,
    target: ArrayLike | None = None,
    num_threads: int | None = None,
    model: Any = None,
    backend: str = "rust",
    device: str | None = None,
    normals: ArrayLike | None = None,
    similarity: ArrayLike | None = None,
) -> RegistrationResult:
    """Find every copy of the source object in the target.

    Parameters
    ----------
    correspondences : array_like
        (N, 6) rows ``(source xyz | target xyz)``; or (N, 3) source points, with the (N, 3)
        target points as the second argument: ``register(source_points, target_points)``.
    features : array_like, optional
        (N, D) per-correspondence features (e.g. the learned embedding, L2-normalised); with
        them pruning and clustering use ``S = S^F * beta`` instead of ``S = beta``. When the
        first argument holds points, the second positional argument is the target; to give
        features with points, pass ``register(source, target=target, features=f)``.
    %(config)s
    %(seed)s
    %(num_threads)s
    %(model)s
    %(backend)s
    %(device)s
    %(normals)s
    %(similarity)s

    Returns
    -------
    RegistrationResult
        ``instances`` (each with ``transformation`` = T_target_source 4x4, ``fitness``,
        ``inlier_rmse``, ``correspondence_set``), ``transformations`` (M, 4, 4) and
        ``labels`` (N,): -1 for outliers, k for instance k.
    """
    corr, features = _rows_and_features(correspondences, features, target)
    feats = as_features(features, len(corr))
    network = None
    backend = check_backend(backend, model, device)
    rows = corr if normals is None else with_normals(corr, normals)
    if model is not None:
        if feats is not None:
            raise InputError("pass either features or model, not both")
        cues = [(normals, similarity)]
        network, embedded, config = _embedding(
            model, backend, device, config, [corr], num_threads, cues
        )
        feats = None if embedded is None else embedded[0]
    threads = as_threads(num_threads)
    cfg = as_config(config)
    return _core.register(rows, feats, cfg, as_seed(seed), num_threads=threads, network=network)


def _rows_and_features(
    correspondences: ArrayLike, features: ArrayLike | None, target: ArrayLike | None
) -> tuple[np.ndarray, ArrayLike | None]:
    """The (N, 6) rows, and the features left once a positional target is taken out of them
    (``register(source, target)`` passes the target where the features go)."""
    if target is not None:
        corr, used = as_correspondences(correspondences, target)
        if not used:
            raise InputError(
                "target= goes with (N, 3) source points; with (N, 6) correspondences leave it out"
            )
        return corr, features
    corr, used = as_correspondences(correspondences, features)
    return corr, (None if used else features)


def _embedding(
    model: Any,
    backend: str,
    device: str | None,
    config: Config | dict[str, Any] | None,
    corrs: list[np.ndarray],
    num_threads: int | None,
    cues: list[tuple[Any, Any]] | None = None,
) -> tuple[_core.Network | None, list[np.ndarray] | None, Any]:
    """The network for the core to run, or else each scene's embedding computed here; and the
    config: the caller's, else the one recommended with the network.

    The core runs its network on the coordinates as given (and times it), so it gets the
    network only when they are in the network's training units (the config's sigma_d is the
    network's). Otherwise each scene is converted to those units and embedded here
    (:mod:`pointclm.embedding`), so that ``config=Config().scaled(f)`` is right for
    coordinates `f` times larger.
    """
    emb = resolve(model, backend, device)
    if config is None:
        config = default_config(emb)
    sigma_d = as_config(config)["sigma_d"]
    cues = cues or [(None, None)] * len(corrs)
    # A network with inputs beyond coordinates is run here, where its cues are at hand.
    if emb.backend == "rust" and emb.in_training_units(sigma_d) and not emb.inputs:
        return emb.network, None, config
    units = None if emb.in_training_units(sigma_d) else sigma_d
    threads = as_threads(num_threads)
    return (
        None,
        [
            emb.embed(c, units, num_threads=threads, normals=n, similarity=s)
            for c, (n, s) in zip(corrs, cues, strict=True)
        ],
        config,
    )


def _scene_arrays(item: Any, k: int) -> tuple[np.ndarray, np.ndarray | None]:
    try:
        if hasattr(item, "correspondences"):
            corr, _ = as_correspondences(item.correspondences, None)
            return corr, as_features(getattr(item, "features", None), len(corr))
        if isinstance(item, tuple | list) and len(item) == 2 and not np.isscalar(item[0]):
            corr, used = as_correspondences(item[0], item[1])
            return corr, None if used else as_features(item[1], len(corr))
        corr, _ = as_correspondences(item, None)
        return corr, None
    except ValueError as e:
        raise _in_scene(e, k) from None


def _in_scene(e: ValueError, k: int) -> ValueError:
    """`e` with the scene's index in front of its message, of the same class so that
    ``except InputError`` (or FileNotFoundError) catches a batch's error as it does one
    scene's, as the core's own batch errors do."""
    message = f"scene {k}: {e}"
    try:
        renamed = type(e)(message)
    except Exception:  # a class whose constructor does not take one message
        return ValueError(message)
    return renamed if isinstance(renamed, ValueError) else ValueError(message)


def register_batch(
    scenes: Iterable[Any],
    config: Config | dict[str, Any] | None = None,
    seed: int = 0,
    *,
    num_threads: int | None = None,
    model: Any = None,
    backend: str = "rust",
    device: str | None = None,
) -> list[RegistrationResult]:
    """Register many scenes in parallel with the GIL released.

    Each scene is an (N, 6) array, a ``(correspondences, features)`` or ``(source_points,
    target_points)`` pair, or an object with a ``correspondences`` attribute (and optionally
    ``features``), such as `pointclm.datasets.SyntheticScene`. Every scene uses the same
    `seed`, so ``register_batch(s)[i]`` equals ``register(s[i])`` whatever `num_threads`.
    `model`, `backend` and `device` are as in `register`: with the Rust backend each scene's
    embedding runs on the thread of that scene (the results do not depend on `num_threads`);
    with torch the embeddings of all scenes are computed first, one after the other. So are
    they when the config's ``sigma_d`` is not the network's (coordinates in other units are
    converted to the network's first, see `register`).
    """
    if isinstance(scenes, np.ndarray) and scenes.ndim == 2:
        raise InputError(
            f"register_batch takes a list of scenes, got one {scenes.shape} array: "
            "use register(array) or register_batch([array])"
        )
    try:
        items: Sequence[Any] = list(scenes)
    except TypeError:
        raise InputError(f"scenes must be an iterable of scenes, got {type(scenes)}") from None
    arrays = [_scene_arrays(item, k) for k, item in enumerate(items)]
    network = None
    backend = check_backend(backend, model, device)
    if model is not None:
        if any(f is not None for _, f in arrays):
            raise InputError("pass either per-scene features or model, not both")
        corrs = [c for c, _ in arrays]
        network, embedded, config = _embedding(model, backend, device, config, corrs, num_threads)
        if embedded is not None:
            arrays = list(zip(corrs, embedded, strict=True))
    return _core.register_batch(
        arrays,
        as_config(config),
        as_seed(seed),
        num_threads=as_threads(num_threads),
        network=network,
    )


def as_seed(seed: int) -> int:
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not (0 <= seed < 2**64):
        raise InputError(f"seed must be a non-negative int below 2**64, got {seed!r}")
    return int(seed)


def as_threads(num_threads: int | None) -> int | None:
    if num_threads is None:
        return None
    if (
        isinstance(num_threads, bool)
        or not isinstance(num_threads, int | np.integer)
        or num_threads < 1
    ):
        raise InputError(f"num_threads must be an int >= 1 or None, got {num_threads!r}")
    if num_threads >= 2**32:  # the core checks its own, lower, upper bound
        raise InputError(f"num_threads is too large: {num_threads}")
    return int(num_threads)
