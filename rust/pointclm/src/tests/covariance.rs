use nalgebra::{Rotation3, Vector3};

use super::*;
use crate::error::Error;

/// A triaxial ellipsoid sampled on a grid of angles, with its exact unit normals: no
/// continuous symmetry, so the scan pins every direction.
fn ellipsoid(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let (a, b, c) = (1.0, 0.6, 0.35);
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for i in 0..n {
        for j in 0..2 * n {
            let th = std::f64::consts::PI * (i as f64 + 0.5) / n as f64;
            let ph = std::f64::consts::PI * j as f64 / n as f64;
            let p = Vector3::new(
                a * th.sin() * ph.cos(),
                b * th.sin() * ph.sin(),
                c * th.cos(),
            );
            let g = Vector3::new(p.x / (a * a), p.y / (b * b), p.z / (c * c)).normalize();
            pts.push(p.into());
            nrm.push(g.into());
        }
    }
    (pts, nrm)
}

fn pose() -> RigidTransform {
    RigidTransform {
        rotation: *Rotation3::from_euler_angles(0.3, -0.5, 1.1).matrix(),
        translation: Vector3::new(2.0, -1.0, 4.0),
    }
}

/// The model posed by `pose`, each point pushed `noise(i)` along its normal, with the posed
/// normals: a scan of the model at `pose`.
fn scan_of(
    model: &[[f64; 3]],
    normals: &[[f64; 3]],
    pose: &RigidTransform,
    noise: impl Fn(usize) -> f64,
) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut pts = Vec::new();
    let mut nrm = Vec::new();
    for (i, (p, n)) in model.iter().zip(normals).enumerate() {
        let nv = pose.rotation * Vector3::from(*n);
        let q = Vector3::from(pose.apply(*p)) + noise(i) * nv;
        pts.push(q.into());
        nrm.push(nv.into());
    }
    (pts, nrm)
}

fn wobble(i: usize) -> f64 {
    0.004 * ((i as f64) * 12.9898).sin()
}

fn covariance_at(noise: impl Fn(usize) -> f64) -> PoseCovariance {
    let (model, normals) = ellipsoid(24);
    let (scan, scan_normals) = scan_of(&model, &normals, &pose(), noise);
    let index = PointIndex::new(&scan).unwrap();
    let out = pose_covariances(&model, &index, &scan, &scan_normals, &[pose()], 0.05).unwrap();
    out[0].clone()
}

#[test]
fn a_curved_part_at_its_true_pose_is_fully_observable() {
    let c = covariance_at(wobble);
    assert_eq!(c.unobservable, 0);
    assert_eq!(c.pairs, 24 * 48);
    assert!(c.residual_variance > 0.0);
    let eig = c.covariance.symmetric_eigenvalues();
    assert!(eig.iter().all(|&l| l > 0.0), "{eig:?}");
    assert!((c.covariance - c.covariance.transpose()).norm() < 1e-12 * c.covariance.norm());
    // Observable everywhere: the covariance is the residual variance over the information.
    let inverse = c.information.try_inverse().unwrap() * c.residual_variance;
    assert!((inverse - c.covariance).norm() < 1e-6 * inverse.norm());
}

#[test]
fn covariance_scales_with_the_noise_variance() {
    let one = covariance_at(wobble);
    let two = covariance_at(|i| 2.0 * wobble(i));
    // Near the poles a noisier scan pairs a few points with a neighbour: close, not exact.
    let ratio = two.residual_variance / one.residual_variance;
    assert!((ratio - 4.0).abs() < 0.2, "{ratio}");
    assert!((two.covariance - one.covariance * 4.0).norm() < 0.1 * two.covariance.norm());
    assert!((two.information - one.information).norm() < 0.02 * one.information.norm());
}

#[test]
fn a_plane_leaves_its_slides_and_spin_unobservable() {
    let mut model = Vec::new();
    for i in 0..30 {
        for j in 0..30 {
            model.push([i as f64 * 0.02, j as f64 * 0.02, 0.0]);
        }
    }
    let up = vec![[0.0, 0.0, 1.0]; model.len()];
    let at = RigidTransform {
        rotation: nalgebra::Matrix3::identity(),
        translation: Vector3::new(0.5, 0.25, 1.0),
    };
    let (scan, scan_normals) = scan_of(&model, &up, &at, wobble);
    let index = PointIndex::new(&scan).unwrap();
    let c = pose_covariance(&model, &index, &scan, &scan_normals, &at, 0.05);
    assert_eq!(c.unobservable, 3);
    // rz, x and y: no pair's residual changes along them.
    for k in [2, 3, 4] {
        assert!(c.information.row(k).norm() < 1e-9, "{}", c.information);
    }
    assert!(c.information[(5, 5)] > 800.0);
    // The slide is large and finite; the normal direction stays tight.
    assert!(c.covariance[(3, 3)] > 1e4 * c.covariance[(5, 5)]);
    assert!(c.covariance.iter().all(|v| v.is_finite()));
}

#[test]
fn too_few_pairs_know_nothing_and_bad_normals_are_refused() {
    let (model, normals) = ellipsoid(8);
    let (scan, scan_normals) = scan_of(&model, &normals, &pose(), |_| 0.0);
    let index = PointIndex::new(&scan).unwrap();
    let far = RigidTransform {
        rotation: nalgebra::Matrix3::identity(),
        translation: Vector3::new(100.0, 0.0, 0.0),
    };
    let c = pose_covariance(&model, &index, &scan, &scan_normals, &far, 0.05);
    assert_eq!((c.pairs, c.unobservable), (0, 6));
    assert!(c.covariance.iter().all(|v| v.is_finite()));
    assert!(c
        .covariance
        .symmetric_eigenvalues()
        .iter()
        .all(|&l| l > 0.0));
    let short = &scan_normals[1..];
    let err = pose_covariances(&model, &index, &scan, short, &[far], 0.05).unwrap_err();
    assert!(matches!(err, Error::LengthMismatch { .. }), "{err:?}");
    let err = pose_covariances(&model, &index, &scan, &scan_normals, &[far], 0.0).unwrap_err();
    assert!(matches!(err, Error::InvalidParameter { .. }), "{err:?}");
}
