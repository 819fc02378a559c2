"""The staged pipeline against numpy, scipy and scikit-learn."""

from __future__ import annotations

import numpy as np
import pytest
from pointclm import Config, staged
from pointclm.datasets import make_scene

scipy_linalg = pytest.importorskip("scipy.linalg")
sklearn_cluster = pytest.importorskip("sklearn.cluster")
sklearn_metrics = pytest.importorskip("sklearn.metrics")


def random_symmetric(n: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(n, n))
    return (a + a.T) / 2


def block_affinity(seed: int) -> tuple[np.ndarray, np.ndarray, int]:
    """3-6 shuffled blocks of 10-40 points: weights U[0.5, 1] inside a block, 1e-3 across."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(3, 7))
    truth = np.repeat(np.arange(k), rng.integers(10, 41, k))
    n = len(truth)
    w = rng.uniform(0.5, 1.0, (n, n))
    w = (w + w.T) / 2
    affinity = np.where(truth[:, None] == truth[None], w, 1e-3)
    perm = rng.permutation(n)
    return affinity[perm][:, perm], truth[perm], k


def numpy_laplacian(a: np.ndarray) -> np.ndarray:
    d = a.sum(axis=1)
    inv_sqrt = 1.0 / np.sqrt(d)
    return np.eye(len(a)) - inv_sqrt[:, None] * a * inv_sqrt[None, :]


def numpy_beta(corr: np.ndarray, sigma_d: float) -> np.ndarray:
    x, y = corr[:, :3], corr[:, 3:]
    dx = np.linalg.norm(x[:, None] - x[None], axis=2)
    dy = np.linalg.norm(y[:, None] - y[None], axis=2)
    return np.maximum(0.0, 1.0 - (dx - dy) ** 2 / sigma_d**2)


@pytest.fixture(scope="module")
def corr() -> np.ndarray:
    return np.array(make_scene(1).correspondences[:400])


# --- eigendecomposition ---------------------------------------------------------------------


def check_eigh(m: np.ndarray) -> None:
    w, v = staged.eigh(m)
    n = len(m)
    assert w.shape == (n,) and v.shape == (n, n)
    assert w.dtype == np.float64 and v.dtype == np.float64
    assert np.all(np.diff(w) >= 0), "eigenvalues must be ascending"
    np.testing.assert_allclose(w, scipy_linalg.eigh(m, eigvals_only=True), rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(m @ v, v * w, atol=1e-10)  # A v = lambda v, column by column
    np.testing.assert_allclose(v.T @ v, np.eye(n), atol=1e-10)


@pytest.mark.parametrize("seed", [0, 1])
def test_eigh_random_symmetric(seed: int) -> None:
    check_eigh(random_symmetric(50, seed))


def test_eigh_laplacian() -> None:
    affinity, _, k = block_affinity(3)
    lap = numpy_laplacian(affinity)
    check_eigh(lap)
    w, _ = staged.eigh(lap)
    assert w[0] == pytest.approx(0.0, abs=1e-10)
    assert w[k - 1] < 0.05 < w[k]  # k nearly disconnected blocks: k small eigenvalues


def test_eigh_repeated_eigenvalues() -> None:
    q, _ = np.linalg.qr(np.random.default_rng(2).normal(size=(20, 20)))
    m = q @ np.diag(np.repeat([1.0, 2.0, 5.0, 5.0], 5)) @ q.T
    check_eigh((m + m.T) / 2)
    check_eigh(np.eye(7))
    check_eigh(np.array([[4.0]]))


# --- Laplacian ------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 5])
def test_normalized_laplacian_matches_numpy(seed: int) -> None:
    affinity, _, _ = block_affinity(seed)
    lap = staged.normalized_laplacian(affinity)
    np.testing.assert_allclose(lap, numpy_laplacian(affinity), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(lap, lap.T, rtol=0, atol=1e-15)


def test_normalized_laplacian_of_a_soft_beta(corr: np.ndarray) -> None:
    affinity = numpy_beta(corr[:120], 0.1) + 1e-7  # the authors' clustering affinity
    np.testing.assert_allclose(
        staged.normalized_laplacian(affinity), numpy_laplacian(affinity), rtol=1e-12, atol=1e-14
    )


# --- spectral clustering --------------------------------------------------------------------


@pytest.mark.parametrize("assignment", ["kmeans", "discretize"])
@pytest.mark.parametrize("seed", range(6))
def test_spectral_clustering_agrees_with_sklearn(seed: int, assignment: str) -> None:
    affinity, truth, k = block_affinity(seed)
    labels, n, eigenvalues = staged.spectral_clustering(affinity, k, assignment=assignment)
    assert n == k
    assert labels.shape == truth.shape and labels.dtype == np.int64
    assert set(labels.tolist()) == set(range(k))
    ref = sklearn_cluster.SpectralClustering(
        n_clusters=k, affinity="precomputed", random_state=0, assign_labels=assignment
    ).fit_predict(affinity)
    ari = sklearn_metrics.adjusted_rand_score
    assert ari(labels, ref) >= 0.99
    assert ari(labels, truth) >= 0.99
    exact = np.linalg.eigvalsh(numpy_laplacian(affinity))
    if len(eigenvalues) == len(exact):  # the dense decomposition, below 150 rows
        np.testing.assert_allclose(eigenvalues, exact, rtol=1e-9, atol=1e-10)
    else:  # the lowest eigenpairs only: the groups' and the first past the gap, to 1e-2 of
        # the norm bound (2); the dense rest of the spectrum is only roughly resolved
        assert k < len(eigenvalues) < len(exact)
        np.testing.assert_allclose(eigenvalues[: k + 1], exact[: k + 1], rtol=0, atol=2e-2)


@pytest.mark.parametrize("assignment", ["kmeans", "discretize"])
@pytest.mark.parametrize("seed", range(6))
def test_eigengap_finds_the_block_count(seed: int, assignment: str) -> None:
    affinity, truth, k = block_affinity(seed)
    labels, n, eigenvalues = staged.spectral_clustering(affinity, assignment=assignment)
    assert n == k
    assert n == int(np.argmax(np.diff(eigenvalues))) + 1  # M = argmax_k (l_{k+1} - l_k)
    assert sklearn_metrics.adjusted_rand_score(labels, truth) >= 0.99


def test_max_clusters_caps_the_eigengap() -> None:
    affinity, _, k = block_affinity(0)
    assert k > 2
    labels, n, _ = staged.spectral_clustering(affinity, max_clusters=2)
    assert 1 <= n <= 2 and set(labels.tolist()) == set(range(n))
    assert staged.spectral_clustering(affinity, max_clusters=k)[1] == k
    assert staged.spectral_clustering(affinity, max_clusters=k + 5)[1] == k


def test_spectral_clustering_is_seeded() -> None:
    affinity, _, k = block_affinity(4)
    noisy = affinity + 0.2 * np.random.default_rng(0).uniform(size=affinity.shape)
    noisy = (noisy + noisy.T) / 2
    a = staged.spectral_clustering(noisy, k, seed=3)
    b = staged.spectral_clustering(noisy, k, seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[2], b[2])


# --- spatial consistency and pruning --------------------------------------------------------


@pytest.mark.parametrize("sigma_d", [0.05, 0.3])
def test_spatial_consistency_matches_numpy(corr: np.ndarray, sigma_d: float) -> None:
    beta = staged.spatial_consistency(corr, sigma_d)
    assert beta.shape == (len(corr), len(corr)) and beta.dtype == np.float64
    np.testing.assert_array_equal(beta, beta.T)
    np.testing.assert_array_equal(np.diag(beta), 1.0)
    assert beta.min() >= 0.0 and beta.max() <= 1.0
    np.testing.assert_allclose(beta, numpy_beta(corr, sigma_d), rtol=0, atol=1e-12)
    assert 0 < np.count_nonzero(beta) < beta.size  # neither trivial case


def test_spatial_consistency_is_rigid_invariant(corr: np.ndarray) -> None:
    q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))
    moved = np.hstack([corr[:, :3] @ q.T + 4.0, corr[:, 3:]])
    np.testing.assert_allclose(
        staged.spatial_consistency(moved, 0.05),
        staged.spatial_consistency(corr, 0.05),
        atol=1e-9,
    )


def test_density_counts_paper_pruning(corr: np.ndarray) -> None:
    cfg = Config()
    counts = staged.density_counts(corr, config=cfg)
    assert counts.shape == (len(corr),) and counts.dtype == np.int64
    expected = (numpy_beta(corr, cfg.sigma_d) > cfg.tau_s).sum(axis=1)
    np.testing.assert_array_equal(counts, expected)
    np.testing.assert_array_equal(staged.density_counts(corr), expected)  # default config
    assert (counts > cfg.tau_n).any() and (counts <= cfg.tau_n).any()


def test_density_counts_with_features(corr: np.ndarray) -> None:
    rng = np.random.default_rng(0)
    feats = rng.normal(size=(len(corr), 4))
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    beta = numpy_beta(corr, 0.05)
    sim = feats @ feats.T
    paper = Config(tau_s=0.5)
    np.testing.assert_array_equal(
        staged.density_counts(corr, feats, paper), (sim * beta > 0.5).sum(axis=1)
    )
    authors = Config(pruning="authors")
    np.testing.assert_array_equal(
        staged.density_counts(corr, feats, authors),
        ((beta > authors.beta_threshold) & (sim > authors.feature_threshold)).sum(axis=1),
    )
    np.testing.assert_array_equal(
        staged.density_counts(corr, None, authors),
        (beta > authors.beta_threshold).sum(axis=1),
    )


def test_density_counts_thread_independent(corr: np.ndarray) -> None:
    np.testing.assert_array_equal(
        staged.density_counts(corr, num_threads=1), staged.density_counts(corr, num_threads=2)
    )


# --- Kabsch ---------------------------------------------------------------------------------


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    pose = np.eye(4)
    pose[:3, :3] = q
    pose[:3, 3] = rng.uniform(-5, 5, 3)
    return pose


@pytest.mark.parametrize("n", [3, 4, 100])
def test_kabsch_recovers_a_random_pose(n: int) -> None:
    rng = np.random.default_rng(n)
    pose = random_pose(rng)
    x = rng.normal(size=(n, 3))
    y = x @ pose[:3, :3].T + pose[:3, 3]
    est = staged.kabsch(x, y)
    assert est.shape == (4, 4) and est.dtype == np.float64
    np.testing.assert_allclose(est, pose, atol=1e-9)


def test_kabsch_least_squares_and_reflection() -> None:
    rng = np.random.default_rng(7)
    pose = random_pose(rng)
    x = rng.normal(size=(200, 3))
    y = x @ pose[:3, :3].T + pose[:3, 3] + rng.normal(scale=0.01, size=(200, 3))
    est = staged.kabsch(x, y)
    # the closed-form optimum: no other pose nearby has a lower residual
    rss = np.sum((x @ est[:3, :3].T + est[:3, 3] - y) ** 2)
    assert rss <= np.sum((x @ pose[:3, :3].T + pose[:3, 3] - y) ** 2)
    np.testing.assert_allclose(est, pose, atol=0.01)
    # mirrored target: still a proper rotation
    mirrored = staged.kabsch(x, x * [1.0, 1.0, -1.0])
    assert np.linalg.det(mirrored[:3, :3]) == pytest.approx(1.0)
    # coplanar points determine the pose
    flat = x * [1.0, 1.0, 0.0]
    np.testing.assert_allclose(
        staged.kabsch(flat, flat @ pose[:3, :3].T + pose[:3, 3]), pose, atol=1e-9
    )
