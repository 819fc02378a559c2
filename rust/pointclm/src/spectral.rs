//! Spectral clustering of the kept correspondences: affinity, normalised Laplacian, full
//! symmetric eigendecomposition (faer; f32 for large kept sets), eigengap choice of the number
//! of instances and the row-normalised spectral embedding.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{
    self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors, SelfAdjointEvdParams,
};
use faer::{Mat, MatRef, Par, Spec};

use crate::consistency::{beta_row_subset, inv_sigma_sq};
use crate::correspondences::{Correspondences, Features};
use crate::error::{Error, Result};

/// Added to every affinity entry (as the authors' code does) so the graph is connected and
/// the degrees never vanish; isolated rows then become their own tiny clusters.
pub const AFFINITY_FLOOR: f64 = 1e-7;

/// Affinity of the kept set: soft spatial consistency at `sigma`, times the clamped feature
/// similarity when features are given, plus [`AFFINITY_FLOOR`].
pub fn affinity(
    c: &Correspondences,
    features: Option<&Features>,
    kept: &[usize],
    sigma: f64,
) -> Result<Mat<f64>> {
    let inv = inv_sigma_sq(sigma)?;
    let k = kept.len();
    let mut a = Mat::<f64>::zeros(k, k);
    let mut row = vec![0.0; k];
    // One triangle, mirrored: beta and the similarity are symmetric bit for bit (the same
    // products in the same order), so the matrix is the one computed in full.
    for (r, &i) in kept.iter().enumerate() {
        let upper = &kept[r..];
        beta_row_subset(c, i, upper, inv, &mut row[..upper.len()]);
        for (off, &j) in upper.iter().enumerate() {
            let b = row[off];
            let s = match features {
                // beta = 0 gives 0 whatever the similarity: skip its dot product
                Some(f) if b != 0.0 => b * f.similarity(i, j).max(0.0),
                _ => b,
            };
            a[(r, r + off)] = s + AFFINITY_FLOOR;
            a[(r + off, r)] = s + AFFINITY_FLOOR;
        }
    }
    Ok(a)
}

/// Checks that `m` is square, finite and symmetric (to a relative 1e-9).
pub fn check_symmetric(m: MatRef<'_, f64>) -> Result<()> {
    let n = m.nrows();
    if m.ncols() != n {
        return Err(Error::InvalidMatrix(format!(
            "expected a square matrix, got {} x {}",
            n,
            m.ncols()
        )));
    }
    let mut scale = 0.0f64;
    for j in 0..n {
        for i in 0..n {
            let v = m[(i, j)];
            if !v.is_finite() {
                return Err(Error::InvalidMatrix(format!(
                    "non-finite value at ({i}, {j})"
                )));
            }
            scale = scale.max(v.abs());
        }
    }
    for j in 0..n {
        for i in (j + 1)..n {
            if (m[(i, j)] - m[(j, i)]).abs() > 1e-9 * scale.max(1.0) {
                return Err(Error::InvalidMatrix(format!("not symmetric at ({i}, {j})")));
            }
        }
    }
    Ok(())
}

/// `L = I - D^-1/2 A D^-1/2` for a non-negative symmetric affinity `A`.
pub fn normalized_laplacian(a: MatRef<'_, f64>) -> Result<Mat<f64>> {
    check_symmetric(a)?;
    laplacian_of_symmetric(a)
}

/// [`normalized_laplacian`] of a matrix known to be square, finite and symmetric (the
/// pipeline's own [`affinity`], symmetric by construction); negative entries are still an
/// error. Why: checking symmetry reads the whole matrix twice, 2-3 % of a 2 ms call.
pub(crate) fn laplacian_of_symmetric(a: MatRef<'_, f64>) -> Result<Mat<f64>> {
    let n = a.nrows();
    let mut inv_sqrt_deg = vec![0.0; n];
    // Degrees as column sums: equal to the row sums of a symmetric matrix, and contiguous.
    for (j, d) in inv_sqrt_deg.iter_mut().enumerate() {
        let mut deg = 0.0;
        for (i, &v) in a.col(j).iter().enumerate() {
            if v < 0.0 {
                return Err(Error::InvalidMatrix(format!(
                    "affinity must be non-negative, got {v} at ({i}, {j})"
                )));
            }
            deg += v;
        }
        *d = if deg > 0.0 { 1.0 / deg.sqrt() } else { 0.0 };
    }
    Ok(Mat::from_fn(n, n, |i, j| {
        let off = a[(i, j)] * inv_sqrt_deg[i] * inv_sqrt_deg[j];
        if i == j {
            1.0 - off
        } else {
            -off
        }
    }))
}

/// Eigenvalues (ascending) and, if asked, eigenvectors (as columns) of a symmetric matrix.
///
/// Runs sequentially on purpose: the pipeline already parallelises across scenes and
/// clusters, and a fixed order of floating-point operations keeps results identical
/// whatever the thread count.
pub fn symmetric_eigen(m: MatRef<'_, f64>, vectors: bool) -> Result<(Vec<f64>, Option<Mat<f64>>)> {
    check_symmetric(m)?;
    let n = m.nrows();
    if n == 0 {
        return Ok((vec![], vectors.then(|| Mat::zeros(0, 0))));
    }
    let par = Par::Seq;
    let params: Spec<SelfAdjointEvdParams, f64> = Default::default();
    let compute = if vectors {
        ComputeEigenvectors::Yes
    } else {
        ComputeEigenvectors::No
    };
    let mut s = faer::diag::Diag::<f64>::zeros(n);
    let mut u = vectors.then(|| Mat::<f64>::zeros(n, n));
    let mut buf = MemBuffer::new(self_adjoint_evd_scratch::<f64>(n, compute, par, params));
    let stack = MemStack::new(&mut buf);
    self_adjoint_evd(
        m,
        s.as_mut(),
        u.as_mut().map(|u| u.as_mut()),
        par,
        stack,
        params,
    )
    .map_err(|_| Error::EigenNoConvergence { n })?;
    let values: Vec<f64> = (0..n).map(|i| s[i]).collect();
    Ok((values, u))
}

/// Rows from which [`symmetric_eigen_f32`] replaces the f64 decomposition in clustering.
pub const SINGLE_PRECISION_ROWS: usize = 400;

/// [`symmetric_eigen`] with eigenvectors, computed in f32 and returned in f64.
///
/// Why: past a few hundred rows the O(n^3) decomposition dominates the whole pipeline (0.58 s
/// in f64 against 0.25 s in f32 at n = 2000 on one core), while its consumers read only a few
/// digits: the eigengap compares gaps of order 1e-2 and more, and k-means places rows on the
/// unit sphere of the embedding. The affinity's own noise (descriptor matches within about a
/// voxel) is far above f32's rounding. Sequential, like [`symmetric_eigen`].
pub fn symmetric_eigen_f32(m: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>)> {
    check_symmetric(m)?;
    let n = m.nrows();
    let single = Mat::<f32>::from_fn(n, n, |i, j| m[(i, j)] as f32);
    let par = Par::Seq;
    let params: Spec<SelfAdjointEvdParams, f32> = Default::default();
    let mut s = faer::diag::Diag::<f32>::zeros(n);
    let mut u = Mat::<f32>::zeros(n, n);
    let mut buf = MemBuffer::new(self_adjoint_evd_scratch::<f32>(
        n,
        ComputeEigenvectors::Yes,
        par,
        params,
    ));
    self_adjoint_evd(
        single.as_ref(),
        s.as_mut(),
        Some(u.as_mut()),
        par,
        MemStack::new(&mut buf),
        params,
    )
    .map_err(|_| Error::EigenNoConvergence { n })?;
    let values = (0..n).map(|i| f64::from(s[i])).collect();
    Ok((values, Mat::from_fn(n, n, |i, j| f64::from(u[(i, j)]))))
}

/// Number of clusters from the largest gap of the ascending spectrum:
/// `M = argmax_k (lambda_{k+1} - lambda_k)`, k = 1..n-1 (1-based), optionally with `M <= cap`.
pub fn eigengap(eigenvalues: &[f64], cap: Option<usize>) -> usize {
    let n = eigenvalues.len();
    if n <= 1 {
        return n;
    }
    let last = cap.map_or(n - 1, |c| c.clamp(1, n - 1));
    let mut best = (1, f64::NEG_INFINITY);
    for k in 1..=last {
        let gap = eigenvalues[k] - eigenvalues[k - 1];
        if gap > best.1 {
            best = (k, gap);
        }
    }
    best.0
}

/// First `m` eigenvectors as rows of an `n x m` row-major matrix, each row scaled to unit
/// length (Ng, Jordan and Weiss), so points of one cluster sit near one direction.
pub fn row_normalized_embedding(vectors: MatRef<'_, f64>, m: usize) -> Vec<f64> {
    let n = vectors.nrows();
    let mut out = vec![0.0; n * m];
    for i in 0..n {
        let row = &mut out[i * m..(i + 1) * m];
        for (k, v) in row.iter_mut().enumerate() {
            *v = vectors[(i, k)];
        }
        let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        if norm > 0.0 {
            row.iter_mut().for_each(|v| *v /= norm);
        }
    }
    out
}

#[cfg(test)]
#[path = "tests/spectral.rs"]
pub(crate) mod tests;
