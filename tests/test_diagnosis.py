"""A diagnosis names, for the candidates verification rejected, the rule that rejected each,
its measured value and the threshold, and never quotes as a reason a value that passes.

Each rule is made to reject by forcing its threshold through the core's declared rules
(`RefinementContext.rejections`), on small clouds built here."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pointclm
import pytest
from pointclm.clouds.diagnosis import _diagnose, explain_rejections, miss_text
from pointclm.refinement import MAX_SHARED, MIN_RELATIVE_FITNESS, Rejection

EYE = (0.0, 0.0, 5.0)


def _sphere(n: int = 800, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _shifted(x: float = 0.0, z: float = 0.0) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, 0.0, z)
    return t


SPHERE = _sphere()
CAP = SPHERE[SPHERE[:, 2] > 0]  # what a sensor above sees of the sphere
QUARTER = SPHERE[(SPHERE[:, 2] > 0) & (SPHERE[:, 0] > 0)]
# The quarter over a floor: the rest of the cap lies where the sensor looked (a scan that ended
# at the quarter's edge would say nothing of it).
_GRID = np.arange(-3.0, 3.05, 0.1)
FLOOR = np.stack([*np.meshgrid(_GRID, _GRID), np.full((len(_GRID),) * 2, -1.5)], -1).reshape(-1, 3)
QUARTER_ON_FLOOR = np.vstack([QUARTER, FLOOR])
OFF = {"min_seen": 0.0, "min_visible_fitness": 0.0, "max_contradiction": 1.0}

# (rule, scan, viewpoint, poses, forced rules): the rule that must reject the first pose.
CASES = [
    ("min_fitness", CAP, None, [np.eye(4)], {"min_fitness": 0.9}),
    ("min_relative_fitness", SPHERE, None, [np.eye(4), _shifted(x=1.2)], {}),
    ("max_shared", SPHERE, None, [np.eye(4), np.eye(4)], {}),
    ("explains_nothing", SPHERE, None, [_shifted(x=10.0)],
     {"min_fitness": 0.0, "min_relative_fitness": 0.0}),
    ("min_seen", CAP, EYE, [np.eye(4)], {"min_seen": 0.9}),
    ("min_visible_fitness", QUARTER_ON_FLOOR, EYE, [np.eye(4)], {"min_visible_fitness": 0.8}),
    ("max_contradiction", CAP, EYE, [_shifted(z=0.4)],
     {"min_seen": 0.0, "min_visible_fitness": 0.0, "max_contradiction": 0.05}),
]  # fmt: skip

#: "<value> < <threshold> (<rule>" or with ">" for a ceiling, as a diagnosis writes a miss.
MISS = re.compile(r"(\d+\.\d+) ([<>]) (\d+\.\d+) \((\w+)")


def _quoted_misses(text: str) -> list[tuple[float, str, float, str]]:
    return [(float(v), op, float(t), rule) for v, op, t, rule in MISS.findall(text)]


def _assert_every_quote_misses(text: str) -> None:
    for value, op, threshold, rule in _quoted_misses(text):
        assert (value > threshold) if op == ">" else (value < threshold), (rule, text)


@pytest.mark.parametrize(("rule", "scan", "viewpoint", "poses", "forced"), CASES)
def test_each_rule_is_named_with_its_value_and_threshold(
    rule, scan, viewpoint, poses, forced
) -> None:  # type: ignore[no-untyped-def]
    context = pointclm.RefinementContext(SPHERE, scan, 0.1, viewpoint=viewpoint)
    rejected = context.rejections(np.stack(poses), icp=False, **forced)
    mine = [r for r in rejected if r.rule == rule]
    assert mine, f"{rule} rejected nothing: {rejected}"
    text = explain_rejections(rejected, len(poses), forced)
    assert f"1 by {rule} (" in text
    r = mine[0]
    assert f"candidate {r.origin}, " in text
    if rule == "explains_nothing":
        assert "explains no scan point (explains_nothing" in text
        return
    (quoted,) = [q for q in _quoted_misses(text) if q[3] == rule]
    value, op, threshold, _ = quoted
    assert value == pytest.approx(r.value, abs=0.006)
    assert threshold == pytest.approx(r.threshold, abs=0.006)
    expected = {**{"max_shared": MAX_SHARED}, **forced}.get(rule)
    if expected is not None:
        assert threshold == pytest.approx(expected)
    _assert_every_quote_misses(text)


def test_the_relative_rule_names_the_best_candidates_fitness() -> None:
    context = pointclm.RefinementContext(SPHERE, SPHERE, 0.1)
    rejected = context.rejections(np.stack([np.eye(4), _shifted(x=1.2)]), icp=False)
    text = explain_rejections(rejected, 2)
    assert (
        f"(min_relative_fitness: {MIN_RELATIVE_FITNESS:g} x the best candidate's fitness 1.000)"
        in text
    )


def test_rounding_never_makes_a_miss_read_as_a_pass() -> None:
    # 0.2996 against 0.30 would print 0.30 < 0.30 at two decimals.
    assert miss_text("min_visible_fitness", 0.2996, 0.3, {}) == (
        "visible fitness 0.2996 < 0.3000 (min_visible_fitness)"
    )
    assert miss_text("max_contradiction", 0.0304, 0.03, {}) == (
        "contradiction 0.0304 > 0.0300 (max_contradiction)"
    )
    assert (
        miss_text("min_seen", float("nan"), 0.1, {})
        == "seen not measurable (min_seen needs >= 0.10)"
    )


def test_a_verdict_that_passes_its_threshold_is_never_quoted() -> None:
    passing = Rejection(0, "min_visible_fitness", 0.9, 0.3)
    failing = Rejection(1, "max_contradiction", 0.2, 0.05)
    text = explain_rejections([passing, failing], 2)
    assert "min_visible_fitness" not in text and "0.90" not in text
    assert "candidate 1, contradiction 0.20 > 0.05 (max_contradiction)" in text
    assert explain_rejections([passing], 1) == ""


def test_the_nearest_misses_come_first_with_one_per_rule() -> None:
    rejections = [
        Rejection(0, "min_visible_fitness", 0.10, 0.85),
        Rejection(1, "min_visible_fitness", 0.80, 0.85),
        Rejection(2, "min_visible_fitness", 0.50, 0.85),
        Rejection(3, "min_visible_fitness", 0.20, 0.85),
        Rejection(4, "max_contradiction", 0.5, 0.03),
    ]
    text = explain_rejections(rejections, 5)
    assert text.startswith("4 by min_visible_fitness (") and ", 1 by max_contradiction (" in text
    named = [int(k) for k in re.findall(r"candidate (\d+),", text)]
    assert named == [1, 4, 2]  # each rule's nearest miss, then the next nearest
    _assert_every_quote_misses(text)


def test_an_empty_result_says_which_rule_rejected_each_candidate() -> None:
    # The diagnosis of a run, its refinement context asking with a forced rule.
    context = pointclm.RefinementContext(SPHERE, CAP, 0.1, viewpoint=EYE)

    class Forced:
        def rejections(self, poses, **kwargs):  # type: ignore[no-untyped-def]
            return context.rejections(poses, icp=False, min_seen=0.9, **kwargs)

    run = SimpleNamespace(viewpoint=EYE, unconfirmed=None, voxel=0.1, num_threads=1,
                          refiner=Forced())  # fmt: skip
    first = _Pass(np.stack([np.eye(4), _shifted(z=0.01)]))
    text = _diagnose(run, 0, True, [first])  # type: ignore[arg-type]
    assert text.startswith(
        "nothing found: verification rejected all 2 candidate pose(s) as seen from the "
        "viewpoint (0, 0, 5): 2 by min_seen (the share of the model the sensor could see)."
    )
    assert re.search(r"candidate \d, seen 0\.\d+ < 0\.90 \(min_seen\)", text)
    _assert_every_quote_misses(text)


@pytest.mark.parametrize(
    ("face_proposals", "faces", "says"),
    [
        (False, 0, "or proposals='faces' for a part made of large flat faces (a box)."),
        (True, 4, "; verification rejected all 4 pose(s) laying a model face on the scan."),
        (True, 0, "; no planar patch of the scan took a model face."),
    ],
)
def test_too_few_matches_is_named_with_what_the_faces_did(face_proposals, faces, says) -> None:  # type: ignore[no-untyped-def]
    run = SimpleNamespace(viewpoint=EYE, unconfirmed=None, voxel=0.1, num_threads=1,
                          refiner=None, face_proposals=face_proposals)  # fmt: skip
    first = _Pass(np.zeros((0, 4, 4)), matches=2, faces=faces)
    text = _diagnose(run, 0, True, [first])  # type: ignore[arg-type]
    assert text.startswith(
        "nothing found: only 2 descriptor match(es) survived matching (3 needed for a pose)"
    )
    assert says in text and "try a smaller voxel_size or mutual=False" in text
    assert ("proposals='faces'" in text) == (not face_proposals)
    # A copy found (by a face) needs no explaining.
    assert _diagnose(run, 1, True, [first]) == ""  # type: ignore[arg-type]


class _Pass:
    """A first pass with candidate poses, as the diagnosis reads one."""

    def __init__(self, poses: np.ndarray, matches: int | None = None, faces: int = 0) -> None:
        self.result = _Result(poses)
        self.correspondences = np.zeros((10 if matches is None else 0, 6))
        self.matches = matches
        self.faces = np.tile(np.eye(4), (faces, 1, 1))


class _Result:
    def __init__(self, poses: np.ndarray) -> None:
        self.transformations = poses

    def __len__(self) -> int:
        return len(self.transformations)
