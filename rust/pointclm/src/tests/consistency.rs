//! Unit tests of `consistency`.

use super::*;
use crate::testing::{random_scene, with_normals};

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

#[test]
fn normals_keep_rigid_pairs_and_cut_others() {
    let scene = random_scene(150, 2, 0.3, 21);
    let c = with_normals(&scene, 5);
    assert!(c.has_normals() && !scene.corr.has_normals());
    let n = c.len();
    let plain = spatial_consistency(&scene.corr, 0.3).unwrap();
    let b = spatial_consistency(&c, 0.3).unwrap();
    let (mut cut, mut compat) = (0, 0);
    for i in 0..n {
        assert_eq!(b[i * n + i], 1.0);
        for j in 0..n {
            let (v, p) = (b[i * n + j], plain[i * n + j]);
            assert!((0.0..=1.0).contains(&v) && v <= p + 1e-12);
            assert_eq!(v, b[j * n + i]);
            let (li, lj) = (scene.labels[i], scene.labels[j]);
            if li >= 0 && li == lj {
                // The normal term of a rigid pair is 1 (sign flips included).
                assert!((v - p).abs() <= 1e-9, "pair ({i}, {j}): {v} vs {p}");
            } else if p > 0.5 {
                compat += 1;
                cut += usize::from(v < 0.5 * p);
            }
        }
    }
    // Length-compatible pairs that are not rigid pairs mostly fail on their normals.
    assert!(compat > 100 && cut * 2 > compat, "{cut} of {compat}");
}

#[test]
fn subset_matches_full_row_with_normals() {
    let scene = random_scene(60, 2, 0.4, 12);
    let c = with_normals(&scene, 6);
    let inv = inv_sigma_sq(0.2).unwrap();
    let n = c.len();
    let cols: Vec<usize> = (0..n).rev().collect();
    let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n {
        beta_row(&c, i, inv, &mut a);
        beta_row_subset(&c, i, &cols, inv, &mut b);
        b.reverse();
        assert_eq!(a, b);
    }
}

#[test]
fn bad_normals_are_typed_errors() {
    let scene = random_scene(10, 1, 1.0, 1);
    let ok = vec![[0.0, 0.0, 1.0]; 10];
    let mut zero = ok.clone();
    zero[4] = [0.0; 3];
    let mut nan = ok.clone();
    nan[2][1] = f64::NAN;
    let c = &scene.corr;
    for (s, t, tol) in [
        (&ok[..9], &ok[..], 0.5),
        (&ok[..], &zero[..], 0.5),
        (&nan[..], &ok[..], 0.5),
        (&ok[..], &ok[..], 0.0),
        (&ok[..], &ok[..], f64::NAN),
        (&ok[..], &ok[..], 3.0),
    ] {
        assert!(c.clone().with_normals(s, t, tol).is_err());
    }
    assert!(c.clone().with_normals(&ok, &ok, 0.5).is_ok());
}
