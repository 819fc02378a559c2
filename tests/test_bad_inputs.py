"""Every bad input reaches the caller as a ValueError that says what to fix.

A Rust panic would surface as pyo3's PanicException, a BaseException that `except Exception`
misses; `raises_value_error` fails the test on anything but ValueError.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm import Config, staged
from pointclm.datasets import make_scene

CORR = np.array(make_scene(0).correspondences[:200])
SRC, DST = CORR[:, :3].copy(), CORR[:, 3:].copy()
RNG = np.random.default_rng(0)
FEATS = RNG.normal(size=(len(CORR), 8))


@contextlib.contextmanager
def raises_value_error(match: str) -> Iterator[None]:
    try:
        yield
    except ValueError as e:
        assert re.search(match, str(e)), f"message {str(e)!r} does not match {match!r}"
    except KeyboardInterrupt:
        raise
    except BaseException as e:  # PanicException, TypeError, OverflowError...
        pytest.fail(f"expected ValueError matching {match!r}, got {type(e).__name__}: {e}")
    else:
        pytest.fail(f"expected ValueError matching {match!r}, nothing was raised")


def with_nan(a: np.ndarray, value: float = np.nan) -> np.ndarray:
    b = np.array(a, dtype=np.float64)
    b[len(b) // 2, 1] = value
    return b


# --- correspondences ------------------------------------------------------------------------

REGISTER_CASES: list[tuple[str, Callable[[], Any], str]] = [
    ("N5", lambda: pointclm.register(CORR[:, :5]), r"shape \(N, 6\).*\(200, 5\)"),
    ("N7", lambda: pointclm.register(np.ones((20, 7))), r"shape \(N, 6\)"),
    ("1-D", lambda: pointclm.register(CORR[:, 0]), r"shape \(N, 6\).*\(200,\)"),
    ("flat", lambda: pointclm.register(CORR.ravel()), r"shape \(N, 6\)"),
    ("3-D", lambda: pointclm.register(CORR[None]), r"shape \(N, 6\).*\(1, 200, 6\)"),
    ("scalar", lambda: pointclm.register(1.0), r"shape \(N, 6\)"),
    ("None", lambda: pointclm.register(None), "real numbers"),
    ("N=0", lambda: pointclm.register(np.empty((0, 6))), "at least 3 correspondences, got 0"),
    ("N=2", lambda: pointclm.register(CORR[:2]), "at least 3 correspondences, got 2"),
    ("N=2 points", lambda: pointclm.register(SRC[:2], DST[:2]), "at least 3"),
    ("NaN", lambda: pointclm.register(with_nan(CORR)), r"non-finite.*row 100"),
    ("inf", lambda: pointclm.register(with_nan(CORR, np.inf)), r"non-finite.*row 100"),
    ("-inf", lambda: pointclm.register(with_nan(CORR, -np.inf)), "non-finite"),
    ("NaN float32", lambda: pointclm.register(with_nan(CORR).astype(np.float32)), "non-finite"),
    ("NaN source", lambda: pointclm.register(with_nan(SRC), DST), "source_points.*non-finite"),
    ("NaN target", lambda: pointclm.register(SRC, with_nan(DST)), "target_points.*non-finite"),
    ("points no target", lambda: pointclm.register(SRC), "no target"),
    ("length mismatch", lambda: pointclm.register(SRC, DST[:-1]), "same length.*200 and 199"),
    ("target (N,2)", lambda: pointclm.register(SRC, DST[:, :2]), r"target_points.*\(N, 3\)"),
    ("target (N,6)", lambda: pointclm.register(SRC, CORR), r"target_points.*\(N, 3\)"),
    (
        "target= with (N,6)",  # used to be silently ignored
        lambda: pointclm.register(CORR, target=DST),
        r"target= goes with \(N, 3\) source points",
    ),
    ("ragged list", lambda: pointclm.register([[0.0] * 6, [0.0] * 5]), "could not be read"),
    ("strings", lambda: pointclm.register(CORR.astype(str)), "real numbers.*<U"),
    ("numeric strings", lambda: pointclm.register([["1"] * 6] * 5), "real numbers"),
    ("object", lambda: pointclm.register(CORR.astype(object)), "real numbers.*object"),
    ("complex", lambda: pointclm.register(CORR.astype(complex)), "real numbers.*complex"),
    ("bool", lambda: pointclm.register(CORR > 1), "real numbers.*bool"),
    ("datetime", lambda: pointclm.register(np.zeros((5, 6), "datetime64[s]")), "real numbers"),
]

FEATURE_CASES: list[tuple[str, Callable[[], Any], str]] = [
    ("too few rows", lambda: pointclm.register(CORR, FEATS[:-1]), "one row per corr.*200.*199"),
    ("too many rows", lambda: pointclm.register(CORR, np.ones((201, 8))), "one row per"),
    ("1-D", lambda: pointclm.register(CORR, FEATS[:, 0]), r"features.*\(N, D\)"),
    ("0 columns", lambda: pointclm.register(CORR, np.ones((200, 0))), "at least one column"),
    ("NaN", lambda: pointclm.register(CORR, with_nan(FEATS)), "features.*non-finite"),
    ("inf", lambda: pointclm.register(CORR, with_nan(FEATS, np.inf)), "features.*non-finite"),
    ("strings", lambda: pointclm.register(CORR, FEATS.astype(str)), "features.*real numbers"),
    ("complex", lambda: pointclm.register(CORR, FEATS.astype(complex)), "features.*real"),
]


@pytest.mark.parametrize(
    ("call", "match"), [c[1:] for c in REGISTER_CASES], ids=[c[0] for c in REGISTER_CASES]
)
def test_bad_correspondences(call: Callable[[], Any], match: str) -> None:
    with raises_value_error(match):
        call()


@pytest.mark.parametrize(
    ("call", "match"), [c[1:] for c in FEATURE_CASES], ids=[c[0] for c in FEATURE_CASES]
)
def test_bad_features(call: Callable[[], Any], match: str) -> None:
    with raises_value_error(match):
        call()


# --- config ---------------------------------------------------------------------------------

BAD_CONFIGS: list[tuple[dict[str, Any], str]] = [
    ({"sigma_d": -0.05}, "sigma_d"),
    ({"sigma_d": 0.0}, "sigma_d"),
    ({"sigma_d": float("nan")}, "sigma_d"),
    ({"sigma_d": float("inf")}, "sigma_d"),
    ({"sigma_d": "0.05"}, "sigma_d"),
    ({"sigma_d": True}, "sigma_d: expected a number"),  # bool is an int, hence was 1.0
    ({"sigma_d": 10**400}, "sigma_d.*too large"),
    ({"inlier_threshold": False}, "inlier_threshold: expected a number"),
    ({"tau_s": 1.5}, "tau_s"),
    ({"tau_s": 1.0}, "tau_s"),
    ({"tau_s": -2.0}, "tau_s"),
    ({"tau_n": -1}, "tau_n"),
    ({"tau_n": 10.0}, "tau_n.*int"),
    ({"tau_n": "10"}, "tau_n"),
    ({"tau_n": True}, "tau_n.*int"),
    ({"tau_n": 2**70}, "tau_n"),
    ({"beta_threshold": 1.0}, "beta_threshold"),
    ({"feature_threshold": 1.5}, "feature_threshold"),
    ({"min_cluster_size": 2}, "min_cluster_size"),
    ({"min_cluster_size": 10.5}, "min_cluster_size.*int"),
    ({"ransac_iterations": 0}, "ransac_iterations"),
    ({"ransac_iterations": 50.0}, "ransac_iterations.*int"),
    ({"kmeans_restarts": 0}, "kmeans_restarts"),
    ({"max_kept": 0}, "max_kept"),
    ({"max_instances": 0}, "max_instances"),
    ({"max_instances": 2.5}, "max_instances"),
    ({"max_instances": -1}, "max_instances"),
    ({"affinity_sigma": -1.0}, "affinity_sigma"),
    ({"inlier_threshold": 0.0}, "inlier_threshold"),
    ({"pruning": "foo"}, "pruning.*foo"),
    ({"pruning": None}, "pruning"),
    ({"assignment": "bar"}, "assignment.*bar"),
    ({"refine": 1}, "refine.*True or False"),
    ({"refine": "yes"}, "refine"),
    ({"merge_duplicates": None}, "merge_duplicates"),
]


@pytest.mark.parametrize(("fields", "match"), BAD_CONFIGS, ids=lambda v: repr(v)[:40])
def test_bad_config_values(fields: dict[str, Any], match: str) -> None:
    with raises_value_error(match):
        Config(**fields)
    with raises_value_error(match):  # the same check when the dict goes to register
        pointclm.register(CORR, config=fields)


def test_bad_config_containers() -> None:
    with raises_value_error(r"unknown config key.*'sigma'"):
        pointclm.register(CORR, config={"sigma": 0.1})
    with raises_value_error("unknown config key"):
        pointclm.register_batch([CORR], config={"ransac": 3})
    with raises_value_error("unknown config key"):
        staged.density_counts(CORR, config={"foo": 1})
    with raises_value_error("config must be a pointclm.Config, a dict or None"):
        pointclm.register(CORR, config=[("sigma_d", 0.1)])
    with raises_value_error("config must be"):
        pointclm.register(CORR, config="paper")


@pytest.mark.parametrize(
    "factor",
    [0.0, -1.0, float("nan"), float("inf"), 10**400, "2", None, True, 2j],
    ids=lambda v: repr(v)[:10],
)
def test_bad_scale_factor(factor: Any) -> None:
    with raises_value_error("scale factor must be a finite number > 0"):
        Config().scaled(factor)


# --- seed and threads -----------------------------------------------------------------------


@pytest.mark.parametrize("seed", [-1, 1.5, "0", None, True])
def test_bad_seed(seed: Any) -> None:
    with raises_value_error("seed must be a non-negative int"):
        pointclm.register(CORR, seed=seed)
    with raises_value_error("seed must be a non-negative int"):
        pointclm.register_batch([CORR], seed=seed)


@pytest.mark.parametrize(
    ("num_threads", "match"),
    [
        (0, "must be an int >= 1"),
        (-1, "must be an int >= 1"),
        (1.0, "must be an int >= 1"),
        ("2", "must be an int >= 1"),
        (True, "must be an int >= 1"),
        (2**70, "is too large"),  # used to be an OverflowError
    ],
    ids=repr,
)
def test_bad_num_threads(num_threads: Any, match: str) -> None:
    with raises_value_error(f"num_threads {match}"):
        pointclm.register(CORR, num_threads=num_threads)
    with raises_value_error(f"num_threads {match}"):
        pointclm.register_batch([CORR], num_threads=num_threads)
    with raises_value_error(f"num_threads {match}"):
        staged.density_counts(CORR, num_threads=num_threads)


# --- register_batch -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bad", "match"),
    [
        (CORR[:, :5], r"scene 2: correspondences must have shape \(N, 6\)"),
        (with_nan(CORR), "scene 2: correspondences has a non-finite value"),
        (CORR[:2], "scene 2: need at least 3"),
        ((SRC, DST[:-3]), "scene 2: source_points and target_points must have the same length"),
        ((CORR, FEATS[:-1]), "scene 2: features must have one row per correspondence"),
        ((CORR, with_nan(FEATS)), "scene 2: features has a non-finite"),
        (SRC, "scene 2: got .N, 3. points but no target"),
        (None, "scene 2: correspondences must hold real numbers"),
        ("scene", "scene 2: correspondences must hold real numbers"),
    ],
    ids=[
        "N5",
        "NaN",
        "N2",
        "pair-mismatch",
        "feature-rows",
        "feature-NaN",
        "points",
        "None",
        "str",
    ],
)
def test_batch_names_the_bad_scene(bad: Any, match: str) -> None:
    with raises_value_error(match):
        pointclm.register_batch([CORR, (SRC, DST), bad, CORR])


@pytest.mark.parametrize(
    ("scenes", "match"),
    [
        (CORR, r"list of scenes, got one \(200, 6\) array"),  # rows would become scenes
        (5, "iterable of scenes"),
        (None, "iterable of scenes"),
    ],
    ids=["one-array", "int", "None"],
)
def test_batch_bad_container(scenes: Any, match: str) -> None:
    with raises_value_error(match):
        pointclm.register_batch(scenes)


def test_batch_bad_scene_object() -> None:
    class Scene:
        correspondences = with_nan(CORR)

    with raises_value_error("scene 1: correspondences has a non-finite"):
        pointclm.register_batch([CORR, Scene()])


# --- staged functions -----------------------------------------------------------------------

SYM = RNG.uniform(size=(6, 6))
SYM = (SYM + SYM.T) / 2
ASYM = SYM.copy()
ASYM[0, 3] += 0.5
NAN_SYM = SYM.copy()
NAN_SYM[1, 2] = NAN_SYM[2, 1] = np.nan

MATRIX_FUNCS = {
    "eigh": staged.eigh,
    "normalized_laplacian": staged.normalized_laplacian,
    "spectral_clustering": staged.spectral_clustering,
}


@pytest.mark.parametrize("name", list(MATRIX_FUNCS))
@pytest.mark.parametrize(
    ("matrix", "match"),
    [
        (np.ones((4, 5)), r"square matrix.*\(4, 5\)"),
        (ASYM, "not symmetric"),
        (NAN_SYM, "non-finite"),
        (np.where(SYM > 0.9, np.inf, SYM), "non-finite"),
        (np.ones(5), "shape"),
        (np.ones((2, 2, 2)), "shape"),
        (SYM.astype(complex), "real numbers"),
    ],
    ids=["non-square", "asymmetric", "NaN", "inf", "1-D", "3-D", "complex"],
)
def test_staged_bad_matrices(name: str, matrix: np.ndarray, match: str) -> None:
    with raises_value_error(match):
        MATRIX_FUNCS[name](matrix)


@pytest.mark.parametrize("name", ["normalized_laplacian", "spectral_clustering"])
def test_negative_affinity(name: str) -> None:
    with raises_value_error("non-negative"):
        MATRIX_FUNCS[name](-SYM)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_clusters": 0}, "n_clusters"),
        ({"n_clusters": -1}, "n_clusters"),
        ({"n_clusters": 2.5}, "n_clusters"),
        ({"max_clusters": 0}, "max_clusters"),
        ({"restarts": 0}, "restarts"),
        ({"seed": -1}, "seed"),
        ({"assignment": "bar"}, "assignment.*bar"),
        ({"assignment": None}, "assignment must be 'kmeans' or 'discretize'"),
        ({"restarts": 2**70}, "restarts is too large"),  # these three were OverflowErrors
        ({"n_clusters": 2**70}, "n_clusters is too large"),
        ({"max_clusters": 2**70}, "max_clusters is too large"),
    ],
    ids=lambda v: repr(v)[:30],
)
def test_spectral_clustering_bad_arguments(kwargs: dict[str, Any], match: str) -> None:
    with raises_value_error(match):
        staged.spectral_clustering(SYM, **kwargs)


@pytest.mark.parametrize(
    ("source", "target", "match"),
    [
        (np.outer(np.arange(6.0), [1.0, 2.0, 3.0]), None, "collinear"),
        (np.ones((5, 3)), None, "collinear or coincident"),
        (SRC[:2], DST[:2], "at least 3"),
        (SRC, DST[:-1], "same length"),
        (with_nan(SRC), DST, "non-finite"),
        (CORR, DST, r"source.*\(N, 3\)"),
        (SRC[:, :2], DST[:, :2], r"\(N, 3\)"),
    ],
    ids=["collinear", "coincident", "N2", "mismatch", "NaN", "N6-source", "2-D points"],
)
def test_kabsch_bad_inputs(source: np.ndarray, target: np.ndarray | None, match: str) -> None:
    with raises_value_error(match):
        staged.kabsch(source, source if target is None else target)


def test_staged_correspondence_checks() -> None:
    with raises_value_error(r"shape \(N, 6\)"):
        staged.spatial_consistency(CORR[:, :5])
    with raises_value_error("non-finite"):
        staged.spatial_consistency(with_nan(CORR))
    for sigma in (0.0, -1.0, float("nan"), "x", None):
        with raises_value_error("sigma_d"):
            staged.spatial_consistency(CORR, sigma)  # type: ignore[arg-type]
    with raises_value_error("one row per correspondence"):
        staged.density_counts(CORR, FEATS[:10])
    with raises_value_error("non-finite"):
        staged.density_counts(with_nan(CORR))


def test_too_many_threads_and_clusters() -> None:
    corr = make_scene(0, n_keep=50).correspondences
    with raises_value_error("num_threads must"):
        pointclm.register(corr, num_threads=10_000)
    affinity = np.eye(6) + 1e-3
    with raises_value_error("n_clusters"):
        staged.spectral_clustering(affinity, 7)
    with raises_value_error("below 2"):
        pointclm.register(corr, seed=2**64)
