//! Peeling: what the accepted copies explain of the scan, so that the next pass matches the
//! rest, and which of a round's poses only repeat an accepted copy.

use rayon::prelude::*;

use crate::error::Result;
use crate::kabsch::RigidTransform;
use crate::pointcloud::{check_points, check_positive, PointIndex};

/// Per scan point, whether it lies at least `radius` from every point of `model` posed at
/// each of `poses` (every point, without poses). In parallel on the current rayon pool.
pub fn unexplained(
    scan: &[[f64; 3]],
    model: &[[f64; 3]],
    poses: &[RigidTransform],
    radius: f64,
) -> Result<Vec<bool>> {
    check_points(scan, "scan points", 0)?;
    check_points(model, "model points", 1)?;
    check_positive("radius", radius)?;
    if poses.is_empty() {
        return Ok(vec![true; scan.len()]);
    }
    let posed: Vec<[f64; 3]> = poses
        .iter()
        .flat_map(|pose| model.iter().map(move |&p| pose.apply(p)))
        .collect();
    let index = PointIndex::with_cells(&posed, radius)?;
    Ok(scan
        .par_iter()
        .map(|q| !index.any_within(q, radius))
        .collect())
}

/// The scan points (indices into `scan`'s, distinct and ascending) that are the nearest scan
/// point, within `radius`, of some point of `model` at `pose`: what a pose explains, as
/// verification counts it.
pub fn explained_scan_points(
    scan: &PointIndex,
    model: &[[f64; 3]],
    pose: &RigidTransform,
    radius: f64,
) -> Vec<usize> {
    let mut hits: Vec<usize> = model
        .iter()
        .filter_map(|&p| scan.nearest_within(&pose.apply(p), radius).map(|(i, _)| i))
        .collect();
    hits.sort_unstable();
    hits.dedup();
    hits
}

/// Indices of `poses` (surest first) whose explained scan points are at most `max_shared`
/// `taken` by accepted copies or by a surer pose of the list (verification's duplicate rule);
/// marks the kept poses' points taken. A pose that explains no scan point is not kept.
pub fn not_duplicates(
    scan: &PointIndex,
    model: &[[f64; 3]],
    poses: &[RigidTransform],
    radius: f64,
    max_shared: f64,
    taken: &mut [bool],
) -> Result<Vec<usize>> {
    check_points(model, "model points", 1)?;
    check_positive("radius", radius)?;
    crate::pointcloud::check_len(taken.len(), scan.len(), "taken (one per scan point)")?;
    let explained: Vec<Vec<usize>> = poses
        .par_iter()
        .map(|pose| explained_scan_points(scan, model, pose, radius))
        .collect();
    let mut keep = Vec::new();
    for (i, hits) in explained.iter().enumerate() {
        if hits.is_empty() {
            continue;
        }
        let shared = hits.iter().filter(|&&h| taken[h]).count();
        if shared as f64 / hits.len() as f64 > max_shared {
            continue;
        }
        for &h in hits {
            taken[h] = true;
        }
        keep.push(i);
    }
    Ok(keep)
}
