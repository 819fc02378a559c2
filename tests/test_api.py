"""The public contract of `pointclm.register`: result types, input forms, determinism, config."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

import numpy as np
import pointclm
import pytest
from helpers import assert_same_result
from pointclm import Config, Instance, RegistrationResult, _core
from pointclm.datasets import make_scene
from pointclm.metrics import score_scene


@pytest.fixture(scope="module")
def scene() -> pointclm.datasets.SyntheticScene:
    return make_scene(0)


@pytest.fixture(scope="module")
def corr(scene: pointclm.datasets.SyntheticScene) -> np.ndarray:
    return np.array(scene.correspondences)  # a writeable, C-contiguous float64 copy


@pytest.fixture(scope="module")
def result(corr: np.ndarray) -> RegistrationResult:
    return pointclm.register(corr)


def residuals(corr: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return np.linalg.norm(corr[:, :3] @ pose[:3, :3].T + pose[:3, 3] - corr[:, 3:], axis=1)


# --- result contract ------------------------------------------------------------------------


def test_result_types_shapes_dtypes(result: RegistrationResult, corr: np.ndarray) -> None:
    n = len(corr)
    m = len(result)
    assert isinstance(result, RegistrationResult)
    assert m == len(result.instances) > 0
    assert all(isinstance(inst, Instance) for inst in result.instances)
    assert result.transformations.shape == (m, 4, 4)
    assert result.transformations.dtype == np.float64
    assert result.labels.shape == (n,)
    assert result.labels.dtype == np.int64
    assert result.kept.dtype == np.int64 and result.kept.ndim == 1
    assert np.all((result.kept >= 0) & (result.kept < n))
    assert len(np.unique(result.kept)) == len(result.kept)
    assert isinstance(result.n_clusters, int) and result.n_clusters >= m
    assert isinstance(result.timings, dict)
    assert all(
        isinstance(k, str) and isinstance(v, float) and v >= 0 for k, v in result.timings.items()
    )
    for k, inst in enumerate(result.instances):
        assert inst.transformation.shape == (4, 4) and inst.transformation.dtype == np.float64
        np.testing.assert_array_equal(result[k].transformation, inst.transformation)
        np.testing.assert_array_equal(result.transformations[k], inst.transformation)
        assert inst.inliers.dtype == np.int64 and inst.inliers.ndim == 1
        assert inst.correspondence_set.dtype == np.int64
        assert inst.correspondence_set.shape == (len(inst.inliers), 2)
        # Open3D convention: (source index, target index); both are the row here
        np.testing.assert_array_equal(inst.correspondence_set[:, 0], inst.inliers)
        np.testing.assert_array_equal(inst.correspondence_set[:, 1], inst.inliers)
        assert len(inst) == len(inst.inliers)
        assert isinstance(inst.fitness, float) and isinstance(inst.inlier_rmse, float)
    with pytest.raises(IndexError):
        result[m]
    with pytest.raises(IndexError):
        result[-m - 1]
    np.testing.assert_array_equal(result[-1].inliers, result.instances[-1].inliers)
    assert [len(i) for i in result] == [len(i) for i in result.instances]  # iterable


def test_labels_match_instance_inliers(result: RegistrationResult, corr: np.ndarray) -> None:
    labels = result.labels
    assert labels.min() >= -1 and labels.max() == len(result) - 1
    for k, inst in enumerate(result.instances):
        np.testing.assert_array_equal(np.flatnonzero(labels == k), inst.inliers)
    n_labelled = sum(len(inst.inliers) for inst in result.instances)
    assert np.count_nonzero(labels >= 0) == n_labelled  # no row in two instances


def test_transformations_are_proper_rigid(result: RegistrationResult) -> None:
    for pose in result.transformations:
        r = pose[:3, :3]
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-10)
        assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-10)
        np.testing.assert_array_equal(pose[3], [0.0, 0.0, 0.0, 1.0])
        assert np.isfinite(pose).all()


def test_fitness_and_rmse(result: RegistrationResult, corr: np.ndarray) -> None:
    for inst in result.instances:
        assert inst.fitness == pytest.approx(len(inst.inliers) / len(corr), rel=1e-12)
        res = residuals(corr, inst.transformation)[inst.inliers]
        assert inst.inlier_rmse == pytest.approx(np.sqrt(np.mean(res**2)), rel=1e-9)


@pytest.mark.parametrize("refine", [False, True])
def test_inliers_are_within_threshold_of_returned_pose(refine: bool) -> None:
    # Open3D's contract: correspondence_set is the inlier set of the *returned* transformation.
    # In this scene the final least-squares refit moves instance 0 so that row 631 (a GT
    # outlier at 0.0998 before the refit) ends at 0.112: it must leave the inlier set.
    scene = make_scene(4042502035264064771)
    corr = scene.correspondences
    res = pointclm.register(corr, config=Config(refine=refine))
    assert len(res) > 0
    for inst in res.instances:
        within = residuals(corr, inst.transformation) < 0.1
        np.testing.assert_array_equal(inst.inliers[~within[inst.inliers]], [])


CONTRACT_CONFIGS = [
    Config(),
    Config(refine=False, merge_duplicates=False),
    Config(ransac_iterations=1, inlier_threshold=0.3),
    Config(pruning="authors", assignment="discretize", min_cluster_size=25),
]


@pytest.mark.parametrize("seed", range(6))
def test_contract_holds_across_scenes_and_configs(seed: int) -> None:
    corr = make_scene(seed + 100).correspondences
    for cfg in CONTRACT_CONFIGS:
        res = pointclm.register(corr, config=cfg, seed=seed)
        covered = np.zeros(len(corr), dtype=int)
        for k, inst in enumerate(res.instances):
            np.testing.assert_array_equal(np.flatnonzero(res.labels == k), inst.inliers)
            assert len(inst) >= cfg.min_cluster_size
            r = inst.transformation[:3, :3]
            np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-10)
            assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-10)
            within = residuals(corr, inst.transformation)[inst.inliers] < cfg.inlier_threshold
            assert within.all()
            assert inst.fitness == pytest.approx(len(inst) / len(corr), rel=1e-12)
            covered[inst.inliers] += 1
        assert covered.max(initial=0) <= 1
        assert np.all(res.labels[covered == 0] == -1)
        assert np.all(np.diff(res.kept) > 0) and len(res.kept) <= cfg.max_kept


@pytest.mark.parametrize(
    "cfg",
    [
        Config(max_kept=50),
        Config(min_cluster_size=15),
        Config(max_instances=3),
        Config(pruning="authors"),
        Config(pruning="none", max_instances=20),  # uncapped, the eigengap picks k = 998
        Config(assignment="discretize", merge_duplicates=False),
        Config(min_cluster_size=3, tau_n=3),
    ],
    ids=["max_kept", "min_cluster_size", "max_instances", "authors", "none", "discretize", "small"],
)
def test_config_limits_are_respected(cfg: Config, corr: np.ndarray) -> None:
    res = pointclm.register(corr, config=cfg)
    assert len(res.kept) <= cfg.max_kept
    assert all(len(inst) >= cfg.min_cluster_size for inst in res.instances)
    if cfg.max_instances is not None:
        assert len(res) <= cfg.max_instances
    for k, inst in enumerate(res.instances):
        np.testing.assert_array_equal(np.flatnonzero(res.labels == k), inst.inliers)


def test_repr_is_readable(result: RegistrationResult, corr: np.ndarray) -> None:
    text = repr(result)
    assert text.startswith("RegistrationResult(")
    assert f"{len(result)} instances" in text
    assert str(len(corr)) in text
    assert text.count("Instance(") == len(result)
    inst = repr(result.instances[0])
    assert inst.startswith("Instance(") and "fitness" in inst and "inlier_rmse" in inst
    assert len(text) < 4000


def test_finds_the_ground_truth(result: RegistrationResult, scene) -> None:
    score = score_scene(result.transformations, scene.poses)
    assert score.strict_f1 == 1.0, score


# --- input forms ----------------------------------------------------------------------------


def test_source_target_pair_equals_correspondences(
    result: RegistrationResult, corr: np.ndarray
) -> None:
    assert_same_result(pointclm.register(corr[:, :3], corr[:, 3:]), result)
    assert_same_result(pointclm.register(corr[:, :3].tolist(), corr[:, 3:].tolist()), result)
    assert_same_result(pointclm.register(corr[:, :3], target=corr[:, 3:]), result)


def _strided(corr: np.ndarray) -> np.ndarray:
    big = np.zeros((2 * len(corr), 12))
    big[::2, ::2] = corr
    view = big[::2, ::2]
    assert not view.flags.c_contiguous and not view.flags.f_contiguous
    return view


@pytest.mark.parametrize(
    "convert",
    [
        pytest.param(np.asfortranarray, id="fortran"),
        pytest.param(_strided, id="strided"),
        pytest.param(lambda c: c.tolist(), id="list"),
        pytest.param(lambda c: tuple(map(tuple, c)), id="tuple"),
        pytest.param(lambda c: c.view(c.dtype.newbyteorder()).byteswap(), id="big-endian"),
    ],
)
def test_layouts_give_identical_results(
    convert, result: RegistrationResult, corr: np.ndarray
) -> None:
    assert_same_result(pointclm.register(convert(corr)), result)


@pytest.mark.parametrize("dtype", [np.float32, np.int32, np.int64, np.uint16])
def test_other_dtypes_equal_their_float64_value(dtype, corr: np.ndarray) -> None:
    # integers: millimetres, shifted to be non-negative for the unsigned type
    scaled = corr * 1000 + 1000 if np.issubdtype(dtype, np.integer) else corr
    a = scaled.astype(dtype)
    cfg = Config().scaled(1000) if np.issubdtype(dtype, np.integer) else None
    expected = pointclm.register(a.astype(np.float64), config=cfg)
    assert len(expected) > 0
    assert_same_result(pointclm.register(a, config=cfg), expected)
    assert_same_result(pointclm.register(np.asfortranarray(a), config=cfg), expected)


def test_inputs_are_not_modified(corr: np.ndarray) -> None:
    rng = np.random.default_rng(5)
    f32 = np.asfortranarray(corr.astype(np.float32))
    feats = rng.normal(size=(len(corr), 8))
    frozen = corr.copy()
    frozen.setflags(write=False)
    arrays = [corr, f32, feats, frozen]
    copies = [a.copy() for a in arrays]
    flags = [(a.flags.writeable, a.flags.c_contiguous, a.flags.f_contiguous) for a in arrays]
    pointclm.register(corr, feats)
    pointclm.register(f32)
    pointclm.register(frozen)  # read-only input is accepted
    pointclm.register(corr[:, :3], corr[:, 3:])
    pointclm.register_batch([corr, (f32, feats), frozen])
    for a, c, fl in zip(arrays, copies, flags, strict=True):
        np.testing.assert_array_equal(a, c)
        assert (a.flags.writeable, a.flags.c_contiguous, a.flags.f_contiguous) == fl


def test_result_arrays_are_independent(corr: np.ndarray) -> None:
    # Arrays handed out are either read-only or copies: writing to one never changes the result.
    res = pointclm.register(corr)
    fields = [res.labels, res.kept, res.transformations, res[0].inliers, res[0].transformation]
    before = [a.copy() for a in fields]
    for a in [res.labels, res.kept, res.transformations, res[0].inliers, res[0].transformation]:
        if a.flags.writeable:
            a[...] = 0
    after = [res.labels, res.kept, res.transformations, res[0].inliers, res[0].transformation]
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)


# --- determinism ----------------------------------------------------------------------------


def test_same_seed_same_result(corr: np.ndarray) -> None:
    a = pointclm.register(corr, seed=123)
    assert_same_result(pointclm.register(corr, seed=123), a)
    assert_same_result(pointclm.register(corr, seed=np.uint64(123)), a)


def test_num_threads_do_not_change_the_result(corr: np.ndarray) -> None:
    for seed in (0, 9):
        one = pointclm.register(corr, seed=seed, num_threads=1)
        assert_same_result(pointclm.register(corr, seed=seed, num_threads=2), one)
        assert_same_result(pointclm.register(corr, seed=seed), one)
        assert_same_result(pointclm.register(corr, seed=seed, num_threads=np.int64(2)), one)


def test_num_threads_do_not_change_a_large_result() -> None:
    # 4000 rows: every parallel stage splits its work into several chunks
    scene = make_scene(3, n_keep=4000)
    feats = _oracle_features(scene, noise=0.05, seed=3)
    for f in (None, feats):
        one = pointclm.register(scene.correspondences, f, num_threads=1)
        assert len(one) > 3
        assert_same_result(pointclm.register(scene.correspondences, f, num_threads=2), one)
        assert_same_result(pointclm.register(scene.correspondences, f, num_threads=5), one)


def test_seed_is_used(corr: np.ndarray) -> None:
    # Few RANSAC iterations: the hypotheses, hence the poses, depend on the seed.
    cfg = Config(ransac_iterations=1, refine=False)
    poses = {
        pointclm.register(corr, config=cfg, seed=s).transformations.tobytes() for s in range(4)
    }
    assert len(poses) > 1


# --- config ---------------------------------------------------------------------------------


def test_config_is_the_rust_schema() -> None:
    # The Rust struct is the one definition: the dataclass has its fields, in its order, with
    # the annotation its kind implies and its default.
    schema = _core.config_schema()
    assert [f.name for f in dataclasses.fields(Config)] == [f["name"] for f in schema]
    hints = typing.get_type_hints(Config)
    for field in schema:
        name = field["name"]
        if field["kind"] == "choice":
            expected: Any = typing.Literal[tuple(field["choices"])]
        else:
            expected = {"float": float, "count": int, "bool": bool}[field["kind"]]
        if field["optional"]:
            expected = expected | None
        assert hints[name] == expected, name
        py = getattr(Config(), name)
        assert py == field["default"] and type(py) is type(field["default"]), name
        assert f"\n    {name} : " in (Config.__doc__ or ""), name  # documented from Rust
        assert field["doc"].strip(), name
    assert Config().to_dict() == _core.default_config()
    _core.validate_config(_core.default_config())


def test_config_scaled_multiplies_the_schema_lengths() -> None:
    lengths = [f["name"] for f in _core.config_schema() if f["length"]]
    assert lengths == ["sigma_d", "affinity_sigma", "inlier_threshold"]  # as documented
    base = Config(max_nfa=0.5, cluster_level=0.3, max_instances=4)
    scaled = base.scaled(4)
    for name, value in base.to_dict().items():
        expected = value * 4 if name in lengths else value
        assert getattr(scaled, name) == expected, name


def test_config_normalises_numbers() -> None:
    # numpy scalars and ints become the plain Python types the core and repr expect
    cfg = Config(
        sigma_d=np.float32(0.25), tau_n=np.int64(5), max_instances=np.int32(3), inlier_threshold=1
    )
    assert cfg == Config(sigma_d=0.25, tau_n=5, max_instances=3, inlier_threshold=1.0)
    defaults = Config().to_dict()
    for name, value in cfg.to_dict().items():
        if defaults[name] is not None:
            assert type(value) is type(defaults[name]), name
    assert type(cfg.tau_n) is int and type(cfg.max_instances) is int
    assert "np." not in repr(cfg)


def test_config_dict_equals_config(corr: np.ndarray) -> None:
    cfg = {"ransac_iterations": 20, "assignment": "discretize"}
    assert_same_result(
        pointclm.register(corr, config=cfg), pointclm.register(corr, config=Config(**cfg))
    )
    assert_same_result(pointclm.register(corr, config={}), pointclm.register(corr))


def test_config_is_used(corr: np.ndarray, result: RegistrationResult) -> None:
    # Nothing is dense enough with tau_n = 500: every row is pruned.
    none = pointclm.register(corr, config=Config(tau_n=500))
    assert len(none) == 0 and len(none.kept) == 0
    capped = pointclm.register(corr, config=Config(max_instances=2))
    assert len(capped) <= 2 < len(result)


def test_config_is_frozen_and_scaled() -> None:
    cfg = Config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.sigma_d = 1.0  # type: ignore[misc]
    big = cfg.scaled(10)
    assert big.sigma_d == pytest.approx(0.5)
    assert big.affinity_sigma == pytest.approx(1.0)
    assert big.inlier_threshold == pytest.approx(1.0)
    assert (big.tau_s, big.tau_n, big.min_cluster_size) == (
        cfg.tau_s,
        cfg.tau_n,
        cfg.min_cluster_size,
    )


def test_scaled_config_on_scaled_scene(scene, result: RegistrationResult) -> None:
    big = pointclm.register(scene.correspondences * 10, config=Config().scaled(10))
    assert len(big) == len(result)
    np.testing.assert_array_equal(big.labels, result.labels)
    np.testing.assert_allclose(
        big.transformations[:, :3, :3], result.transformations[:, :3, :3], atol=1e-9
    )
    np.testing.assert_allclose(
        big.transformations[:, :3, 3], 10 * result.transformations[:, :3, 3], atol=1e-8
    )
    gt = scene.poses.copy()
    gt[:, :3, 3] *= 10
    assert score_scene(big.transformations, gt, max_translation=1.0).strict_f1 == 1.0


# --- features -------------------------------------------------------------------------------


def _oracle_features(scene, noise: float, seed: int) -> np.ndarray:
    """One-hot of the GT instance plus noise for inliers, random directions for outliers."""
    rng = np.random.default_rng(seed)
    dim = scene.n_instances + 8
    feats = rng.normal(size=(len(scene.labels), dim))
    inl = scene.labels >= 0
    feats[inl] = np.eye(dim)[scene.labels[inl]] + noise * rng.normal(size=(inl.sum(), dim))
    return feats / np.linalg.norm(feats, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_features_path_finds_the_instances(seed: int) -> None:
    scene = make_scene(seed)
    feats = _oracle_features(scene, noise=0.02, seed=seed)
    res = pointclm.register(scene.correspondences, feats)
    assert score_scene(res.transformations, scene.poses).strict_f1 == 1.0
    # the features remove outliers that spatial consistency alone keeps
    assert np.all(scene.labels[res.kept] >= 0)
    assert_same_result(pointclm.register(scene.correspondences, features=feats), res)


def test_features_are_used(scene) -> None:
    # Mutually near-orthogonal random features: S = S^F * beta stays under tau_s everywhere.
    feats = np.random.default_rng(3).normal(size=(len(scene.labels), 512))
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    res = pointclm.register(scene.correspondences, feats)
    assert len(res) == 0 and len(res.kept) == 0


# --- empty results --------------------------------------------------------------------------


@pytest.mark.parametrize("n", [3, 50, 1000])
def test_pure_noise_gives_a_valid_empty_result(n: int) -> None:
    rng = np.random.default_rng(n)
    noise = rng.uniform(0.0, 6.0, (n, 6))
    res = pointclm.register(noise)
    assert len(res) == 0 and res.instances == []
    assert res.transformations.shape == (0, 4, 4) and res.transformations.dtype == np.float64
    assert res.labels.shape == (n,) and res.labels.dtype == np.int64
    assert np.all(res.labels == -1)
    assert "0 instances" in repr(res)
    with pytest.raises(IndexError):
        res[0]


def test_degenerate_inputs_give_valid_results() -> None:
    # All rows identical: every pair is consistent but no rotation is determined.
    for corr in (np.ones((30, 6)), np.zeros((30, 6))):
        res = pointclm.register(corr)
        assert res.labels.shape == (30,)
        assert res.transformations.shape == (len(res), 4, 4)
        assert np.isfinite(res.transformations).all()


def test_eigengap_never_exceeds_what_can_become_instances() -> None:
    # Without pruning every isolated row is its own component; the cluster count must stay
    # at most n / 3, one group per minimal sample that can seed a pose (it used to reach ~N
    # and take seconds).
    corr = make_scene(0).correspondences
    res = pointclm.register(corr, config=Config(pruning="none"))
    assert res.n_clusters <= len(corr) // 3


def test_features_with_point_arrays_by_keyword() -> None:
    scene = make_scene(5)
    src, dst = scene.correspondences[:, :3], scene.correspondences[:, 3:]
    onehot = np.eye(12)[scene.labels + 1]
    a = pointclm.register(src, target=dst, features=onehot)
    b = pointclm.register(scene.correspondences, onehot)
    np.testing.assert_array_equal(a.transformations, b.transformations)
