//! Surface normals by PCA of each point's neighbourhood, oriented consistently.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::search::PointIndex;
use super::{check_count, check_index, check_normals, check_points, check_positive};
use crate::error::{Error, Result};

/// How to choose the sign of each normal, which PCA leaves undetermined. FPFH compares
/// normals across the two clouds, so both must follow the same rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Orientation {
    /// Towards a viewpoint: the sensor position for a scan (the usual choice; a range sensor
    /// sees only surfaces facing it).
    Towards([f64; 3]),
    /// Away from a point inside the object, e.g. a complete model's centroid: outward on
    /// roughly convex shapes, matching the sensor rule on the scan side.
    AwayFrom([f64; 3]),
}

/// One unit normal per point: the direction of least variance of its hybrid neighbourhood
/// (at most `max_nn` nearest within `radius`), signed by `orientation`. A point with fewer than
/// three neighbours gets `(0, 0, 1)` (oriented), as in Open3D.
pub fn estimate_normals(
    points: &[[f64; 3]],
    index: &PointIndex,
    radius: f64,
    max_nn: usize,
    orientation: Orientation,
) -> Result<Vec<[f64; 3]>> {
    check_points(points, "points for normals", 1)?;
    check_index(index, points)?;
    check_positive("normal radius", radius)?;
    check_count("normal max_nn", max_nn, 3)?;
    let anchor = match orientation {
        Orientation::Towards(v) | Orientation::AwayFrom(v) => v,
    };
    if !anchor.iter().all(|v| v.is_finite()) {
        return Err(Error::NonFinite {
            what: "normal orientation point",
            row: 0,
        });
    }
    // The lists FPFH uses too (from a grid where the cloud allows): nearest first, as the
    // tree's own search returns them.
    let hoods = index.neighbourhoods(points, radius, max_nn)?;
    Ok(points
        .par_iter()
        .enumerate()
        .map(|(i, p)| orient(pca_normal(points, hoods.of(i).0), p, orientation))
        .collect())
}

/// Unit normals of `points` (the cloud `index` was built on) from each point's `k` nearest
/// points whatever their distance, oriented by `orientation`: for comparing directions on a
/// cloud whose spacing is not known (a radius may hold too few points on a sparse cloud).
pub(crate) fn nearest_k_normals(
    points: &[[f64; 3]],
    index: &PointIndex,
    k: usize,
    orientation: Orientation,
) -> Vec<[f64; 3]> {
    points
        .par_iter()
        .map(|p| {
            let hood: Vec<u32> = index
                .nearest_k(p, k)
                .into_iter()
                .map(|(j, _)| j as u32)
                .collect();
            orient(pca_normal(points, &hood), p, orientation)
        })
        .collect()
}

/// For each eye of `eyes`, the `rank`-th smallest (from 0) `|cos|` of the angle between a
/// normal of `normals` and its point's line of sight from the eye: how close to edge-on the
/// eye sees the normals it sees worst, ignoring the `rank` worst. The eye that maximises it
/// orients the most normals unambiguously (`pointclm.preprocessing.estimate_viewpoint`). A
/// sight of zero length counts as `f64::MIN_POSITIVE`. Errors: no points, a length mismatch,
/// non-finite input, `rank` beyond the points.
pub fn edge_on_scores(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    eyes: &[[f64; 3]],
    rank: usize,
) -> Result<Vec<f64>> {
    check_points(points, "points", 1)?;
    check_normals(normals, points.len(), "normals", "normals (one per point)")?;
    check_points(eyes, "eyes", 0)?;
    if rank >= points.len() {
        return Err(Error::InvalidParameter {
            name: "rank",
            value: rank.to_string(),
            reason: "must be below the number of points",
        });
    }
    Ok(eyes
        .par_iter()
        .map_init(Vec::new, |cos, eye| {
            cos.clear();
            cos.extend(points.iter().zip(normals).map(|(p, n)| {
                let s = [eye[0] - p[0], eye[1] - p[1], eye[2] - p[2]];
                let length = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
                    .sqrt()
                    .max(f64::MIN_POSITIVE);
                (s[0] * n[0] + s[1] * n[1] + s[2] * n[2]).abs() / length
            }));
            *cos.select_nth_unstable_by(rank, f64::total_cmp).1
        })
        .collect())
}

/// The unit normal of the plane fitted to `points[neighbours]` (+z with fewer than three).
pub(super) fn pca_normal(points: &[[f64; 3]], neighbours: &[u32]) -> [f64; 3] {
    if neighbours.len() < 3 {
        return [0.0, 0.0, 1.0];
    }
    let inv = 1.0 / neighbours.len() as f64;
    let mut mean = Vector3::zeros();
    for &j in neighbours {
        mean += Vector3::from(points[j as usize]);
    }
    mean *= inv;
    let mut cov = Matrix3::zeros();
    for &j in neighbours {
        let d = Vector3::from(points[j as usize]) - mean;
        cov += d * d.transpose();
    }
    cov *= inv;
    let eig = SymmetricEigen::new(cov);
    let k = eig.eigenvalues.imin();
    let n = eig.eigenvectors.column(k).into_owned();
    let norm = n.norm();
    if norm <= 0.0 || !norm.is_finite() {
        return [0.0, 0.0, 1.0];
    }
    (n / norm).into()
}

fn orient(n: [f64; 3], p: &[f64; 3], orientation: Orientation) -> [f64; 3] {
    let (anchor, towards) = match orientation {
        Orientation::Towards(v) => (v, true),
        Orientation::AwayFrom(v) => (v, false),
    };
    let dot: f64 = (0..3).map(|k| n[k] * (anchor[k] - p[k])).sum();
    if (dot < 0.0) == towards {
        n.map(|v| -v)
    } else {
        n
    }
}

#[cfg(test)]
#[path = "../tests/normals.rs"]
mod tests;
