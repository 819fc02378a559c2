//! The smallest eigenpairs of a normalised Laplacian without a full eigendecomposition.
//!
//! The eigengap needs only the bottom of the spectrum, and the spectral embedding only its
//! first eigenvectors; a dense decomposition of a 2000 x 2000 affinity costs O(n^3) (about a
//! second on one core) for n - k values nobody reads. `L = I - D^-1/2 A D^-1/2` has its
//! spectrum in [0, 2], so the smallest eigenvalues of `L` are the largest of `2I - L`, which
//! faer's restarted Lanczos (Krylov-Schur) finds with O(n^2) matrix-vector products.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::matrix_free::eigen::{
    partial_self_adjoint_eigen, partial_self_adjoint_eigen_scratch, PartialEigenParams,
};
use faer::{Col, Mat, MatRef, Par};
use rand::Rng;

use crate::seeds::{stream, STAGE_CLUSTERING};

/// Below this many rows the dense decomposition is as fast and exact: use it.
pub const PARTIAL_MIN_ROWS: usize = 400;

/// Residual tolerance of a converged eigenpair (eigenvalues lie in [0, 2]).
const TOLERANCE: f64 = 1e-10;

/// The `k` smallest eigenvalues (ascending) and their eigenvectors (as columns) of the
/// normalised Laplacian `l`, or `None` when the Krylov method does not apply (`k` too close
/// to `n`) or did not converge within its restarts: the caller then decomposes densely.
///
/// The start vector comes from `seed`, so the result is reproducible; everything runs on
/// one thread, so it does not depend on the pool either.
pub fn smallest_eigenpairs(
    l: MatRef<'_, f64>,
    k: usize,
    seed: u64,
) -> Option<(Vec<f64>, Mat<f64>)> {
    let n = l.nrows();
    // faer's Krylov-Schur needs a search space (at least 64 and twice k) smaller than n.
    if k == 0 || n < PARTIAL_MIN_ROWS || 4 * k > n || n <= 128 {
        return None;
    }
    let shifted = Mat::from_fn(
        n,
        n,
        |i, j| if i == j { 2.0 - l[(i, j)] } else { -l[(i, j)] },
    );
    let mut rng = stream(seed, STAGE_CLUSTERING, 1);
    let v0 = Col::from_fn(n, |_| rng.random_range(-1.0..1.0));
    let par = Par::Seq;
    let params = PartialEigenParams {
        max_restarts: 1000,
        ..Default::default()
    };
    let op = shifted.as_ref();
    let mut buf = MemBuffer::new(partial_self_adjoint_eigen_scratch(&op, k, par, params));
    let mut vectors = Mat::<f64>::zeros(n, k);
    let mut values = vec![0.0; k];
    let info = partial_self_adjoint_eigen(
        vectors.as_mut(),
        &mut values,
        &op,
        v0.as_ref(),
        TOLERANCE,
        par,
        MemStack::new(&mut buf),
        params,
    );
    if info.n_converged_eigen < k {
        return None;
    }
    // Largest of 2I - L first = smallest of L first; faer orders by magnitude, and 2I - L is
    // positive semi-definite, so magnitude order is value order.
    let mut order: Vec<usize> = (0..k).collect();
    order.sort_by(|&a, &b| values[b].total_cmp(&values[a]));
    let eigenvalues = order.iter().map(|&j| 2.0 - values[j]).collect();
    let eigenvectors = Mat::from_fn(n, k, |i, c| vectors[(i, order[c])]);
    Some((eigenvalues, eigenvectors))
}

#[cfg(test)]
#[path = "tests/lanczos.rs"]
mod tests;
