"""A scan whose descriptors leave fewer than 3 matches is an answer, not an error: the result
is empty (or holds what the face proposals, which need no matches, found), and its diagnosis
says how few matches survived and what to try. Bad input still raises."""

from __future__ import annotations

import numpy as np
import pointclm
import pytest
from helpers import box_surface
from pointclm.datasets import load_shape
from pointclm.errors import InputError

#: A box's size; no face tiles another (flush copies of one face never make up another).
SIZE = (0.16, 0.1, 0.045)
SENSOR = (0.0, 0.0, 1.0)


@pytest.fixture(scope="module")
def bunny() -> np.ndarray:
    return load_shape("bunny", 3000)


def _floor(extent: float, step: float) -> np.ndarray:
    """A flat square: every point's FPFH is the same, so the mutual check keeps one or two
    pairs."""
    g = np.arange(0.0, extent, step)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


@pytest.mark.parametrize("refine", [True, False])
def test_a_flat_scan_of_no_bunny_is_an_empty_result_saying_why(bunny, refine) -> None:  # type: ignore[no-untyped-def]
    d = float(np.linalg.norm(np.ptp(bunny, axis=0)))
    reg = pointclm.register_point_clouds(bunny, _floor(2 * d, d / 60), refine=refine, num_threads=1)
    assert reg.instances == [] and reg.ambiguous == [] and len(reg.transformations) == 0
    (first,) = reg.passes
    assert first.matches is not None and first.matches < 3
    assert reg.correspondences.shape == (0, 6) and len(reg.result) == 0
    assert reg.diagnosis.startswith(
        f"nothing found: only {first.matches} descriptor match(es) survived matching "
        "(3 needed for a pose)"
    )
    assert "try a smaller voxel_size or mutual=False" in reg.diagnosis
    assert "note: nothing found: only" in repr(reg)


def test_a_box_with_too_few_matches_is_still_found_by_its_faces() -> None:
    box = box_surface(SIZE)
    top = box[box[:, 2] > SIZE[2] / 2 - 1e-9]  # what the sensor above sees
    reg = pointclm.register_point_clouds(box, top, viewpoint=SENSOR, num_threads=1)
    assert reg.passes[0].matches < 3 and len(reg.passes[0].faces) > 0
    (copy,) = reg.instances
    assert copy.matches is None and reg.diagnosis == ""
    posed = box @ copy.rotation.T + copy.translation
    # Where the box is, whatever its half turns: the same extent, below what the sensor saw.
    np.testing.assert_allclose(posed.min(axis=0), box.min(axis=0), atol=2 * reg.voxel_size)
    np.testing.assert_allclose(posed.max(axis=0), box.max(axis=0), atol=2 * reg.voxel_size)
    plain = pointclm.register_point_clouds(
        box, top, viewpoint=SENSOR, proposals="descriptors", num_threads=1
    )
    assert plain.instances == []
    assert "or proposals='faces' for a part made of large flat faces" in plain.diagnosis


def test_several_models_answer_each_for_itself(bunny) -> None:  # type: ignore[no-untyped-def]
    box = box_surface(SIZE)
    top = box[box[:, 2] > SIZE[2] / 2 - 1e-9]
    found = pointclm.register_models([bunny, box], top, viewpoint=SENSOR, num_threads=1)
    assert [len(r.instances) for r in found] == [0, 1]
    assert "descriptor match(es) survived matching" in found[0].diagnosis


def test_bad_input_still_raises(bunny) -> None:  # type: ignore[no-untyped-def]
    floor = _floor(0.3, 0.005)
    floor[7, 2] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        pointclm.register_point_clouds(bunny, floor, num_threads=1)
    with pytest.raises(InputError, match="need at least 3 points"):
        pointclm.register_point_clouds(bunny, floor[:2], num_threads=1)
