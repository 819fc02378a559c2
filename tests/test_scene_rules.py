"""The scene-wide rules and the acceptance rules are declared once, in the Rust core, and every
Python name for them reads that declaration."""

from __future__ import annotations

import dataclasses

import numpy as np
import pointclm
import pytest
from pointclm import _core, point_clouds, refinement
from pointclm.errors import ConfigError
from pointclm.scene_rules import SCENE_DEFAULTS, SceneRules


def test_scene_rules_lines_match_the_core_schema() -> None:
    schema = _core.scene_rules_schema()
    fields = dataclasses.fields(SceneRules)
    assert [f.name for f in fields] == [s["name"] for s in schema]
    for f, s in zip(fields, schema, strict=True):
        assert f.default == s["default"], f.name
        assert f.type == {"float": "float", "count": "int"}[s["kind"]], f.name
        lo, hi = s["range"]
        assert lo <= s["default"] <= hi, f.name
        assert s["doc"].strip(), f.name
    # Every field's reason reaches help().
    assert all(f.name in (SceneRules.__doc__ or "") for f in fields)


def test_module_constants_are_the_declared_defaults() -> None:
    rules = {f["name"]: f["default"] for f in _core.refine_params_schema()}
    for name in refinement._RULES:
        assert getattr(refinement, name.upper()) == rules[name]
    assert refinement.MAX_RELATIVE_VISIBLE_RMSE == SCENE_DEFAULTS.max_relative_visible_rmse
    assert refinement.FLIP_EVIDENCE_RATIO == SCENE_DEFAULTS.flip_evidence_ratio
    assert point_clouds.HEAP_MIN_COPIES == SCENE_DEFAULTS.heap_min_copies
    assert point_clouds.MAX_PEEL_ROUNDS == SCENE_DEFAULTS.max_peel_rounds
    assert point_clouds.VOXELS_PER_DIAGONAL == SCENE_DEFAULTS.voxels_per_diagonal
    # The lengths of verification are declared in voxels.
    assert rules["fit_radius"] == 1.5 and rules["icp_radius_coarse"] == 3.0


def test_bad_scene_rules_are_config_errors_naming_the_field() -> None:
    with pytest.raises(ConfigError, match="max_stray_share"):
        SceneRules(max_stray_share=1.5)
    with pytest.raises(ConfigError, match="heap_min_copies"):
        SceneRules(heap_min_copies=2.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="no_such_rule"):
        SceneRules.from_dict({"no_such_rule": 1})
    with pytest.raises(ConfigError, match="scene must be"):
        SceneRules.resolve(3)  # type: ignore[arg-type]
    assert SceneRules.resolve({"max_peel_rounds": 4}).max_peel_rounds == 4


def test_refine_rules_pass_by_name_and_are_checked_by_the_core() -> None:
    pts = np.random.default_rng(0).uniform(size=(200, 3))
    with pytest.raises(ConfigError, match="min_seen"):
        _core.refine_poses(pts, pts, np.eye(4)[None], 0.05, False, None, {"min_seen": 2.0})
    with pytest.raises(ConfigError, match="unknown refine rule field"):
        _core.refine_poses(pts, pts, np.eye(4)[None], 0.05, False, None, {"nope": 0.0})
    # A surface (a bumpy sheet) posed on itself is kept.
    g = np.linspace(0.0, 1.0, 21)
    u, v = np.meshgrid(g, g)
    sheet = np.column_stack([u.ravel(), v.ravel(), 0.1 * np.sin(3 * u.ravel()) * v.ravel()])
    kept = refinement.refine_poses(sheet, sheet, np.eye(4)[None], 0.05, icp=False)
    assert len(kept.origin) == 1


def _three_copies() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    # A bumpy, asymmetric blob: distinctive enough for FPFH.
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    model = d * (1.0 + 0.3 * np.sin(3 * d[:, :1]) * np.cos(2 * d[:, 1:2]) + 0.2 * d[:, 2:])
    copies = [model + [3.0 * k, 0.0, 0.0] for k in range(3)]
    return model, np.concatenate(copies)


def test_scene_rules_reach_the_scene_stages() -> None:
    model, scan = _three_copies()
    plain = pointclm.register_point_clouds(model, scan, peel=False)
    no_rounds = pointclm.register_point_clouds(model, scan, scene={"max_peel_rounds": 0})
    assert len(no_rounds.passes) == 1
    coarse = pointclm.register_point_clouds(
        model, scan, peel=False, scene=SceneRules(voxels_per_diagonal=20.0)
    )
    assert coarse.voxel_size == pytest.approx(2.0 * plain.voxel_size)


#: `register_point_clouds` parameters the command line takes otherwise, and why.
NOT_A_METHOD_FLAG = {
    "source": "the MODEL argument",
    "target": "the SCENE argument (SCANS for batch)",
    "symmetry": "register's --symmetry: the model's, not the method's (batch has no flag yet)",
}


def test_every_parameter_of_register_point_clouds_is_reachable_from_the_command_line() -> None:
    import inspect

    from pointclm import cli
    from pointclm.batch.options import OPTION_NAMES

    names = set(inspect.signature(pointclm.register_point_clouds).parameters)
    wanted = names - set(NOT_A_METHOD_FLAG)
    flags = ["--scene", "max_peel_rounds=3", "--scene", "scene_turn_deg=10", "--no-flips"]
    flags += ["--heap-rank", "none", "--mutual-window", "auto", "--top-k", "50", "--k", "2"]
    args = cli.build_parser().parse_args(["register", "m.ply", "s.ply", *flags, "--normals"])
    options = cli._method_options(args, lambda: np.zeros((10, 3)))
    assert wanted <= set(options), wanted - set(options)
    assert wanted <= set(OPTION_NAMES), wanted - set(OPTION_NAMES)
    assert options["scene"] == {"max_peel_rounds": 3, "scene_turn_deg": 10.0}
    assert options["flips"] is False and options["heap_rank"] is None
    assert (options["mutual_window"], options["top_k"], options["k"]) == ("auto", 50, 2)
    assert options["normals"] is True
    batch = cli.build_parser().parse_args(["batch", "m.ply", "s.ply", "--out", "o.jsonl", *flags])
    assert cli._method_options(batch, lambda: np.zeros((10, 3)))["scene"] == options["scene"]


@pytest.mark.parametrize("bad", ["nope=1", "max_peel_rounds", "max_peel_rounds=x"])
def test_a_bad_scene_flag_is_a_usage_error(bad: str, capsys: pytest.CaptureFixture[str]) -> None:
    from pointclm import cli

    with pytest.raises(SystemExit) as exit_:
        cli.build_parser().parse_args(["register", "m.ply", "s.ply", "--scene", bad])
    assert exit_.value.code == 2
    assert "--scene" in capsys.readouterr().err


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"heap": True, "flips": False},
        {"viewpoint": None},
        {"refine": False},
        {"k": 2},
        {"mutual_window": 0.5},
        {"mutual_window": "auto", "heap": True},
    ],
    ids=str,
)
def test_register_point_clouds_is_the_core_s_scene_pipeline(options: dict) -> None:
    # `register_point_clouds` hands every option to the core's pipeline and builds its result
    # from the core's answer (its Python stages were compared with the core and removed:
    # benchmarks/results/clouds/scene_core.md), on a small bin of procedural boxes.
    from pointclm.datasets.bins import make_bin_scene
    from test_bins import SMALL

    scene = make_bin_scene(0, SMALL)
    kwargs = {"viewpoint": tuple(float(v) for v in scene.sensor), **options}
    reg = pointclm.register_point_clouds(scene.model_points, scene.scan, **kwargs)
    config = pointclm.registration.as_config(reg.config)  # the call's, in the clouds' units
    rs = _core.register_scan(scene.model_points, scene.scan, config=config, **kwargs)
    assert rs["voxel_size"] == reg.voxel_size and len(rs["passes"]) == len(reg.passes)
    np.testing.assert_array_equal(rs["transformations"], reg.transformations)
    assert list(rs["confidence"]) == [i.confidence for i in reg.instances]
    assert rs["pass_index"] == [i.pass_index for i in reg.instances]
    for p, q in zip(rs["passes"], reg.passes, strict=True):
        np.testing.assert_array_equal(p["correspondences"], q.correspondences)
    if options.get("refine") is False:
        # The correspondence stage's poses as it gave them, most inliers first, one pass.
        stage = reg.passes[0].result
        assert len(reg.passes) == 1 and reg.passes[0].added == len(stage) == len(reg.instances)
        for i, inst in enumerate(reg.instances):
            assert inst.matches is not None and inst.pass_index == 0
            np.testing.assert_allclose(
                inst.transformation, stage.instances[i].transformation, atol=1e-9
            )
        assert reg.config.max_nfa is not None  # the stage's own test judges the groups
    with pytest.raises(ConfigError, match="max_stray_share"):
        _core.register_scan(scene.model_points, scene.scan, scene={"max_stray_share": 2.0})
    with pytest.raises(ValueError, match="mutual_window"):
        _core.register_scan(scene.model_points, scene.scan, mutual_window="windows")


def test_the_learned_path_calls_its_embedding_back_from_the_core() -> None:
    # The shipped network's embedding, called back from the core for every pass, and normals
    # handed to the correspondence stage.
    from pointclm.datasets.scenes import SceneParams, make_realistic_scene

    scene = make_realistic_scene(0, SceneParams(model="bunny"))
    for kwargs in (
        {"model": "default"},
        {"normals": True},
        {"model": "default", "viewpoint": None},
    ):
        kwargs = {"viewpoint": scene.viewpoint, **kwargs}
        rs = pointclm.register_point_clouds(scene.source_points, scene.target_points, **kwargs)
        assert len(rs.instances) >= 3
        if kwargs.get("model"):
            assert rs.timings["embedding"] > 0
    # One thread: the network, called back from the core's only worker, runs there (no wait
    # for a free worker), with the same result.
    one = pointclm.register_point_clouds(
        scene.source_points, scene.target_points, num_threads=1, **kwargs
    )
    np.testing.assert_array_equal(one.transformations, rs.transformations)
    # The embedding's own exception reaches the caller as it was raised.
    with pytest.raises(ZeroDivisionError):
        _core.register_scan(scene.source_points, scene.target_points, embed=lambda *cues: 1 / 0)
    with pytest.raises(ValueError, match="rows for"):
        _core.register_scan(
            scene.source_points, scene.target_points, embed=lambda c, *cues: np.ones((1, 4))
        )


def test_verification_names_the_rule_that_rejected_each_pose() -> None:
    # Without a viewpoint: the model on its own scan twice (the second a duplicate) and once
    # far from it (explaining nothing of the model against the best pose's share).
    rng = np.random.default_rng(3)
    model = rng.normal(size=(800, 3))
    model /= np.linalg.norm(model, axis=1, keepdims=True)
    far = np.eye(4)
    far[:3, 3] = (10.0, 0.0, 0.0)
    poses = np.stack([np.eye(4), np.eye(4), far])
    context = refinement.RefinementContext(model, model, 0.1)
    kept = context.refine(poses, icp=False)
    assert kept.origin.tolist() == [0]
    rejected = context.rejections(poses, icp=False)
    assert [(r.origin, r.rule) for r in rejected] == [
        (1, "max_shared"),
        (2, "min_relative_fitness"),
    ]
    assert rejected[0].value == 1.0 and rejected[0].threshold == refinement.MAX_SHARED
    assert rejected[1].value == 0.0 and rejected[1].threshold == pytest.approx(
        refinement.MIN_RELATIVE_FITNESS
    )
    # With every rule off but the duplicates', only the duplicate is rejected.
    loose = context.rejections(poses, icp=False, min_fitness=0.0, min_relative_fitness=0.0)
    assert [r.rule for r in loose] == ["max_shared", "explains_nothing"]
    with pytest.raises(ValueError, match="unknown rule"):
        context.rejections(poses, min_seeen=0.1)


def test_the_thresholds_for_clouds_are_the_cores() -> None:
    # Declared once, in the core: the Python config for refined poses on clouds is its.
    from pointclm.point_clouds import cloud_base_config

    core = _core.cloud_base_config()
    python = cloud_base_config(refine=True).to_dict()
    assert {k: python[k] for k in core} == core
    assert core["max_nfa"] is None and core["tau_n"] == 1
