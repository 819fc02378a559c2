//! How well the scan determines a refined pose: the 6 x 6 information matrix of
//! point-to-plane ICP at the final pose and the pose covariance it gives.
//!
//! Parameters, in this order: a small rotation `omega` (rx, ry, rz, radians, about the scan
//! frame's axes) and a translation `dt` (x, y, z, in the clouds' units), perturbing the pose
//! `T = (R, t)` as `R <- exp([omega]x) R`, `t <- t + dt`: the rotation turns the model about
//! its own origin (the pose's translation), so the position and orientation blocks are those
//! of a ROS `PoseWithCovariance` (which orders them translation first).

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};
use rayon::prelude::*;

use super::{check_normals, check_points, check_positive, PointIndex};
use crate::error::Result;
use crate::kabsch::RigidTransform;

/// An unobservable direction's standard deviation, in spreads of the explained points about
/// their centroid (translations) or in radians (rotations): large and finite, so that a
/// covariance stays JSON-safe and a ROS consumer reads "unknown" without meeting infinity.
/// Why not larger: a noisy face's slide directions lean a little (by its normals' noise)
/// towards the pinned ones, and this variance leaks into them by that lean squared.
pub const UNOBSERVABLE_SPREADS: f64 = 10.0;

/// A direction of the (centred, rotation scaled by the spread) information matrix is
/// unobservable when its eigenvalue is below this share of the largest. Why this value: a
/// flat face's in-plane directions are pinned only by the scan normals' noise, about `sin^2`
/// of its angle (1.2e-3 at 2 degrees, 5e-3 at 4), and the covariance there says nothing about
/// the pose; a bunny's smallest direction sits near 0.06.
pub const MIN_RELATIVE_EIGENVALUE: f64 = 5e-3;

/// One pose's information and covariance (order: rx, ry, rz, x, y, z; see the module).
#[derive(Clone, Debug, PartialEq)]
pub struct PoseCovariance {
    /// `sum J^T J` over the pairs, `J = [((p - t) x n)^T, n^T]` for a posed model point `p`
    /// and the unit normal `n` of its nearest scan point: the Gauss-Newton normal matrix,
    /// not divided by the residual variance, returned as is (singular along a slide).
    pub information: Matrix6<f64>,
    /// `residual_variance` times the pseudo-inverse of `information` over its observable
    /// directions, plus `UNOBSERVABLE_SPREADS` standard deviations along each unobservable
    /// one. Symmetric positive semi-definite, finite.
    pub covariance: Matrix6<f64>,
    /// `sum r^2 / (pairs - 6)` of the point-to-plane residuals `r = n . (p - q)`; 0 with
    /// six pairs or fewer.
    pub residual_variance: f64,
    /// Model points with a scan point within the radius (the pairs `fitness` counts).
    pub pairs: usize,
    /// How many of the six directions the scan does not determine (all six with six pairs or
    /// fewer).
    pub unobservable: usize,
}

/// [`pose_covariance`] of each of `poses`, in parallel on the current rayon pool (the result
/// does not depend on the thread count). `scan_normals`: one unit normal (either sign) per
/// point `index` holds.
///
/// Errors: non-finite model points or normals, normals not one per scan point, a radius that
/// is not positive and finite.
pub fn pose_covariances(
    model: &[[f64; 3]],
    index: &PointIndex,
    scan: &[[f64; 3]],
    scan_normals: &[[f64; 3]],
    poses: &[RigidTransform],
    radius: f64,
) -> Result<Vec<PoseCovariance>> {
    check_points(model, "model points", 0)?;
    check_points(scan, "scan points", 0)?;
    check_normals(
        scan_normals,
        scan.len(),
        "scan normals",
        "scan normals (one per scan point)",
    )?;
    check_normals(
        scan_normals,
        index.len(),
        "scan normals",
        "scan normals (one per indexed scan point)",
    )?;
    check_positive("radius", radius)?;
    Ok(poses
        .par_iter()
        .map(|pose| pose_covariance(model, index, scan, scan_normals, pose, radius))
        .collect())
}

/// The information and covariance of `pose` over the model points with a scan point within
/// `radius` (inputs checked by [`pose_covariances`]).
pub fn pose_covariance(
    model: &[[f64; 3]],
    index: &PointIndex,
    scan: &[[f64; 3]],
    scan_normals: &[[f64; 3]],
    pose: &RigidTransform,
    radius: f64,
) -> PoseCovariance {
    let t = pose.translation;
    let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = Vec::new();
    let mut information = Matrix6::zeros();
    let mut sum_sq = 0.0;
    for p in model {
        let posed = pose.apply(*p);
        let Some((j, _)) = index.nearest_within(&posed, radius) else {
            continue;
        };
        let n = Vector3::from(scan_normals[j]);
        let norm = n.norm();
        if norm == 0.0 {
            continue;
        }
        let n = n / norm;
        let q = Vector3::from(posed);
        let r = n.dot(&(q - Vector3::from(scan[j])));
        sum_sq += r * r;
        let row = jacobian(&(q - t), &n);
        information += row * row.transpose();
        pairs.push((q, n));
    }
    let k = pairs.len();
    if k <= 6 {
        return PoseCovariance {
            information,
            covariance: unknown(&pairs, t),
            residual_variance: 0.0,
            pairs: k,
            unobservable: 6,
        };
    }
    let residual_variance = sum_sq / (k - 6) as f64;
    let centre = pairs.iter().map(|(q, _)| q).sum::<Vector3<f64>>() / k as f64;
    let spread = spread_of(&pairs, &centre);
    // Observability is judged in centred coordinates with rotations as arcs at the spread:
    // rank does not depend on that choice, but conditioning does, and these make the six
    // directions comparable whatever the model's origin and units.
    let mut scaled = Matrix6::zeros();
    for (q, n) in &pairs {
        let row = jacobian(&((q - centre) / spread), n);
        scaled += row * row.transpose();
    }
    let eig = scaled.symmetric_eigen();
    let top = eig.eigenvalues.iter().copied().fold(0.0, f64::max);
    let unknown_var = (UNOBSERVABLE_SPREADS * spread).powi(2);
    let mut cov_scaled = Matrix6::zeros();
    let mut unobservable = 0;
    for i in 0..6 {
        let v = eig.eigenvectors.column(i);
        let lambda = eig.eigenvalues[i];
        let var = if top > 0.0 && lambda > MIN_RELATIVE_EIGENVALUE * top {
            residual_variance / lambda
        } else {
            unobservable += 1;
            unknown_var
        };
        cov_scaled += var * v * v.transpose();
    }
    PoseCovariance {
        information,
        covariance: to_origin(&cov_scaled, spread, &centre, &t),
        residual_variance,
        pairs: k,
        unobservable,
    }
}

/// `[(arm x n)^T, n^T]`: how the residual along `n` changes with (omega, dt).
fn jacobian(arm: &Vector3<f64>, n: &Vector3<f64>) -> Vector6<f64> {
    let c = arm.cross(n);
    Vector6::new(c.x, c.y, c.z, n.x, n.y, n.z)
}

/// RMS distance of the pairs' points from `centre`; 1 when they coincide.
fn spread_of(pairs: &[(Vector3<f64>, Vector3<f64>)], centre: &Vector3<f64>) -> f64 {
    if pairs.is_empty() {
        return 1.0;
    }
    let ms = pairs
        .iter()
        .map(|(q, _)| (q - centre).norm_squared())
        .sum::<f64>()
        / pairs.len() as f64;
    if ms > 0.0 {
        ms.sqrt()
    } else {
        1.0
    }
}

/// Nothing known: every direction at the unobservable variance, about the pairs' centroid.
fn unknown(pairs: &[(Vector3<f64>, Vector3<f64>)], t: Vector3<f64>) -> Matrix6<f64> {
    let centre = if pairs.is_empty() {
        t
    } else {
        pairs.iter().map(|(q, _)| q).sum::<Vector3<f64>>() / pairs.len() as f64
    };
    let spread = spread_of(pairs, &centre);
    let var = (UNOBSERVABLE_SPREADS * spread).powi(2);
    to_origin(&(Matrix6::identity() * var), spread, &centre, &t)
}

/// A covariance over (spread * omega, dt about `centre`) as one over (omega, dt about `t`):
/// `dt_t = dt_c + [c - t]x omega`.
fn to_origin(
    cov_scaled: &Matrix6<f64>,
    spread: f64,
    centre: &Vector3<f64>,
    t: &Vector3<f64>,
) -> Matrix6<f64> {
    let mut a = Matrix6::<f64>::identity();
    for i in 0..3 {
        a[(i, i)] = 1.0 / spread;
    }
    let arm = Matrix3::new(
        0.0,
        -(centre.z - t.z),
        centre.y - t.y,
        centre.z - t.z,
        0.0,
        -(centre.x - t.x),
        -(centre.y - t.y),
        centre.x - t.x,
        0.0,
    );
    // Rows 3..6 take dt_c plus the lever arm times omega (omega = scaled / spread).
    let lever = arm / spread;
    a.fixed_view_mut::<3, 3>(3, 0).copy_from(&lever);
    let cov = a * cov_scaled * a.transpose();
    (cov + cov.transpose()) * 0.5
}

#[cfg(test)]
#[path = "../tests/covariance.rs"]
mod tests;
