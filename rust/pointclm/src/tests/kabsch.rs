//! Unit tests of `kabsch`.

use super::*;
use crate::testing::random_rotation;
use rand::{Rng, SeedableRng};

#[test]
fn recovers_known_pose() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    for _ in 0..20 {
        let truth = RigidTransform {
            rotation: random_rotation(&mut rng),
            translation: Vector3::new(1.0, -2.0, 3.5),
        };
        let src: Vec<[f64; 3]> = (0..30)
            .map(|_| [rng.random(), rng.random(), rng.random()])
            .collect();
        let dst: Vec<[f64; 3]> = src.iter().map(|&p| truth.apply(p)).collect();
        let c = Correspondences::new(&src, &dst).unwrap();
        let idx: Vec<usize> = (0..30).collect();
        let est = kabsch(&c, &idx).unwrap();
        assert!((est.rotation - truth.rotation).abs().max() < 1e-9);
        assert!((est.translation - truth.translation).abs().max() < 1e-9);
        assert!((est.rotation.determinant() - 1.0).abs() < 1e-9);
    }
}

#[test]
fn rejects_collinear_and_fixes_reflection() {
    let src = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]];
    let c = Correspondences::new(&src, &src).unwrap();
    assert!(kabsch(&c, &[0, 1, 2]).is_none());
    // a mirrored point set: the best proper rotation, never a reflection
    let src = [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [1.0, 1.0, 1.0],
    ];
    let dst: Vec<[f64; 3]> = src.iter().map(|p| [-p[0], p[1], p[2]]).collect();
    let c = Correspondences::new(&src, &dst).unwrap();
    let t = kabsch(&c, &[0, 1, 2, 3]).unwrap();
    assert!((t.rotation.determinant() - 1.0).abs() < 1e-9);
}

#[test]
fn works_at_extreme_scales() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let base: Vec<[f64; 3]> = (0..10)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    for scale in [1e-100, 1e-30, 1e30, 1e80] {
        let pts: Vec<[f64; 3]> = base
            .iter()
            .map(|p| [p[0] * scale, p[1] * scale, p[2] * scale])
            .collect();
        let c = Correspondences::new(&pts, &pts).unwrap();
        let idx: Vec<usize> = (0..10).collect();
        let t = kabsch(&c, &idx).unwrap();
        assert!(
            (t.rotation - Matrix3::identity()).abs().max() < 1e-9,
            "scale {scale}"
        );
    }
}

#[test]
fn weighted_fit_ignores_zero_weights_and_matches_uniform() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let truth = RigidTransform {
        rotation: random_rotation(&mut rng),
        translation: Vector3::new(0.5, 0.1, -1.0),
    };
    let src: Vec<[f64; 3]> = (0..40)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    let mut dst: Vec<[f64; 3]> = src.iter().map(|&p| truth.apply(p)).collect();
    for p in dst.iter_mut().skip(30) {
        *p = [rng.random(), rng.random(), rng.random()]; // outliers
    }
    let c = Correspondences::new(&src, &dst).unwrap();
    let idx: Vec<usize> = (0..40).collect();
    let w: Vec<f64> = (0..40).map(|i| if i < 30 { 1.0 } else { 0.0 }).collect();
    let est = kabsch_weighted(&c, &idx, &w).unwrap();
    assert!((est.rotation - truth.rotation).abs().max() < 1e-9);
    let uniform = kabsch_weighted(&c, &idx[..30], &[1.0; 30]).unwrap();
    let plain = kabsch(&c, &idx[..30]).unwrap();
    assert!((uniform.rotation - plain.rotation).abs().max() < 1e-12);
    assert!(kabsch_weighted(&c, &idx, &[0.0; 40]).is_none());
    assert!(kabsch_weighted(&c, &idx, &[1.0; 3]).is_none());
}
