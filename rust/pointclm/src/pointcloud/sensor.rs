//! Where the sensor of a single range scan stood, from the scan alone.
//!
//! Why: verification judges a pose by what the sensor could see of the copy
//! ([`super::visibility`]), and without a viewpoint it falls back to the share of the model
//! explained, which cannot tell a copy's visible side from a model posed on clutter (realistic
//! validation scenes: F1 0.667 without the viewpoint against 0.895 with it, BENCHMARKS.md).
//! A scan exported in a world frame has lost its sensor's position, but not the geometry of
//! one view: from its sensor, each ray ends at its first surface, so a single view hides almost
//! none of its own points; from elsewhere, parallax puts points behind others along the rays,
//! more the farther the eye moves from the sensor. The position that hides the fewest scan
//! points estimates the sensor. The count is flat in the distance beyond the sensor (far eyes
//! see the scan almost orthographically) and rises towards the scan, so the search keeps the
//! nearest distance among counts equal within their noise.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::visibility::DepthMap;
use super::{check_points, check_positive};
use crate::error::{Error, Result};

/// At most this many scan points (evenly strided) are counted per candidate position: the
/// share of hidden points is a mean, settled long before every point is used.
pub const SENSOR_SAMPLE: usize = 8000;
/// Ranges within this many voxels along a ray are one surface: a voxel's noise and the depth a
/// slanted surface spans in one cell, twice the trust test's resolution but tighter than its 5
/// voxels, so that the count rises as soon as the eye leaves the sensor.
pub const SENSOR_TOLERANCE_VOXELS: f64 = 2.0;
/// Distances tried from the scan's centroid, in scan radii (log-spaced): from inside the
/// scene's bounding sphere to a sensor far away.
const NEAREST_RADII: f64 = 0.6;
const FARTHEST_RADII: f64 = 8.0;
const DISTANCES: usize = 12;
/// The direction search's steps in degrees: coarse at a middle distance, then fine at the
/// chosen one.
const COARSE_STEPS_DEG: [f64; 3] = [12.0, 6.0, 3.0];
const FINE_STEPS_DEG: [f64; 2] = [3.0, 1.5];

type V = Vector3<f64>;

/// An estimated sensor position and the share of the scan it hides.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorEstimate {
    pub position: [f64; 3],
    /// Share of the (sampled) scan points lying more than `SENSOR_TOLERANCE_VOXELS` behind
    /// another scan point along the rays from `position`.
    pub hidden_share: f64,
    /// How many scan points the share counts (at most `SENSOR_SAMPLE`): its standard error is
    /// `sqrt(share (1 - share) / points)`.
    pub points: usize,
}

/// The position, on the side of `towards` as seen from the scan's centroid, from which
/// `scan` (downsampled at `voxel`) hides the fewest of its own points: a pattern search over
/// directions at twice the scan's radius, then twice over distances along the best direction
/// (the nearest whose count is the lowest within its noise) and over directions again at the
/// distance found, in finer steps. Deterministic.
///
/// `towards` picks the side: a single view looks alike from its sensor and from the mirror
/// position behind its surfaces when they are flat, so the caller says which side is outside
/// (the normals' orientation). Errors: fewer than 3 points, non-finite input, a voxel that is
/// not a positive number.
pub fn estimate_sensor(scan: &[[f64; 3]], voxel: f64, towards: [f64; 3]) -> Result<SensorEstimate> {
    check_points(scan, "scan points", 3)?;
    check_positive("voxel_size", voxel)?;
    if !towards.iter().all(|v| v.is_finite()) {
        return Err(Error::NonFinite {
            what: "towards",
            row: 0,
        });
    }
    let stride = scan.len().div_ceil(SENSOR_SAMPLE).max(1);
    let sample: Vec<[f64; 3]> = scan.iter().step_by(stride).copied().collect();
    let centre = centroid(&sample);
    let radius = sample
        .iter()
        .map(|p| (V::from(*p) - centre).norm())
        .fold(0.0, f64::max)
        .max(voxel);
    let hidden = |direction: V, distance: f64| {
        let eye = centre + direction * distance;
        DepthMap::own_hidden_share(&sample, eye.into(), voxel, SENSOR_TOLERANCE_VOXELS * voxel)
    };
    let start = unit(V::from(towards) - centre).unwrap_or(V::z());
    let (mut direction, _) = pattern_search(start, &COARSE_STEPS_DEG, |d| hidden(d, 2.0 * radius));
    // The best direction depends on the distance and the other way round: alternate.
    let mut distance = 2.0 * radius;
    let mut share = f64::INFINITY;
    for steps in [&COARSE_STEPS_DEG[1..], &FINE_STEPS_DEG[..]] {
        distance = nearest_best_distance(radius, sample.len(), |r| hidden(direction, r));
        (direction, share) = pattern_search(direction, steps, |d| hidden(d, distance));
    }
    Ok(SensorEstimate {
        position: (centre + direction * distance).into(),
        hidden_share: share,
        points: sample.len(),
    })
}

/// Points scored per candidate eye by [`estimate_viewpoint`] (a stride through the cloud):
/// enough for a stable tenth percentile, and the cost stays bounded on large scans.
pub const VIEWPOINT_SAMPLE: usize = 2000;

/// A point from which one sign rule orients every normal consistently.
///
/// Unoriented normals get their sign from a line of sight; the sign of a normal seen edge-on
/// is a coin toss. The eye chosen sees the fewest normals edge-on: the highest tenth
/// percentile of `|cos|` between normal and line of sight ([`edge_on_scores`]). Candidates:
/// the origin (sensor frames put the sensor there), the cloud's centroid (inside a closed or
/// convex surface, which every normal faces), and points 2, 8 and 1000 cloud radii from the
/// centroid in `n_directions` directions (a Fibonacci lattice: a sensor near, at a usual
/// distance, and as good as at infinity). A single range scan is seen head-on from its
/// sensor, so the result is that sensor or a point that orients like it, up to one global
/// sign (its mirror image behind the surface, or the inside of a convex object): which side is
/// outside is left to the caller. Errors: no points, a length mismatch, non-finite input,
/// no directions.
pub fn estimate_viewpoint(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    n_directions: usize,
) -> Result<[f64; 3]> {
    check_points(points, "points", 1)?;
    super::check_normals(normals, points.len(), "normals", "normals (one per point)")?;
    if n_directions == 0 {
        return Err(Error::InvalidParameter {
            name: "n_directions",
            value: "0".into(),
            reason: "must be at least 1",
        });
    }
    let step = points.len().div_ceil(VIEWPOINT_SAMPLE).max(1);
    let p: Vec<[f64; 3]> = points.iter().step_by(step).copied().collect();
    let n: Vec<[f64; 3]> = normals.iter().step_by(step).copied().collect();
    let centre = crate::scene::mean_point(&p);
    let radius = p
        .iter()
        .map(|q| {
            ((q[0] - centre[0]).powi(2) + (q[1] - centre[1]).powi(2) + (q[2] - centre[2]).powi(2))
                .sqrt()
        })
        .fold(f64::NEG_INFINITY, f64::max)
        .max(f64::MIN_POSITIVE);
    let golden = std::f64::consts::PI * (1.0 + 5.0f64.sqrt());
    let dirs: Vec<[f64; 3]> = (0..n_directions)
        .map(|k| {
            let i = k as f64 + 0.5;
            let z = 1.0 - 2.0 * i / n_directions as f64;
            let r = (1.0 - z * z).sqrt();
            let a = golden * i;
            [r * a.cos(), r * a.sin(), z]
        })
        .collect();
    let mut eyes = vec![[0.0; 3], centre];
    for scale in [2.0, 8.0, 1e3] {
        let reach = scale * radius;
        eyes.extend(
            dirs.iter()
                .map(|d| [0, 1, 2].map(|k| centre[k] + reach * d[k])),
        );
    }
    let scores = super::edge_on_scores(&p, &n, &eyes, (p.len() - 1) / 10)?;
    // The first of the best, as numpy's argmax.
    let best = (0..scores.len()).fold(0, |b, i| if scores[i] > scores[b] { i } else { b });
    Ok(eyes[best])
}

/// The nearest distance (from `NEAREST_RADII` to `FARTHEST_RADII` scan radii, `DISTANCES`
/// log-spaced values) whose share `cost` lies within two standard errors of the lowest (a
/// share of `n` points): beyond the sensor the count barely moves, so the farther distances
/// win only by sampling noise.
fn nearest_best_distance(radius: f64, n: usize, cost: impl Fn(f64) -> f64 + Sync) -> f64 {
    let ratio = (FARTHEST_RADII / NEAREST_RADII).powf(1.0 / (DISTANCES - 1) as f64);
    let tried: Vec<(f64, f64)> = (0..DISTANCES)
        .into_par_iter()
        .map(|i| {
            let d = NEAREST_RADII * radius * ratio.powi(i as i32);
            (d, cost(d))
        })
        .collect();
    let low = tried.iter().map(|t| t.1).fold(f64::INFINITY, f64::min);
    let noise = 2.0 * (low * (1.0 - low) / n.max(1) as f64).sqrt();
    tried
        .iter()
        .find(|t| t.1 <= low + noise)
        .map_or(2.0 * radius, |t| t.0)
}

/// Compass search on the unit sphere from `start`: at each step size, move to the best of
/// eight neighbours (four along two tangent axes, four diagonal) while one lowers `cost`.
/// Returns the direction and its cost.
fn pattern_search(start: V, steps_deg: &[f64], cost: impl Fn(V) -> f64 + Sync) -> (V, f64) {
    const MOVES: [(f64, f64); 8] = [
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0),
        (0.7, 0.7),
        (-0.7, 0.7),
        (0.7, -0.7),
        (-0.7, -0.7),
    ];
    let (mut at, mut best) = (start, cost(start));
    for &deg in steps_deg {
        let step = deg.to_radians().tan();
        // Each move must lower the cost, so the walk ends; the bound guards against a cost
        // that is not a function of the direction alone.
        for _ in 0..1000 {
            let (a, b) = tangents(&at);
            // The neighbours' costs in parallel; the lowest wins, the first among equals.
            let tried: Vec<Option<(V, f64)>> = MOVES
                .par_iter()
                .map(|&(x, y)| {
                    let next = unit(at + (a * x + b * y) * step)?;
                    Some((next, cost(next)))
                })
                .collect();
            let Some((next, c)) =
                tried
                    .into_iter()
                    .flatten()
                    .fold(None, |low: Option<(V, f64)>, t| match low {
                        Some(l) if l.1 <= t.1 => Some(l),
                        _ => Some(t),
                    })
            else {
                break;
            };
            if c >= best {
                break;
            }
            (at, best) = (next, c);
        }
    }
    (at, best)
}

/// Two unit vectors orthogonal to `d` and to each other.
fn tangents(d: &V) -> (V, V) {
    let helper = if d.x.abs() < 0.9 { V::x() } else { V::y() };
    let a = unit(d.cross(&helper)).unwrap_or(V::z());
    (a, d.cross(&a))
}

fn centroid(points: &[[f64; 3]]) -> V {
    let sum = points.iter().fold(V::zeros(), |s, p| s + V::from(*p));
    sum * (1.0 / points.len() as f64)
}

/// `a` scaled to unit length; `None` for a zero (or non-finite) vector.
fn unit(a: V) -> Option<V> {
    let n = a.norm();
    (n > 0.0 && n.is_finite()).then(|| a * (1.0 / n))
}

#[cfg(test)]
#[path = "../tests/sensor.rs"]
mod tests;
