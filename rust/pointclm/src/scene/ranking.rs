//! The last stage: copies ranked against the scene's others. Copies of one part in one scan
//! are sampled by one sensor, so right poses fit alike and are pinned down alike; a pose that
//! fits looser than the scene's median copy, or that the scan pins down less firmly, comes
//! later or, when far looser, is dropped.

use nalgebra::{Matrix6, Vector3};
use rayon::prelude::*;

use super::{mean_point, median};
use crate::error::Result;
use crate::kabsch::RigidTransform;
use crate::pointcloud::{check_normals, check_points, check_positive, PointIndex};

/// Each value over the median of the finite ones; NaN where a value is not finite, and
/// everywhere when fewer than `min_poses` are finite (nothing to compare with).
pub fn relative_to_median(values: &[f64], min_poses: usize) -> Vec<f64> {
    let mut known: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if known.len() < min_poses.max(1) {
        return vec![f64::NAN; values.len()];
    }
    let median = median(&mut known);
    values
        .iter()
        .map(|&v| if v.is_finite() { v / median } else { f64::NAN })
        .collect()
}

/// Which poses fit the scan loosely against the others: `visible_rmse` above `max_relative`
/// times its median over the poses where it is known (none among fewer than `min_poses`).
pub fn loose_poses(visible_rmse: &[f64], max_relative: f64, min_poses: usize) -> Vec<bool> {
    relative_to_median(visible_rmse, min_poses)
        .into_iter()
        .map(|r| r > max_relative)
        .collect()
}

/// Each pose's factor of sureness from how tightly its visible side lies on the scan against
/// the scene's median pose: `min(1, median / visible_rmse)`, 1 where unknown or among fewer
/// than `min_poses` known values. Why: visible fitness saturates near 1 for every copy a
/// heap shows well, while a pose turned a little about a near-symmetry still pairs its
/// points with its copy's surface, a little looser than the right poses of the same scan.
pub fn fit_tightness(visible_rmse: &[f64], min_poses: usize) -> Vec<f64> {
    relative_to_median(visible_rmse, min_poses)
        .into_iter()
        .map(|r| at_most_one(1.0 / r))
        .collect()
}

/// Each pose's factor of sureness from [`pose_stability`] against the scene's median pose:
/// `min(1, stability / median)`, 1 where unknown or among fewer than `min_poses` known
/// values. Why relative: a right pose is pinned about as firmly as the scene's median copy,
/// whatever the part's shape; a pose resting on one face of a copy or of the bin is pinned
/// less.
pub fn stability_factor(stability: &[f64], min_poses: usize) -> Vec<f64> {
    relative_to_median(stability, min_poses)
        .into_iter()
        .map(at_most_one)
        .collect()
}

/// `min(1, ratio)`, and 1 where `ratio` is NaN.
fn at_most_one(ratio: f64) -> f64 {
    if ratio.is_nan() {
        1.0
    } else {
        ratio.min(1.0)
    }
}

/// How firmly the scan pins each pose down: the smallest over the largest eigenvalue of
/// point-to-plane ICP's 6 x 6 normal matrix (Gelfand et al. 2003, "Geometrically stable
/// sampling for the ICP algorithm") over the posed model points within `radius` of a scan
/// point, rotations taken about the posed model's centroid in units of the model's radius.
/// 0 where fewer than six points are explained. The sign of the normals does not matter.
/// In parallel on the current rayon pool; the result does not depend on the thread count.
///
/// Why: a pose whose explained part is one flat face is free to slide and spin in that plane,
/// and the scan cannot say where it is; a copy showing several faces or a curved side is
/// pinned in every direction.
pub fn pose_stability(
    model: &[[f64; 3]],
    model_normals: &[[f64; 3]],
    scan: &PointIndex,
    poses: &[RigidTransform],
    radius: f64,
) -> Result<Vec<f64>> {
    check_points(model, "model points", 1)?;
    check_normals(
        model_normals,
        model.len(),
        "model normals",
        "model normals (one per model point)",
    )?;
    check_positive("radius", radius)?;
    let centre = Vector3::from(mean_point(model));
    let scale = model
        .iter()
        .map(|p| (Vector3::from(*p) - centre).norm())
        .fold(0.0, f64::max);
    let scale = if scale > 0.0 { scale } else { 1.0 };
    Ok(poses
        .par_iter()
        .map(|pose| {
            let home = pose.rotation * centre + pose.translation;
            let mut normal = Matrix6::<f64>::zeros();
            let mut hits = 0usize;
            for (p, nrm) in model.iter().zip(model_normals) {
                let posed = pose.rotation * Vector3::from(*p) + pose.translation;
                if scan.nearest_within(&posed.into(), radius).is_none() {
                    continue;
                }
                hits += 1;
                let nv = pose.rotation * Vector3::from(*nrm);
                let arm = (posed - home) / scale;
                let c = arm.cross(&nv);
                let row = nalgebra::Vector6::new(c[0], c[1], c[2], nv[0], nv[1], nv[2]);
                normal += row * row.transpose();
            }
            if hits < 6 {
                return 0.0;
            }
            let eig = normal.symmetric_eigenvalues();
            let lo = eig.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = eig.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if hi > 0.0 {
                lo / hi
            } else {
                0.0
            }
        })
        .collect())
}
