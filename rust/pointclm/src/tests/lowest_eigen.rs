//! Unit tests of `lowest_eigen`.

use super::*;
use crate::spectral::tests::block_affinity;
use crate::spectral::{eigengap, normalized_laplacian, symmetric_eigen};

/// Largest principal angle's sine between the column spans of `a` and `b` (orthonormal).
fn subspace_distance(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> f64 {
    // || (I - B B^T) A ||_F bounds the sines of the principal angles.
    let mut worst = 0.0f64;
    for c in 0..a.ncols() {
        let mut v: Vec<f64> = (0..a.nrows()).map(|i| a[(i, c)]).collect();
        for k in 0..b.ncols() {
            let p: f64 = (0..b.nrows()).map(|i| b[(i, k)] * v[i]).sum();
            for (i, x) in v.iter_mut().enumerate() {
                *x -= p * b[(i, k)];
            }
        }
        worst = worst.max(v.iter().map(|x| x * x).sum::<f64>().sqrt());
    }
    worst
}

#[test]
fn agrees_with_the_dense_decomposition() {
    let sizes = [120, 90, 200, 150, 60, 80];
    let l = normalized_laplacian(block_affinity(&sizes).as_ref()).unwrap();
    let (exact, vecs) = symmetric_eigen(l.as_ref(), true).unwrap();
    let vecs = vecs.unwrap();
    let low = lowest_eigenpairs(l.as_ref(), 200, 0, |e| (e.converged >= 10).then_some(6)).unwrap();
    assert!(low.converged >= 10);
    // The groups' eigenvalues; past them the blocks' own spectrum is a tight cluster near 1,
    // where any converged Ritz value is as good as another for the gap.
    let k = sizes.len();
    for (s, e) in low.values[..low.converged].iter().zip(&exact).take(k + 1) {
        assert!((s - e).abs() < 0.02, "{s} vs {e}");
    }
    for (s, e) in low.values[..low.converged].iter().zip(&exact).take(k) {
        assert!((s - e).abs() < 1e-5, "{s} vs {e}");
    }
    // The groups' eigenvectors span the same space (the spectral embedding's input).
    let d = subspace_distance(
        low.vectors.as_ref().subcols(0, k),
        vecs.as_ref().subcols(0, k),
    );
    assert!(d < 1e-3, "{d}");
    assert_eq!(eigengap(&low.values[..low.converged], None), k);
}

#[test]
fn disconnected_groups_beyond_the_block_width() {
    // More exactly decoupled groups than a block has columns: the eigenvalue near 0 has
    // multiplicity 24, and the Krylov space turns invariant on every group it touches.
    let sizes = vec![25; 24];
    let l = normalized_laplacian(block_affinity(&sizes).as_ref()).unwrap();
    let (exact, _) = symmetric_eigen(l.as_ref(), false).unwrap();
    let low = lowest_eigenpairs(l.as_ref(), 300, 3, |e| (e.converged > 30).then_some(24)).unwrap();
    for (s, e) in low.values[..low.converged].iter().zip(&exact).take(24) {
        assert!((s - e).abs() < 1e-5, "{s} vs {e}");
    }
    assert_eq!(eigengap(&low.values[..low.converged], None), 24);
}

#[test]
fn same_seed_same_result_and_budget_is_respected() {
    let l = normalized_laplacian(block_affinity(&[100, 140, 90, 170]).as_ref()).unwrap();
    let a = lowest_eigenpairs(l.as_ref(), 150, 7, |e| (e.converged >= 8).then_some(4)).unwrap();
    let b = lowest_eigenpairs(l.as_ref(), 150, 7, |e| (e.converged >= 8).then_some(4)).unwrap();
    assert_eq!(a.values, b.values);
    assert_eq!(a.vectors, b.vectors);
    // Asking for more than the basis may hold hands the work back.
    assert!(lowest_eigenpairs(l.as_ref(), 150, 7, |e| (e.converged >= 400).then_some(4)).is_none());
    assert!(lowest_eigenpairs(l.as_ref(), BLOCK, 7, |_| Some(1)).is_none());
}
