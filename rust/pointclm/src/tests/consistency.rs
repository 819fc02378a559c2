//! Unit tests of `consistency`.

use super::*;
use crate::testing::random_scene;

#[test]
fn symmetric_in_unit_interval_with_unit_diagonal() {
    let scene = random_scene(120, 2, 0.3, 7);
    let n = scene.corr.len();
    let b = spatial_consistency(&scene.corr, 0.05).unwrap();
    for i in 0..n {
        assert_eq!(b[i * n + i], 1.0);
        for j in 0..n {
            let v = b[i * n + j];
            assert!((0.0..=1.0).contains(&v));
            assert!((v - b[j * n + i]).abs() <= 1e-12);
        }
    }
}

#[test]
fn rigid_pairs_are_consistent() {
    let scene = random_scene(60, 1, 1.0, 3);
    let n = scene.corr.len();
    let b = spatial_consistency(&scene.corr, 0.05).unwrap();
    // noise-free inliers of one rigid motion: lengths preserved exactly
    assert!(b.iter().take(n * n).all(|&v| v > 1.0 - 1e-9));
}

#[test]
fn subset_matches_full_row() {
    let scene = random_scene(50, 2, 0.5, 11);
    let inv = inv_sigma_sq(0.1).unwrap();
    let n = scene.corr.len();
    let cols: Vec<usize> = (0..n).collect();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        beta_row(&scene.corr, i, inv, &mut a);
        beta_row_subset(&scene.corr, i, &cols, inv, &mut b);
        assert_eq!(a, b);
    }
}
