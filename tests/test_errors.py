"""Typed exceptions (`pointclm.errors`): each error of the Rust core that Python can trigger
raises its class from the binding, with the core's message and still a ValueError; a missing
file is a FileNotFoundError in io, datasets and weights alike; the hierarchy is as documented.
"""

from __future__ import annotations

import errno
import json
import pickle
import shutil
import struct
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pointclm
import pytest
from pointclm import _core, preprocessing, staged
from pointclm.datasets import BinParams, load_mesh, load_shape, make_bin_scene, modelnet40_shapes
from pointclm.errors import (
    ConfigError,
    InputError,
    NumericalError,
    PathNotFoundError,
    PointclmError,
    WeightsError,
    WeightsNotFoundError,
)
from pointclm.model import SHIPPED, load_metadata, load_network

CORR = np.random.default_rng(0).uniform(size=(50, 6))
PTS = CORR[:, :3].copy()


def _with_nan(a: np.ndarray) -> np.ndarray:
    b = a.copy()
    b[7, 1] = np.nan
    return b


def _raises(cls: type[BaseException], match: str, call: Callable[[], Any]) -> BaseException:
    """`call()` raises exactly `cls` (not a subclass, not the base) matching `match`."""
    with pytest.raises(cls, match=match) as info:
        call()
    assert type(info.value) is cls, f"{type(info.value).__name__}: {info.value}"
    return info.value


# --- the hierarchy --------------------------------------------------------------------------


def test_every_class_is_a_value_error_under_one_base() -> None:
    for cls in (InputError, ConfigError, NumericalError, WeightsError, PathNotFoundError):
        assert cls.__bases__[-1] is PointclmError
    assert PointclmError.__bases__ == (ValueError,)
    assert issubclass(WeightsNotFoundError, WeightsError)
    assert issubclass(WeightsNotFoundError, PathNotFoundError)
    for cls in (PathNotFoundError, WeightsNotFoundError):
        assert issubclass(cls, FileNotFoundError) and issubclass(cls, ValueError)
    for cls in (InputError, ConfigError, NumericalError, WeightsError):
        assert not issubclass(cls, OSError)
    assert issubclass(pointclm.errors.ViewpointDisagreementWarning, UserWarning)
    assert sorted(pointclm.errors.__all__) == sorted(
        c.__name__
        for c in (
            pointclm.errors.ViewpointDisagreementWarning,
            PointclmError,
            InputError,
            ConfigError,
            NumericalError,
            WeightsError,
            PathNotFoundError,
            WeightsNotFoundError,
        )
    )


def test_a_missing_path_error_fills_errno_and_filename_and_pickles() -> None:
    e = PathNotFoundError(errno.ENOENT, "no such point cloud file", "/x/a.ply")
    assert (e.errno, e.filename) == (errno.ENOENT, "/x/a.ply")
    assert str(e) == "[Errno 2] no such point cloud file: '/x/a.ply'"
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is PathNotFoundError and back.filename == "/x/a.ply"
    w = pickle.loads(pickle.dumps(WeightsNotFoundError("no weights at m: gone")))
    assert type(w) is WeightsNotFoundError and str(w) == "no weights at m: gone"


def test_errors_and_io_are_reachable_after_import_pointclm_alone() -> None:
    code = (
        "import sys, pointclm\n"
        "assert 'io' in dir(pointclm) and 'errors' in dir(pointclm)\n"
        "assert pointclm.io.read_point_cloud and pointclm.io.write_ply\n"
        "assert pointclm.errors.InputError.__module__ == 'pointclm.errors'\n"
        "heavy = {'torch', 'open3d', 'scipy', 'trimesh', 'matplotlib'} & set(sys.modules)\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


# --- every core variant Python can reach -----------------------------------------------------
# (EigenNoConvergence and ThreadPool need a failing eigensolver or an OS refusing threads;
# Allocation is MemoryError and Cancelled KeyboardInterrupt, unchanged.)

CORE_ERRORS = [
    (InputError, r"need at least 3 correspondences, got 2", lambda: _core.register(CORR[:2])),
    (
        InputError,
        r"correspondences has a non-finite value \(NaN or inf\) in row 7",
        lambda: _core.register(_with_nan(CORR)),
    ),
    (
        InputError,
        r"features has a non-finite value",
        lambda: _core.register(CORR, features=_with_nan(CORR)),
    ),
    (
        InputError,
        r"feature rows \(one per correspondence\): expected 50, got 49",
        lambda: _core.register(CORR, features=CORR[:-1]),
    ),
    (
        InputError,
        r"points to downsample: need at least 1 points, got 0",
        lambda: _core.voxel_downsample(np.empty((0, 3)), 0.1),
    ),
    (
        InputError,
        r"invalid parameter: voxel_size = -1",
        lambda: _core.voxel_downsample(PTS, -1.0),
    ),
    (
        InputError,
        r"invalid matrix: not symmetric",
        lambda: _core.normalized_laplacian(np.triu(np.ones((4, 4)))),
    ),
    (
        InputError,
        r"^source descriptors: .*non-finite",
        lambda: _core.match_features(_with_nan(CORR), CORR),
    ),
    (
        ConfigError,
        r"invalid config: sigma_d = -1",
        lambda: _core.validate_config({"sigma_d": -1.0}),
    ),
    (
        ConfigError,
        r"invalid config: max_rounds = 1000 \(must lie in",
        lambda: _core.validate_config({"max_rounds": 1000}),
    ),
    (
        NumericalError,
        r"magnitudes from .* span more than f64",
        lambda: _core.register(np.where(np.arange(6) == 0, 1e250, CORR)),
    ),
]


@pytest.mark.parametrize(
    ("cls", "match", "call"),
    CORE_ERRORS,
    ids=[
        "TooFewCorrespondences",
        "NonFinite",
        "NonFinite-features",
        "LengthMismatch",
        "TooFewPoints",
        "InvalidParameter",
        "InvalidMatrix",
        "named-argument",
        "InvalidConfig",
        "ConfigOutOfRange",
        "MagnitudeRange",
    ],
)
def test_core_errors_raise_their_class(
    cls: type[PointclmError], match: str, call: Callable[[], Any]
) -> None:
    e = _raises(cls, match, call)
    assert isinstance(e, PointclmError) and isinstance(e, ValueError)


def test_the_public_api_raises_the_core_classes() -> None:
    _raises(ConfigError, "invalid config: max_rounds", lambda: pointclm.Config(max_rounds=1000))
    corr = np.where(np.arange(6) == 0, 1e250, CORR)
    _raises(NumericalError, "magnitudes", lambda: pointclm.register(corr))
    with pytest.raises(ValueError, match="magnitudes"):  # today's `except ValueError` still works
        pointclm.register(corr)


# --- the binding's own checks --------------------------------------------------------------


@pytest.mark.parametrize(
    ("cls", "match", "call"),
    [
        (InputError, r"correspondences must have shape \(N, 6\)", lambda: _core.register(PTS)),
        (InputError, r"seed must be an int", lambda: _core.register(CORR, seed=-1)),
        (InputError, r"num_threads must be an int", lambda: _core.register(CORR, num_threads=0)),
        (
            InputError,
            r"network must be a pointclm.Network",
            lambda: _core.register(CORR, network=1),
        ),
        (InputError, r"give exactly one of towards=", lambda: _core.estimate_normals(PTS, 0.1)),
        (
            InputError,
            r"transformations must have shape",
            lambda: _core.refine_poses(PTS, PTS, np.zeros((1, 3, 3)), 0.1, False, None),
        ),
        (
            InputError,
            r"viewpoint must be 3 finite numbers",
            lambda: _core.looks_like_one_view(PTS, None, 0.1),
        ),
        (
            InputError,
            r"rank = 30 \(must be below the number of points\)",
            lambda: _core.edge_on_scores(PTS[:30], PTS[:30], PTS[:2], 30),
        ),
        (
            InputError,
            r"normals \(one per point\): expected 30, got 29",
            lambda: _core.edge_on_scores(PTS[:30], PTS[:29], PTS[:2], 0),
        ),
        (InputError, r"path must be a str", lambda: _core.Network(3)),
        (
            ConfigError,
            r'unknown config field "nope"',
            lambda: _core.register(CORR, config={"nope": 1}),
        ),
        (ConfigError, r"config must be a dict or None", lambda: _core.register(CORR, config=[1])),
        (ConfigError, r"config field pruning", lambda: _core.validate_config({"pruning": "x"})),
        (
            ConfigError,
            r"^config field assignment: expected",
            lambda: _core.validate_config({"assignment": "x"}),
        ),
        (
            InputError,
            r"^assignment: expected",
            lambda: _core.spectral_clustering(np.eye(3), assignment="x"),
        ),
    ],
)
def test_binding_checks_raise_the_same_classes(
    cls: type[PointclmError], match: str, call: Callable[[], Any]
) -> None:
    _raises(cls, match, call)


def test_a_batch_names_the_scene_and_keeps_the_class() -> None:
    e = _raises(
        InputError,
        r"^scene 1: need at least 3 correspondences, got 2$",
        lambda: _core.register_batch([(CORR, None), (CORR[:2], None)]),
    )
    assert isinstance(e, ValueError)
    _raises(
        InputError,
        r"^scene 0: correspondences must have shape",
        lambda: _core.register_batch([(PTS, None)]),
    )
    _raises(
        ConfigError,
        r"invalid config",
        lambda: _core.register_batch([(CORR, None)], config={"sigma_d": 0.0}),
    )


# --- the Python layer's own checks -----------------------------------------------------------


@pytest.mark.parametrize(
    ("cls", "match", "call"),
    [
        (
            InputError,
            r"^need at least 3 correspondences, got 2$",
            lambda: pointclm.register(CORR[:2]),
        ),
        (InputError, r"got \(N, 3\) points but no target", lambda: pointclm.register(PTS)),
        (InputError, r"features must have one row", lambda: pointclm.register(CORR, CORR[:5])),
        (InputError, r"seed must be a non-negative int", lambda: pointclm.register(CORR, seed=-1)),
        (
            InputError,
            r"need at least 3 point pairs",
            lambda: staged.kabsch(PTS[:2], PTS[:2]),
        ),
        (
            InputError,
            r"voxel_size must be a positive finite number",
            lambda: preprocessing.voxel_downsample(PTS, -1.0),
        ),
        (
            ConfigError,
            r"^config field sigma_d: expected a number",
            lambda: pointclm.Config(sigma_d=True),
        ),
        (ConfigError, r"^config field tau_n: must be >= 0", lambda: pointclm.Config(tau_n=-1)),
        (
            ConfigError,
            r"unknown config key\(s\) \['nope'\]",
            lambda: pointclm.register(CORR, config={"nope": 1}),
        ),
    ],
    ids=[
        "too-few",
        "no-target",
        "features",
        "seed",
        "kabsch",
        "voxel",
        "bool-field",
        "negative",
        "key",
    ],
)
def test_python_checks_raise_the_typed_classes(
    cls: type[PointclmError], match: str, call: Callable[[], Any]
) -> None:
    e = _raises(cls, match, call)
    assert isinstance(e, ValueError)


class _LazyScene:
    """A scene that reads its file when its correspondences are first asked for."""

    def __init__(self, error: ValueError) -> None:
        self.error = error

    @property
    def correspondences(self) -> np.ndarray:
        raise self.error


class _TwoPartError(ValueError):
    def __init__(self, what: str, why: str) -> None:
        super().__init__(f"{what}: {why}")


def test_a_python_batch_error_names_the_scene_and_keeps_the_class() -> None:
    _raises(
        InputError,
        r"^scene 1: need at least 3 correspondences, got 2$",
        lambda: pointclm.register_batch([CORR, CORR[:2]]),
    )
    missing = PathNotFoundError(errno.ENOENT, "no such point cloud file", "/x/a.ply")
    e = _raises(
        PathNotFoundError,
        r"^scene 0: \[Errno 2\] no such point cloud file: '/x/a.ply'$",
        lambda: pointclm.register_batch([_LazyScene(missing)]),
    )
    assert isinstance(e, FileNotFoundError)
    # A class that cannot be rebuilt from one message still reaches `except ValueError`.
    _raises(
        ValueError,
        r"^scene 0: a: b$",
        lambda: pointclm.register_batch([_LazyScene(_TwoPartError("a", "b"))]),
    )


# --- weights ------------------------------------------------------------------------------


def _copy_shipped(tmp_path: Path, name: str) -> Path:
    dst = tmp_path / f"{name}.safetensors"
    shutil.copy(SHIPPED["default"], dst)
    shutil.copy(SHIPPED["default"].with_suffix(".json"), dst.with_suffix(".json"))
    return dst


def _rename_tensor(path: Path, old: str, new: str) -> None:
    """Rename a tensor in the safetensors header (same length: offsets stay valid)."""
    assert len(old) == len(new)
    raw = path.read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    header = raw[8 : 8 + n].replace(f'"{old}"'.encode(), f'"{new}"'.encode())
    path.write_bytes(raw[:8] + header + raw[8 + n :])


def test_weight_errors_raise_their_class(tmp_path: Path) -> None:
    missing = tmp_path / "missing.safetensors"
    e = _raises(
        WeightsNotFoundError,
        r"no weights at .*missing\.safetensors",
        lambda: pointclm.Network(missing),
    )
    assert isinstance(e, FileNotFoundError) and isinstance(e, ValueError)
    _raises(WeightsNotFoundError, "no weights at", lambda: load_network(missing))

    corrupt = _copy_shipped(tmp_path, "corrupt")
    corrupt.write_bytes(b"not a safetensors file")
    _raises(
        WeightsError,
        "malformed weights .*not a safetensors file",
        lambda: pointclm.Network(corrupt),
    )
    renamed = _copy_shipped(tmp_path, "renamed")
    _rename_tensor(renamed, "lift.weight", "lift.weighz")
    _raises(WeightsError, r"lack tensor lift\.weight", lambda: pointclm.Network(renamed))
    wide = _copy_shipped(tmp_path, "wide")
    meta = json.loads(wide.with_suffix(".json").read_text())
    meta["architecture"]["width"] = 32
    wide.with_suffix(".json").write_text(json.dumps(meta))
    _raises(WeightsError, r"tensor lift\.weight has shape", lambda: pointclm.Network(wide))


def test_weight_metadata_errors(tmp_path: Path) -> None:
    _raises(
        WeightsNotFoundError,
        "unreadable weight metadata",
        lambda: load_metadata(tmp_path / "missing.safetensors"),
    )
    bad = _copy_shipped(tmp_path, "bad")
    bad.with_suffix(".json").write_text("[1]")
    _raises(WeightsError, "expected a JSON object", lambda: load_metadata(bad))
    _raises(InputError, "model must be a shipped name", lambda: load_metadata(3))  # type: ignore[arg-type]


def test_load_model_missing_file_is_file_not_found(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    from pointclm.model import load_model

    _raises(WeightsNotFoundError, "no weights at", lambda: load_model(tmp_path / "m.safetensors"))


# --- a missing file is FileNotFoundError everywhere ----------------------------------------


def test_a_missing_file_in_io(tmp_path: Path) -> None:
    missing = tmp_path / "a.ply"
    e = _raises(
        PathNotFoundError, "no such point cloud file", lambda: pointclm.io.read_point_cloud(missing)
    )
    assert (e.errno, e.filename) == (errno.ENOENT, str(missing))  # type: ignore[attr-defined]
    _raises(PathNotFoundError, "no such", lambda: pointclm.io.load_points(tmp_path / "a.xyz"))
    _raises(PathNotFoundError, "no such", lambda: pointclm.io.read_open3d_feature(missing))


def test_a_missing_file_in_datasets(tmp_path: Path) -> None:
    _raises(PathNotFoundError, "no such file", lambda: load_mesh(tmp_path / "a.ply"))
    _raises(PathNotFoundError, "neither a known shape", lambda: load_shape(str(tmp_path / "a.ply")))
    _raises(
        PathNotFoundError,
        "data folder does not exist",
        lambda: load_shape("nothing", data_dir=tmp_path / "nowhere"),
    )
    _raises(PathNotFoundError, "no ply_data_test", lambda: modelnet40_shapes(tmp_path))
    (tmp_path / "test_files.txt").write_text("ply_data_test0.h5\n")
    _raises(PathNotFoundError, "are missing", lambda: modelnet40_shapes(tmp_path))
    params = BinParams(model="common3d/nothing", data_dir=str(tmp_path))
    _raises(PathNotFoundError, "no mesh at", lambda: make_bin_scene(0, params))
    # an unknown name is not a missing file
    _raises(ValueError, "neither a known shape", lambda: load_shape("no-such-shape"))
