//! Unit tests of `spectral`.

use super::*;

/// `k` dense blocks of the given sizes, weak noise between blocks.
pub(crate) fn block_affinity(sizes: &[usize]) -> Mat<f64> {
    let n: usize = sizes.iter().sum();
    let mut block = Vec::with_capacity(n);
    for (b, &s) in sizes.iter().enumerate() {
        block.extend(std::iter::repeat_n(b, s));
    }
    Mat::from_fn(n, n, |i, j| {
        let same = block[i] == block[j];
        let jitter = ((i * 31 + j * 17) % 7) as f64 * 0.01 + ((j * 31 + i * 17) % 7) as f64 * 0.01;
        if same {
            0.8 + jitter
        } else {
            AFFINITY_FLOOR
        }
    })
}

#[test]
fn eigengap_finds_block_count() {
    for sizes in [vec![12, 20], vec![10, 15, 30, 11], vec![25; 7]] {
        let a = block_affinity(&sizes);
        let l = normalized_laplacian(a.as_ref()).unwrap();
        let (vals, _) = symmetric_eigen(l.as_ref(), false).unwrap();
        assert!(vals.windows(2).all(|w| w[0] <= w[1]));
        assert_eq!(eigengap(&vals, None), sizes.len());
        assert_eq!(eigengap(&vals, Some(sizes.len() + 3)), sizes.len());
        assert!(eigengap(&vals, Some(1)) == 1);
    }
}

#[test]
fn eigenpairs_reconstruct() {
    let a = block_affinity(&[5, 9]);
    let l = normalized_laplacian(a.as_ref()).unwrap();
    let (vals, vecs) = symmetric_eigen(l.as_ref(), true).unwrap();
    let u = vecs.unwrap();
    let n = l.nrows();
    for k in 0..n {
        for i in 0..n {
            let lu: f64 = (0..n).map(|j| l[(i, j)] * u[(j, k)]).sum();
            assert!((lu - vals[k] * u[(i, k)]).abs() < 1e-10);
        }
    }
}

#[test]
fn rejects_asymmetric_and_nonfinite() {
    let mut a = Mat::<f64>::identity(3, 3);
    a[(0, 1)] = 0.5;
    assert!(symmetric_eigen(a.as_ref(), false).is_err());
    a[(1, 0)] = 0.5;
    assert!(symmetric_eigen(a.as_ref(), false).is_ok());
    a[(2, 2)] = f64::NAN;
    assert!(normalized_laplacian(a.as_ref()).is_err());
    let rect = Mat::<f64>::zeros(2, 3);
    assert!(symmetric_eigen(rect.as_ref(), false).is_err());
}

#[test]
fn single_precision_agrees_with_double() {
    let a = block_affinity(&[120, 90, 200, 150]);
    let l = normalized_laplacian(a.as_ref()).unwrap();
    let (exact, _) = symmetric_eigen(l.as_ref(), false).unwrap();
    let (single, vecs) = symmetric_eigen_f32(l.as_ref()).unwrap();
    assert_eq!(single.len(), exact.len());
    for (s, e) in single.iter().zip(&exact) {
        assert!((s - e).abs() < 1e-4, "{s} vs {e}");
    }
    assert_eq!(eigengap(&single, None), eigengap(&exact, None));
    // unit eigenvectors
    let norm: f64 = (0..l.nrows()).map(|i| vecs[(i, 0)] * vecs[(i, 0)]).sum();
    assert!((norm - 1.0).abs() < 1e-4);
}
