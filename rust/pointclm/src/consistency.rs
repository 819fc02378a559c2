//! Spatial consistency `beta_ij = [1 - d_ij^2 / sigma^2]_+` with
//! `d_ij = | ||x_i - x_j|| - ||y_i - y_j|| |`: a rigid motion preserves lengths, so two inliers
//! of the same instance have `beta` near 1 while unrelated pairs rarely do.
//!
//! Kernels work one row at a time so that callers never need the full `N x N` matrix.

use crate::correspondences::Correspondences;
use crate::error::{Error, Result};

/// Writes `beta_ij` for `j in cols` into `out` (same length as `cols`), for a fixed `i`.
///
/// Every consumer (dense matrix, blocked counts, affinity) goes through this one function, so
/// their values agree bit for bit.
#[inline]
pub(crate) fn beta_row_subset(
    c: &Correspondences,
    i: usize,
    cols: &[usize],
    inv_sigma_sq: f64,
    out: &mut [f64],
) {
    let (s, t) = (c.source_columns(), c.target_columns());
    let (sx, sy, sz) = (s[0][i], s[1][i], s[2][i]);
    let (tx, ty, tz) = (t[0][i], t[1][i], t[2][i]);
    for (o, &j) in out.iter_mut().zip(cols) {
        *o = beta_value(
            [s[0][j] - sx, s[1][j] - sy, s[2][j] - sz],
            [t[0][j] - tx, t[1][j] - ty, t[2][j] - tz],
            inv_sigma_sq,
        );
    }
}

/// Row `i` of `beta` over all correspondences; the contiguous, vectorisable hot loop.
#[inline]
pub(crate) fn beta_row(c: &Correspondences, i: usize, inv_sigma_sq: f64, out: &mut [f64]) {
    let (s, t) = (c.source_columns(), c.target_columns());
    let (sx, sy, sz) = (s[0][i], s[1][i], s[2][i]);
    let (tx, ty, tz) = (t[0][i], t[1][i], t[2][i]);
    let n = c.len();
    let (s0, s1, s2) = (&s[0][..n], &s[1][..n], &s[2][..n]);
    let (t0, t1, t2) = (&t[0][..n], &t[1][..n], &t[2][..n]);
    for (j, o) in out[..n].iter_mut().enumerate() {
        *o = beta_value(
            [s0[j] - sx, s1[j] - sy, s2[j] - sz],
            [t0[j] - tx, t1[j] - ty, t2[j] - tz],
            inv_sigma_sq,
        );
    }
}

#[inline(always)]
fn beta_value(ds: [f64; 3], dt: [f64; 3], inv_sigma_sq: f64) -> f64 {
    let ls = (ds[0] * ds[0] + ds[1] * ds[1] + ds[2] * ds[2]).sqrt();
    let lt = (dt[0] * dt[0] + dt[1] * dt[1] + dt[2] * dt[2]).sqrt();
    let d = ls - lt;
    (1.0 - d * d * inv_sigma_sq).max(0.0)
}

pub(crate) fn inv_sigma_sq(sigma: f64) -> Result<f64> {
    if sigma.is_finite() && sigma > 0.0 {
        Ok(1.0 / (sigma * sigma))
    } else {
        Err(Error::InvalidConfig {
            field: "sigma_d",
            value: sigma.to_string(),
            reason: "must be a finite length > 0",
        })
    }
}

/// The dense `N x N` matrix (row-major). For small inputs, tests and inspection only: the
/// pipeline itself never materialises it.
pub fn spatial_consistency(c: &Correspondences, sigma: f64) -> Result<Vec<f64>> {
    let inv = inv_sigma_sq(sigma)?;
    let n = c.len();
    let mut m = vec![0.0; n * n];
    for (i, row) in m.chunks_exact_mut(n).enumerate() {
        beta_row(c, i, inv, row);
    }
    Ok(m)
}

#[cfg(test)]
#[path = "tests/consistency.rs"]
mod tests;
