"""`register_point_clouds(proposals=...)`: model faces laid on the scan's planar patches join
the descriptors' proposals for models made of large flat faces ("auto" decides by the model's
share of such faces), judged by the same verification."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from pointclm import _core, cli
from pointclm.batch.options import check_options
from pointclm.datasets.bins import make_bin_scene
from pointclm.errors import InputError
from test_bins import TINY  # a few procedural boxes in a bin: about a second per registration


@pytest.fixture(scope="module")
def boxes():
    return make_bin_scene(0, TINY)


def _blob(n: int = 2000) -> np.ndarray:
    """A bumpy closed surface: no flat face anywhere."""
    i = np.arange(n) + 0.5
    th, z = i * 2.399963, 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    d = np.stack([r * np.cos(th), r * np.sin(th), z], axis=1)
    bump = 1.0 + 0.3 * np.sin(3 * d[:, 0]) * np.cos(2 * d[:, 1]) + 0.2 * d[:, 2]
    return d * bump[:, None]


def _core_call(model: np.ndarray, scan: np.ndarray, proposals: str, **kw) -> dict:
    return _core.register_scan(model, scan, proposals=proposals, num_threads=1, **kw)


def test_auto_lays_faces_for_boxes_and_not_for_a_curved_model(boxes) -> None:
    args = dict(voxel_size=boxes.voxel_size, viewpoint=tuple(boxes.sensor))
    box = _core_call(boxes.model_points, boxes.scan, "auto", **args)
    assert box["face_proposals"] and box["planar_share"] >= 0.5
    assert any(len(p["faces"]) for p in box["passes"])
    model = _blob()
    scan = np.concatenate([model, model + [4.0, 0.0, 0.0]])
    blob = _core_call(model, scan, "auto")
    assert not blob["face_proposals"] and blob["planar_share"] < 0.5
    assert all(len(p["faces"]) == 0 for p in blob["passes"])
    plain = _core_call(model, scan, "descriptors")
    assert np.isnan(plain["planar_share"])
    np.testing.assert_array_equal(blob["transformations"], plain["transformations"])


def test_faces_are_judged_like_every_proposal(boxes) -> None:
    """Every copy returned with faces is one verification kept: its visible side explained."""
    reg = pointclm.register_point_clouds(
        boxes.model_points,
        boxes.scan,
        voxel_size=boxes.voxel_size,
        viewpoint=boxes.sensor,
        proposals="faces",
        num_threads=1,
    )
    assert len(reg.instances) >= 1
    assert all(c.visible_fitness >= 0.5 for c in reg.instances)
    again = pointclm.register_point_clouds(
        boxes.model_points,
        boxes.scan,
        voxel_size=boxes.voxel_size,
        viewpoint=boxes.sensor,
        proposals="faces",
        num_threads=2,
    )
    np.testing.assert_array_equal(reg.transformations, again.transformations)


@pytest.mark.parametrize("bad", ["planes", "", None, 1])
def test_a_bad_value_is_a_value_error(bad) -> None:
    model = _blob(200)
    with pytest.raises(ValueError, match="proposals must be"):
        pointclm.register_point_clouds(model, model, proposals=bad)
    with pytest.raises(InputError, match="proposals must be"):
        check_options({"proposals": bad})
    if isinstance(bad, str):
        with pytest.raises(ValueError, match="proposals"):
            _core.register_scan(model, model, proposals=bad)


def test_the_command_line_passes_the_choice() -> None:
    args = cli.build_parser().parse_args(["register", "m.ply", "s.ply", "--proposals", "faces"])
    assert cli._method_options(args, lambda: np.zeros((10, 3)))["proposals"] == "faces"
    default = cli.build_parser().parse_args(["register", "m.ply", "s.ply"])
    assert cli._method_options(default, lambda: np.zeros((10, 3)))["proposals"] == "auto"
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["register", "m.ply", "s.ply", "--proposals", "planes"])
