//! Depth steps: whether a range scan's normals, fitted within a radius, describe its surfaces
//! or the flat terraces of its sensor's depth quantisation, and the radius that describes them.
//!
//! Why: a depth sensor quantises depth (1/8-pixel disparity steps, 16-bit depth units), and
//! the steps grow with the square of the range: 11 mm at 2 m for a camera of 900 px focal
//! length and 5 cm baseline finding disparity to 1/8 pixel.
//! On a surface turned away from the sensor each step is a flat terrace facing it, several
//! voxels wide, so a normal fitted within one terrace is the line of sight, not the surface:
//! FPFH describes terraces, and verification finds every right pose crossing the scan.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::normals::{estimate_normals, pca_normal, Orientation};
use super::{check_index, check_normals, check_positive, PointIndex};
use crate::error::Result;

/// At most this many scan points (a stride) measure the terracing: a share, settled long
/// before every point is used.
const TERRACE_SAMPLE: usize = 4000;

/// Normals are compared at the radius and twice it: a pair turned by more than this counts
/// (the angle within which verification calls two normals alike).
const TURNED_DEG: f64 = 30.0;

/// A scan is terraced at a radius when, of its sampled points, the share whose normal there
/// turns towards the line of sight (against the normal over twice the radius, by more than
/// [`TURNED_DEG`]) exceeds the share turning away from it by more than this. Noise turns
/// normals either way; only steps facing the sensor turn them towards it. On the validation
/// matrix (`benchmarks/results/matrix/depth_steps.md`) the far 2 m camera measures 0.16-0.19,
/// every other cell -0.16 to 0.03 (flying pixels up to 0.03; time-of-flight noise and the narrow
/// and off-centre cameras turn them away), the real scans without steps (Stanford range scans,
/// 3DMatch fragments) -0.07 to 0.04, so 0.1 sits apart from both; chosen on the far camera
/// against all the others. PCL's Kinect frame measures 0.16-0.22 at voxels of 3-5 mm.
pub const MAX_TERRACED_SHARE: f64 = 0.1;

/// The share of `points` whose normals (`normals`, fitted within `radius`, either sign) turn
/// towards the line of sight to `eye` against the normals fitted within twice `radius`,
/// less the share turning away (see [`MAX_TERRACED_SHARE`]); 0 for fewer than 3 points.
/// Errors: an index not built on `points`, normals not one per point, a radius not positive.
pub fn terraced_share(
    points: &[[f64; 3]],
    index: &PointIndex,
    normals: &[[f64; 3]],
    radius: f64,
    eye: [f64; 3],
) -> Result<f64> {
    check_index(index, points)?;
    check_normals(normals, points.len(), "normals", "normals (one per point)")?;
    check_positive("normal radius", radius)?;
    if points.len() < 3 {
        return Ok(0.0);
    }
    let stride = (points.len() / TERRACE_SAMPLE).max(1);
    let rows: Vec<usize> = (0..points.len()).step_by(stride).collect();
    let min_cos = TURNED_DEG.to_radians().cos();
    let (toward, away) = rows
        .par_iter()
        .map_init(Vec::new, |near: &mut Vec<u32>, &i| {
            let p = &points[i];
            near.clear();
            let wide = index.hybrid(p, 2.0 * radius, coarse_max_nn(NEIGHBOURS));
            near.extend(wide.into_iter().map(|(j, _)| j as u32));
            if near.len() < 3 {
                return (0usize, 0usize);
            }
            let coarse = Vector3::from(pca_normal(points, near));
            let fine = Vector3::from(normals[i]);
            if fine.dot(&coarse).abs() >= min_cos {
                return (0, 0);
            }
            let sight = (Vector3::from(eye) - Vector3::from(*p)).normalize();
            if !sight.iter().all(|v| v.is_finite()) {
                return (0, 0);
            }
            if fine.dot(&sight).abs() > coarse.dot(&sight).abs() {
                (1, 0)
            } else {
                (0, 1)
            }
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    Ok((toward as f64 - away as f64) / rows.len() as f64)
}

/// Neighbours a normal within the usual radius is fitted to (the scan's description's).
const NEIGHBOURS: usize = 30;

/// The neighbour cap for normals over twice a radius whose cap is `max_nn`: the disc holds
/// four times the points.
fn coarse_max_nn(max_nn: usize) -> usize {
    4 * max_nn
}

/// The radius a range scan's normals describe its surfaces at: `radius`, or twice it where
/// the scan seen from `eye` is terraced at `radius` ([`terraced_share`] above
/// [`MAX_TERRACED_SHARE`]; `normals` fitted within `radius`).
pub fn scan_normal_radius(
    points: &[[f64; 3]],
    index: &PointIndex,
    normals: &[[f64; 3]],
    radius: f64,
    eye: [f64; 3],
) -> Result<f64> {
    let terraced = terraced_share(points, index, normals, radius, eye)? > MAX_TERRACED_SHARE;
    Ok(if terraced { 2.0 * radius } else { radius })
}

/// A range scan's normals that describe its surfaces: `fine` (fitted within `radius` to at
/// most `max_nn` points, signed by `orientation`), or, where the scan seen from `eye` is
/// terraced at `radius` ([`scan_normal_radius`]), fitted within twice it to at most four
/// times as many points, signed alike; true for those.
pub fn resolving_terraces(
    points: &[[f64; 3]],
    index: &PointIndex,
    fine: Vec<[f64; 3]>,
    (radius, max_nn): (f64, usize),
    orientation: Orientation,
    eye: [f64; 3],
) -> Result<(Vec<[f64; 3]>, bool)> {
    let chosen = scan_normal_radius(points, index, &fine, radius, eye)?;
    if chosen == radius {
        return Ok((fine, false));
    }
    let coarse = estimate_normals(points, index, chosen, coarse_max_nn(max_nn), orientation)?;
    Ok((coarse, true))
}

#[cfg(test)]
#[path = "../tests/terraces.rs"]
mod tests;
