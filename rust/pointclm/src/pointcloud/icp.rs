//! ICP of one pose against the scan, point-to-plane.
//!
//! Why point-to-plane: a pose from correspondences sits a few voxels off its copy, and
//! point-to-point ICP pairs each model point with the nearest scan sample, which on a
//! downsampled surface lies up to half a voxel aside; the pairs pull along the surface as
//! much as onto it, and the pose creeps (it used the full iteration budget on almost every
//! candidate of a bin). Distances to the scan's tangent planes ignore where on the surface
//! the sample lies, so Gauss-Newton on them converges in a few steps. A small point-to-point
//! term keeps the step defined where the planes leave a motion free (a flat face, a
//! cylinder).

use nalgebra::{Matrix3, Matrix6, Rotation3, Vector3, Vector6};

use super::visibility::DepthMap;
use super::PointIndex;
use crate::grid::dist_sq;
use crate::kabsch::RigidTransform;

/// Weight of the point-to-point term against the point-to-plane one: enough to pin the
/// motions the planes leave free, small enough not to pull along the surface.
pub const POINT_WEIGHT: f64 = 0.1;

/// Model points the stages before the last use at most (evenly strided): they only have to
/// bring the pose within the next radius, which a few hundred pairs fix as well as thousands;
/// the last stage uses them all.
pub const COARSE_POINTS: usize = 500;

/// ICP over shrinking radii: model points farther than a stage's radius from the scan are
/// left out of its steps. A stage ends after `iterations` steps or once a step moves no model
/// point by more than 1e-4 of the radius; a step that cannot be solved (fewer than 3 pairs, or
/// a degenerate system) keeps the pose it has.
///
/// With `sight` (the scan's depth map around its sensor), each stage also leaves out the
/// model points that the model itself hides from the sensor at the stage's starting pose
/// ([`DepthMap::self_hidden`]). Why: a range scan holds nothing of a copy's far side, so
/// those points can only pair with other surfaces; in a heap its underside lies a voxel or
/// two above the copies it rests on, and the coarse stages pulled poses that started within
/// 1-3 degrees to 6-15 degrees off (validation bins, BENCHMARKS.md).
#[allow(clippy::too_many_arguments)] // one ICP: the clouds, the start, the schedule, the sensor
pub fn icp(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    normals: &[[f64; 3]],
    index: &PointIndex,
    pose: RigidTransform,
    radii: &[f64],
    iterations: usize,
    sight: Option<&DepthMap>,
) -> RigidTransform {
    icp_paired(
        source, target, normals, index, pose, radii, iterations, sight,
    )
    .0
}

/// [`icp`], and each model point's scan point at its last step ([`NO_PAIR`]: none), which
/// bounds the verification's search at the final pose.
#[allow(clippy::too_many_arguments)] // as `icp`
pub(crate) fn icp_paired(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    normals: &[[f64; 3]],
    index: &PointIndex,
    mut pose: RigidTransform,
    radii: &[f64],
    iterations: usize,
    sight: Option<&DepthMap>,
) -> (RigidTransform, Vec<u32>) {
    // How far a rotation change can move a model point: rotations turn about the origin.
    let reach = source
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .fold(0.0, f64::max);
    // Each model point's pair at its previous step, in any stage (`NO_PAIR`: none).
    let mut paired = vec![NO_PAIR; source.len()];
    for (stage, &radius) in radii.iter().enumerate() {
        let shown = match sight.map(|depth| facing(source, &pose, depth)) {
            Some(rows) if rows.len() >= 3 => rows,
            _ => (0..source.len()).collect(),
        };
        // The stages before the last only bring the pose within the next radius.
        let rows: Vec<usize> = if stage + 1 < radii.len() {
            let stride = shown.len().div_ceil(COARSE_POINTS).max(1);
            shown.into_iter().step_by(stride).collect()
        } else {
            shown
        };
        for _ in 0..iterations {
            let Some(next) = plane_step(
                source,
                &rows,
                target,
                normals,
                index,
                &pose,
                radius,
                &mut paired,
            ) else {
                break;
            };
            let moved = (next.rotation - pose.rotation).amax() * reach
                + (next.translation - pose.translation).amax();
            pose = next;
            if moved < 1e-4 * radius {
                break;
            }
        }
    }
    (pose, paired)
}

/// The rows of the model points that `depth` does not find hidden behind the model itself at
/// `pose`.
fn facing(source: &[[f64; 3]], pose: &RigidTransform, depth: &DepthMap) -> Vec<usize> {
    let posed: Vec<[f64; 3]> = source.iter().map(|p| pose.apply(*p)).collect();
    depth
        .self_hidden(&posed)
        .into_iter()
        .enumerate()
        .filter(|(_, hidden)| !hidden)
        .map(|(i, _)| i)
        .collect()
}

/// A model point without a pair at the previous ICP step.
pub(crate) const NO_PAIR: u32 = u32::MAX;

/// The scan point `paired` with a model point now at `posed` ([`NO_PAIR`]: none) with its
/// squared distance: what bounds the point's next search
/// ([`PointIndex::nearest_within_near`]).
pub(crate) fn previous_pair(
    paired: u32,
    target: &[[f64; 3]],
    posed: &[f64; 3],
) -> Option<(usize, f64)> {
    (paired != NO_PAIR).then(|| {
        let j = paired as usize;
        (j, dist_sq(&target[j], posed))
    })
}

/// One Gauss-Newton step on the pairs (posed model point of `rows`, nearest scan point
/// within `radius`), linearised about the pairs' centroid so that the rotation and
/// translation parts of the system have comparable scales. `paired` holds each model point's
/// scan point at its previous step ([`NO_PAIR`]: none), which bounds its search, and is
/// updated.
#[allow(clippy::too_many_arguments)] // one step: the clouds, the rows, the pose, the pairs
fn plane_step(
    source: &[[f64; 3]],
    rows: &[usize],
    target: &[[f64; 3]],
    normals: &[[f64; 3]],
    index: &PointIndex,
    pose: &RigidTransform,
    radius: f64,
    paired: &mut [u32],
) -> Option<RigidTransform> {
    let mut pairs = Vec::new();
    let mut centroid = Vector3::zeros();
    for &i in rows {
        let posed = pose.apply(source[i]);
        let last = &mut paired[i];
        let found = index.nearest_within_near(&posed, radius, previous_pair(*last, target, &posed));
        *last = found.map_or(NO_PAIR, |(j, _)| u32::try_from(j).unwrap_or(NO_PAIR));
        if let Some((j, _)) = found {
            let posed = Vector3::from(posed);
            centroid += posed;
            pairs.push((posed, j));
        }
    }
    if pairs.len() < 3 {
        return None;
    }
    centroid /= pairs.len() as f64;
    let (mut h, mut g) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
    for &(posed, j) in &pairs {
        let (q, n) = (Vector3::from(target[j]), Vector3::from(normals[j]));
        accumulate(&mut h, &mut g, posed - centroid, posed - q, n);
    }
    let delta = h.cholesky()?.solve(&(-g));
    if !delta.iter().all(|v| v.is_finite()) {
        return None;
    }
    let turn = Rotation3::new(Vector3::new(delta[0], delta[1], delta[2])).into_inner();
    let shift = Vector3::new(delta[3], delta[4], delta[5]);
    // x -> turn (x - c) + c + shift, after the current pose.
    Some(RigidTransform {
        rotation: turn * pose.rotation,
        translation: turn * (pose.translation - centroid) + centroid + shift,
    })
}

/// Adds one pair's normal equations for the motion (w, t), w a small rotation about the
/// centroid: `a` the posed model point from the centroid, `r` its offset from the scan
/// point, `n` the scan point's normal.
fn accumulate(
    h: &mut Matrix6<f64>,
    g: &mut Vector6<f64>,
    a: Vector3<f64>,
    r: Vector3<f64>,
    n: Vector3<f64>,
) {
    // Plane: n . (r + w x a + t) = n . r + (a x n) . w + n . t
    let an = a.cross(&n);
    let row = Vector6::new(an.x, an.y, an.z, n.x, n.y, n.z);
    *h += row * row.transpose();
    *g += row * n.dot(&r);
    // Point: r + w x a + t = r - [a]x w + t, weighted.
    let ax = a.cross_matrix();
    let w = POINT_WEIGHT;
    let top_left: Matrix3<f64> = ax.transpose() * ax * w;
    let off: Matrix3<f64> = -ax.transpose() * w;
    for i in 0..3 {
        for k in 0..3 {
            h[(i, k)] += top_left[(i, k)];
            h[(i, k + 3)] += off[(i, k)];
            h[(i + 3, k)] += off[(k, i)];
        }
        h[(i + 3, i + 3)] += w;
    }
    let gw = -ax.transpose() * r * w;
    for i in 0..3 {
        g[i] += gw[i];
        g[i + 3] += r[i] * w;
    }
}

#[cfg(test)]
#[path = "../tests/icp.rs"]
mod tests;
