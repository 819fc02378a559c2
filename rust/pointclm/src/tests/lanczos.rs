//! Unit tests of `lanczos`: the partial spectrum agrees with the dense one.

use super::*;
use crate::spectral::tests::block_affinity;
use crate::spectral::{normalized_laplacian, symmetric_eigen};

fn laplacian(sizes: &[usize]) -> Mat<f64> {
    normalized_laplacian(block_affinity(sizes).as_ref()).unwrap()
}

#[test]
fn matches_dense_eigenvalues_and_subspace() {
    let sizes = [60, 45, 90, 30, 75, 50, 40, 70];
    let l = laplacian(&sizes);
    let (dense, dense_vecs) = symmetric_eigen(l.as_ref(), true).unwrap();
    let dense_vecs = dense_vecs.unwrap();
    let k = 16;
    let (vals, vecs) = smallest_eigenpairs(l.as_ref(), k, 7).expect("converges");
    for (a, b) in vals.iter().zip(&dense) {
        assert!((a - b).abs() < 1e-8, "{a} vs {b}");
    }
    // the first 8 eigenvectors span the same space (eigenvalues may coincide within a block)
    let m = sizes.len();
    for c in 0..m {
        let mut proj = 0.0;
        for d in 0..m {
            let dot: f64 = (0..l.nrows())
                .map(|i| vecs[(i, c)] * dense_vecs[(i, d)])
                .sum();
            proj += dot * dot;
        }
        assert!((proj - 1.0).abs() < 1e-6, "column {c}: {proj}");
    }
}

#[test]
fn same_seed_same_result_and_small_input_declined() {
    let l = laplacian(&[100, 150, 200]);
    let a = smallest_eigenpairs(l.as_ref(), 8, 3).unwrap();
    let b = smallest_eigenpairs(l.as_ref(), 8, 3).unwrap();
    assert_eq!(a.0, b.0);
    assert_eq!(a.1, b.1);
    assert!(smallest_eigenpairs(laplacian(&[50, 60]).as_ref(), 4, 0).is_none());
    assert!(smallest_eigenpairs(l.as_ref(), 200, 0).is_none());
}
