"""Each refined pose's information matrix and covariance (`pointclm.covariance`)."""

from __future__ import annotations

import numpy as np
import pytest
from pointclm.covariance import UNOBSERVABLE_SPREADS, pose_covariances
from posed_copies import posed_copies


def _bunny(noise: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    model, scan, poses = posed_copies(1)
    voxel = 0.01 * float(np.linalg.norm(np.ptp(model, axis=0)))
    rng = np.random.default_rng(seed)
    return model, scan + noise * voxel * rng.standard_normal(scan.shape), poses, voxel


def _assert_symmetric_psd(m: np.ndarray) -> None:
    np.testing.assert_allclose(m, m.T, atol=1e-12 * np.abs(m).max())
    assert np.linalg.eigvalsh(m).min() >= -1e-9 * np.abs(m).max()


def test_a_bunny_at_its_true_pose_is_pinned_in_every_direction() -> None:
    model, scan, poses, voxel = _bunny(0.1)
    out = pose_covariances(model, scan, poses, voxel)
    assert out.information.shape == (1, 6, 6) and out.covariance.shape == (1, 6, 6)
    assert out.unobservable.tolist() == [0]
    info, cov = out.information[0], out.covariance[0]
    _assert_symmetric_psd(info)
    _assert_symmetric_psd(cov)
    assert np.linalg.eigvalsh(cov).min() > 0
    expected = out.residual_variance[0] * np.linalg.inv(info)
    np.testing.assert_allclose(cov, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
    # Translation standard deviations well under a voxel: the pose is known.
    assert np.sqrt(np.diag(cov)[3:]).max() < 0.5 * voxel


def test_the_covariance_grows_with_the_scan_noise() -> None:
    model, quiet, poses, voxel = _bunny(0.05)
    _, loud, _, _ = _bunny(0.2)
    a = pose_covariances(model, quiet, poses, voxel)
    b = pose_covariances(model, loud, poses, voxel)
    ratio = np.trace(b.covariance[0][3:, 3:]) / np.trace(a.covariance[0][3:, 3:])
    assert ratio > 4.0, ratio


def test_a_patch_on_a_plane_slides_and_the_information_shows_it() -> None:
    # A box's face on a table: a flat model patch lying on a larger flat scan.
    g = np.linspace(0.0, 1.0, 21)
    model = np.stack(np.meshgrid(g, g, [0.0]), -1).reshape(-1, 3)
    h = np.linspace(-1.0, 2.0, 61)
    scan = np.stack(np.meshgrid(h, h, [0.0]), -1).reshape(-1, 3)
    scan[:, 2] += 0.002 * np.sin(np.arange(len(scan)) * 12.9898)
    pose = np.eye(4)
    pose[:3, 3] = [0.3, -0.2, 0.0]
    out = pose_covariances(model, scan, pose[None], 0.05)
    info, cov = out.information[0], out.covariance[0]
    assert out.unobservable[0] == 3
    # The information's near-null space is the slide: x, y and the turn about the normal (z).
    w, v = np.linalg.eigh(info)
    assert w[2] < 1e-3 * w[-1]
    slide = np.zeros((6, 3))
    slide[[3, 4, 2], [0, 1, 2]] = 1.0
    np.testing.assert_allclose(np.linalg.svd(v[:, :3].T @ slide)[1], 1.0, atol=1e-3)
    # The slide carries a large finite variance, the normal direction a small one.
    assert np.isfinite(cov).all()
    assert cov[3, 3] > (0.1 * UNOBSERVABLE_SPREADS) ** 2
    assert cov[5, 5] < 1e-4


def test_bad_poses_are_refused() -> None:
    model, scan, _, voxel = _bunny(0.0)
    with pytest.raises(ValueError, match="transformations"):
        pose_covariances(model, scan, np.eye(3), voxel)
    assert pose_covariances(model, scan, np.zeros((0, 4, 4)), voxel).covariance.shape == (0, 6, 6)


def test_registered_copies_carry_their_information_and_covariance() -> None:
    from pointclm import register_point_clouds

    model, scan, poses, voxel = _bunny(0.1)
    reg = register_point_clouds(model, scan, voxel_size=2 * voxel)
    assert reg.instances
    for inst in reg.instances:
        assert inst.information.shape == (6, 6) and inst.covariance.shape == (6, 6)
        _assert_symmetric_psd(inst.information)
        _assert_symmetric_psd(inst.covariance)
    again = pose_covariances(
        reg.source_points, reg.target_points, reg.transformations, reg.voxel_size
    )
    assert reg.instances[0].unobservable == int(again.unobservable[0]) == 0
