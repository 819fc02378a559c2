"""The multi-model realistic benchmark: model split, seeds kept apart, the scene cache, the
report, and the N = 50,000 child's measurement (`benchmarks/clouds/realistic_models.py`)."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import DATA, needs_data
from pointclm.datasets.procedural import PROCEDURAL_SHAPES
from pointclm.datasets.scenes import (
    HELDOUT_MODELS,
    MODEL_FILES,
    VALIDATION_MODELS,
    SceneParams,
    _up_rotation,
    make_realistic_scene,
)

from benchmarks.bins import run as bins
from benchmarks.clouds import realistic_models as rm
from benchmarks.clouds import scale
from benchmarks.clouds import scenes as sc


def test_split_covers_every_model_once() -> None:
    assert not set(VALIDATION_MODELS) & set(HELDOUT_MODELS)
    assert set(VALIDATION_MODELS) | set(HELDOUT_MODELS) == set(MODEL_FILES) | set(PROCEDURAL_SHAPES)
    assert "stanford/bunny" in HELDOUT_MODELS
    assert sum(m.startswith("common3d/") for m in HELDOUT_MODELS) == 6


@needs_data
def test_every_model_file_is_in_the_data_folder() -> None:
    for rel, up in MODEL_FILES.values():
        assert (DATA / rel).is_file(), rel
        assert up in ("x", "y", "z", "-z")


@pytest.mark.parametrize("up", ["x", "y", "z", "-z"])
def test_up_rotation_is_proper_and_lifts_the_axis(up: str) -> None:
    r = _up_rotation(up)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(r), 1.0)
    axis = np.eye(3)["xyz".index(up[-1])] * (-1 if up.startswith("-") else 1)
    np.testing.assert_allclose(r @ axis, [0, 0, 1], atol=1e-12)


def test_benchmark_seeds_miss_threshold_and_training_seeds() -> None:
    from pointclm.training.realistic import scene_seed

    models = (*HELDOUT_MODELS, *VALIDATION_MODELS)
    bench = [s for m in models for s in sc.benchmark_seeds(m, 1000)]
    thresholds = [s for m in models for s in sc.threshold_seeds(m, 1000)]
    assert len(set(bench)) == len(bench) == 1000 * len(models)  # no two models share a seed
    assert not set(bench) & set(thresholds)
    assert sc.benchmark_seeds("common3d/spot", 3) == sc.benchmark_seeds("common3d/spot", 5)[:3]
    # The training banks (run seed s) and their validation banks (s + 1), for the first runs.
    banks = {scene_seed(b, i, k) for b in range(3) for i in range(12) for k in range(200)}
    lo, hi = sc.BENCHMARK_SEED_BASE, sc.THRESHOLD_SEED_BASE + sc.SEED_RANGE
    assert not any(lo <= s < hi for s in banks)
    assert max(bench + thresholds) < hi
    # ... and the bunny benchmark's and the tests' small seeds.
    assert min(bench + thresholds) > 10_000
    with pytest.raises(ValueError, match="scenes per model"):
        sc.benchmark_seeds("torus", sc.SCENES_PER_SLOT + 1)
    with pytest.raises(ValueError, match="unknown model"):
        sc.threshold_seeds("bunny", 1)
    # Random procedural shapes get blocks after the named models', inside the same range.
    from pointclm.datasets.procedural import procedural_family_names

    shapes = procedural_family_names(40, 7)
    extra = [s for m in shapes for s in sc.threshold_seeds(m, 2)]
    assert not set(extra) & set(thresholds) and max(extra) < hi
    assert sc.threshold_seeds(shapes[0], 2) == sc.threshold_seeds(shapes[0], 3)[:2]
    with pytest.raises(ValueError, match="unknown model"):
        sc.threshold_seeds("superquadric-x", 1)


def test_scene_params_by_n() -> None:
    small = sc.scene_params("stanford/bunny", 1000, None)
    assert small.mutual and small.n_correspondences == 1000 and small.top_k == 10_000
    big = sc.scene_params("stanford/bunny", 5000, None)
    assert not big.mutual and big.top_k == 5000 and big.n_correspondences is None
    # Only the matching differs: the same seed lays out the same scene.
    assert SceneParams(**{**big.__dict__, "mutual": True, "top_k": 10_000}) == SceneParams(
        **{**small.__dict__, "n_correspondences": None}
    )
    with pytest.raises(ValueError, match="positive"):
        sc.scene_params("stanford/bunny", 0, None)


def test_cache_round_trip_and_keys(tmp_path: Path) -> None:
    params = SceneParams(model="bunny", data_dir=None, instances=(2, 2), clutter=(0, 0))
    scene = make_realistic_scene(3, params)
    path = sc.cache_path(tmp_path, "bunny", 3, params)
    sc.save_scene(path, scene)
    back = sc.load_scene(path)
    for k in sc._ARRAYS:
        np.testing.assert_array_equal(getattr(back, k), getattr(scene, k))
    assert (back.voxel_size, back.diameter, back.model, back.seed) == (
        scene.voxel_size,
        scene.diameter,
        scene.model,
        scene.seed,
    )
    assert back.timings == scene.timings
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        assert "correspondences" in z.files
    other = SceneParams(model="bunny", data_dir=None, instances=(2, 2), clutter=(0, 1))
    assert sc.cache_path(tmp_path, "bunny", 3, other) != path
    assert sc.cache_path(tmp_path, "bunny", 4, params) != path
    # The data folder's location is not part of the key.
    moved = SceneParams(model="bunny", data_dir="/elsewhere", instances=(2, 2), clutter=(0, 0))
    assert sc.cache_path(tmp_path, "bunny", 3, moved) == path
    # A cached scene is read, not rebuilt.
    assert sc.load_scenes([("bunny", 3, params)], tmp_path, 1, progress=False)[0].seed == 3


def test_summary_counts_predictions_over_ground_truth() -> None:
    rows = [
        {"n_pred": 3, "n_gt": 2, "precision": 2 / 3, "recall": 1.0, "strict_precision": 2 / 3,
         "strict_recall": 1.0, "strict_f1": 0.8, "n_matched": 2, "seconds": 0.1},
        {"n_pred": 1, "n_gt": 2, "precision": 1.0, "recall": 0.5, "strict_precision": 1.0,
         "strict_recall": 0.5, "strict_f1": 2 / 3, "n_matched": 1, "seconds": 0.3},
    ]  # fmt: skip
    s = rm.summary(rows)
    assert s["pred/GT"] == pytest.approx(1.0)
    assert s["MR"] == pytest.approx(75.0) and s["MP"] == pytest.approx(100 * 5 / 6)
    assert s["median ms"] == pytest.approx(200.0)


def test_quick_run_writes_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Without --out the report goes to out/ under the working directory, never over the
    # committed benchmarks/results/.
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out" / "realistic_models.md"
    argv = ["--models", "torus", "--scenes-per-model", "1", "--scale", "0", "--no-ransac"]
    argv += ["--no-kiss", "--cache", str(tmp_path / "cache"), "--workers", "1"]
    rm.main(argv)
    text = out.read_text()
    assert "Validation models, pooled (torus)" in text and "Headline" not in text
    assert "| pointclm, training-free, correspondences alone |" in text
    record = json.loads(out.with_suffix(".json").read_text())
    assert {r["method"] for r in record["rows"]} >= {"pointclm", "pointclm+refine", "oracle"}
    assert {r["seed"] for r in record["rows"]} == set(sc.benchmark_seeds("torus", 1))
    with pytest.raises(SystemExit, match="unknown model"):
        rm.main(["--models", "no-such-model", "--out", str(out)])


def test_a_missing_peer_is_named_before_any_scene_is_built(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "kiss_matcher", None)  # as if not installed
    cache = tmp_path / "cache"
    argv = ["--models", "torus", "--scenes-per-model", "1", "--scale", "0", "--no-ransac"]
    argv += ["--cache", str(cache), "--workers", "1", "--out", str(tmp_path / "r.md")]
    with pytest.raises(SystemExit, match=r"KISS-Matcher.*kiss-matcher.*--skip-missing-peers"):
        rm.main(argv)
    assert not cache.exists() and not (tmp_path / "r.md").exists()
    # Asked to, it runs without the peer and says so at the start.
    rm.main([*argv, "--skip-missing-peers"])
    assert "leaving out sequential KISS-Matcher" in capsys.readouterr().out.splitlines()[0]
    record = json.loads((tmp_path / "r.json").read_text())
    assert "kiss" not in {r["method"] for r in record["rows"]}


def test_bins_names_a_missing_peer_up_front_and_writes_beside_the_results(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    assert not bins.DEFAULT_OUT.startswith("benchmarks/results")
    monkeypatch.setitem(sys.modules, "kiss_matcher", None)
    monkeypatch.setitem(sys.modules, "open3d", None)
    wanted = "pointclm,sequential KISS-Matcher,sequential RANSAC (Open3D)"
    with pytest.raises(SystemExit, match=r"kiss-matcher open3d-cpu.*--skip-missing-peers"):
        bins.choose_methods(wanted, skip_missing_peers=False)
    assert bins.choose_methods(wanted, skip_missing_peers=True) == ["pointclm"]
    assert "leaving out sequential KISS-Matcher" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="unknown method"):
        bins.choose_methods("pointclm,no-such-method", skip_missing_peers=True)
    # The whole script stops before building its first scene (that took 31 s).
    monkeypatch.setattr(sys, "argv", ["bins.py", "--models", "no-such-model"])
    with pytest.raises(SystemExit, match="missing peer"):
        bins.main()


def test_scale_child_reports_time_and_memory(tmp_path: Path, capsys) -> None:
    params = SceneParams(
        model="bunny",
        data_dir=None,
        instances=(2, 2),
        mutual=False,
        top_k=600,
        n_correspondences=None,
    )
    path = sc.cache_path(tmp_path, "bunny", 1, params)
    sc.save_scene(path, make_realistic_scene(1, params))
    scale.main([str(path), "--threads", "1"])
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["n"] == 600 and r["threads"] == 1 and r["gt"] == 2
    assert r["seconds"] > 0 and r["peak_mb"] >= r["baseline_mb"] > 0


@pytest.mark.parametrize(
    ("script", "models", "refused"),
    [
        ("realistic_thresholds", "stanford/dragon,common3d/spot", "common3d/spot"),
        ("realistic_ceilings", "stanford/armadillo,stanford/bunny", "stanford/bunny"),
    ],
)
def test_validation_scripts_refuse_held_out_models(
    monkeypatch: pytest.MonkeyPatch, script: str, models: str, refused: str
) -> None:
    module = importlib.import_module(f"benchmarks.clouds.{script}")
    monkeypatch.setattr(sys, "argv", ["x", "--models", models])
    with pytest.raises(SystemExit, match=f"not validation models: {refused}"):
        module.main()


def test_threshold_scorer_matches_refine_poses_on_the_raw_poses() -> None:
    import pointclm
    from pointclm.metrics import score_scene
    from pointclm.point_clouds import scaled_config

    from benchmarks.clouds import realistic_thresholds as rt

    scene = make_realistic_scene(2, SceneParams(model="bunny", data_dir=None, instances=(3, 3)))
    params = {"tau_s": 0.8, "tau_n": 1, "min_cluster_size": 3}
    cfg = scaled_config(scene.voxel_size, pointclm.Config(**params))
    raw = pointclm.register(scene.correspondences, None, cfg, seed=0).transformations
    refined = pointclm.refine_poses(
        scene.source_points, scene.target_points, raw, scene.voxel_size
    ).transformations
    scorer = rt.Scorer([scene])
    for poses, refine in ((raw, False), (refined, True)):
        want = score_scene(poses, scene.poses, 15.0, scene.max_translation)
        ((_, got),) = scorer.sweep(None, [params], [0], refine)
        assert got["mean_recall"] == want.recall and got["mean_precision"] == want.precision


def test_ceiling_row_features_rank_true_inliers_first() -> None:
    from benchmarks.clouds import realistic_ceilings as rc

    scene = make_realistic_scene(3, SceneParams(model="bunny", data_dir=None, instances=(3, 3)))
    before = scene.correspondences.copy()
    x = rc.row_features(scene)
    np.testing.assert_array_equal(scene.correspondences, before)
    assert x.shape == (len(scene.labels), 2 + 3 * len(rc.TOLERANCES)) and np.isfinite(x).all()
    assert (x[:, 1:] >= 0).all() and (x[:, 1:] <= 1).all()
    inlier = scene.labels >= 0
    # the consistency degrees are what the learned score starts from: inliers agree with more
    for col in range(2, x.shape[1]):
        assert x[inlier, col].mean() > x[~inlier, col].mean(), col


def test_ceiling_keeps_the_highest_scores_and_at_least_three() -> None:
    from benchmarks.clouds import realistic_ceilings as rc

    score = np.array([0.1, 0.9, 0.5, 0.7, 0.2])
    np.testing.assert_array_equal(rc._kept(score, 0.4), [1, 2, 3])
    np.testing.assert_array_equal(rc._kept(score, 0.8), [1, 2, 3, 4])
