//! Spatial consistency `beta_ij = [1 - d_ij^2 / sigma^2]_+` with
//! `d_ij = | ||x_i - x_j|| - ||y_i - y_j|| |`: a rigid motion preserves lengths, so two inliers
//! of the same instance have `beta` near 1 while unrelated pairs rarely do.
//!
//! With surface normals at both ends ([`Correspondences::with_normals`]) `beta` is multiplied
//! by a normal term on the pair's point pair feature (Drost et al., CVPR 2010), which a rigid
//! motion also preserves; it stays in `[0, 1]`, so every consumer is unchanged.
//!
//! Kernels work one row at a time so that callers never need the full `N x N` matrix.

use crate::correspondences::{Correspondences, PairNormals};
use crate::error::{Error, Result};

/// Writes `beta_ij` for `j in cols` into `out` (same length as `cols`), for a fixed `i`.
///
/// Every consumer (dense matrix, blocked counts, affinity) goes through this one function or
/// [`beta_row`], so their values agree bit for bit.
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
    match c.pair_normals() {
        None => {
            for (o, &j) in out.iter_mut().zip(cols) {
                *o = beta_value(
                    [s[0][j] - sx, s[1][j] - sy, s[2][j] - sz],
                    [t[0][j] - tx, t[1][j] - ty, t[2][j] - tz],
                    inv_sigma_sq,
                );
            }
        }
        Some(pn) => {
            let row = NormalRow::new(pn, i, inv_sigma_sq);
            for (o, &j) in out.iter_mut().zip(cols) {
                *o = row.beta(
                    [s[0][j] - sx, s[1][j] - sy, s[2][j] - sz],
                    [t[0][j] - tx, t[1][j] - ty, t[2][j] - tz],
                    pn.source(j),
                    pn.target(j),
                );
            }
        }
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
    match c.pair_normals() {
        None => {
            for (j, o) in out[..n].iter_mut().enumerate() {
                *o = beta_value(
                    [s0[j] - sx, s1[j] - sy, s2[j] - sz],
                    [t0[j] - tx, t1[j] - ty, t2[j] - tz],
                    inv_sigma_sq,
                );
            }
        }
        Some(pn) => {
            let row = NormalRow::new(pn, i, inv_sigma_sq);
            let (m0, m1, m2) = (&pn.src[0][..n], &pn.src[1][..n], &pn.src[2][..n]);
            let (u0, u1, u2) = (&pn.dst[0][..n], &pn.dst[1][..n], &pn.dst[2][..n]);
            for (j, o) in out[..n].iter_mut().enumerate() {
                *o = row.beta(
                    [s0[j] - sx, s1[j] - sy, s2[j] - sz],
                    [t0[j] - tx, t1[j] - ty, t2[j] - tz],
                    [m0[j], m1[j], m2[j]],
                    [u0[j], u1[j], u2[j]],
                );
            }
        }
    }
}

#[inline(always)]
pub(crate) fn beta_value(ds: [f64; 3], dt: [f64; 3], inv_sigma_sq: f64) -> f64 {
    let ls = (ds[0] * ds[0] + ds[1] * ds[1] + ds[2] * ds[2]).sqrt();
    let lt = (dt[0] * dt[0] + dt[1] * dt[1] + dt[2] * dt[2]).sqrt();
    let d = ls - lt;
    (1.0 - d * d * inv_sigma_sq).max(0.0)
}

#[inline(always)]
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// What the normal term needs of row `i`, hoisted out of the loop over `j`.
struct NormalRow {
    ns: [f64; 3],
    nt: [f64; 3],
    inv_sigma_sq: f64,
    sigma: f64,
    inv_tol_sq: f64,
    tol: f64,
}

impl NormalRow {
    fn new(pn: &PairNormals, i: usize, inv_sigma_sq: f64) -> Self {
        Self {
            ns: pn.source(i),
            nt: pn.target(i),
            inv_sigma_sq,
            sigma: inv_sigma_sq.sqrt().recip(),
            inv_tol_sq: pn.inv_tol_sq,
            tol: pn.tol,
        }
    }

    /// The length term times the normal term: the cosine between the two normals and the
    /// distance of each point from the other's tangent plane must agree on both sides. Plane
    /// distances are compared in length units with a tolerance `tol * l + sigma`, so a line
    /// shorter than a few `sigma` (whose direction is mostly noise) barely counts.
    #[inline(always)]
    fn beta(&self, ds: [f64; 3], dt: [f64; 3], ms: [f64; 3], mt: [f64; 3]) -> f64 {
        let ls = dot(ds, ds).sqrt();
        let lt = dot(dt, dt).sqrt();
        let d = ls - lt;
        let length = (1.0 - d * d * self.inv_sigma_sq).max(0.0);
        // Absolute values: a sign flip of either normal changes no term (see `with_normals`).
        let da = dot(self.ns, ms).abs() - dot(self.nt, mt).abs();
        let dp = dot(self.ns, ds).abs() - dot(self.nt, dt).abs();
        let dq = dot(ms, ds).abs() - dot(mt, dt).abs();
        let w = self.tol * 0.5 * (ls + lt) + self.sigma;
        let inv_w_sq = 1.0 / (w * w);
        // (i, j) and (j, i) swap the two plane terms: multiplying them first keeps beta
        // symmetric bit for bit.
        let planes = (1.0 - dp * dp * inv_w_sq).max(0.0) * (1.0 - dq * dq * inv_w_sq).max(0.0);
        length * (1.0 - da * da * self.inv_tol_sq).max(0.0) * planes
    }
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
