//! The last stage on clouds: each pose the correspondences gave is refined by ICP against the
//! scan and checked against it.
//!
//! Why: a pose fitted to a few FPFH matches is off by a few voxels and degrees (a match lands
//! anywhere within about a voxel of the true point), and realistic scenes hold consistent
//! groups of wrong matches that yield wrong poses. The clouds settle both. ICP pulls a nearly
//! right pose onto the copy, and the share of the model the scan then explains (Open3D's
//! `fitness`) tells a copy from a pose floating over clutter. Poses that converge onto a copy
//! that a better pose already explains are duplicates.

use rayon::prelude::*;

use super::{check_points, check_positive, PointIndex};
use crate::correspondences::Correspondences;
use crate::error::{Error, Result};
use crate::kabsch::{kabsch, RigidTransform};

/// Lengths (in the clouds' units) and acceptance rules of [`refine_poses`].
#[derive(Debug, Clone, PartialEq)]
pub struct RefineParams {
    /// ICP stages, coarse to fine: model points farther than this from the scan are left out
    /// of the fit. Empty: no ICP, verification only.
    pub radii: Vec<f64>,
    /// At most this many ICP iterations per stage (a stage ends early once the pose stops
    /// moving).
    pub iterations: usize,
    /// A model point is explained when a scan point lies within this distance.
    pub fit_radius: f64,
    /// Poses explaining a smaller share of the model are rejected.
    pub min_fitness: f64,
    /// Poses explaining less than this share of the best pose's fitness are rejected: copies
    /// of one object seen by one sensor are seen alike, whatever the object.
    pub min_relative_fitness: f64,
    /// A pose is a duplicate when more than this share of the scan points it explains are
    /// already explained by a better pose.
    pub max_shared: f64,
}

impl RefineParams {
    /// The defaults for clouds downsampled at `voxel`: ICP at 3, 2 and 1.5 voxels, fitness
    /// within 1.5 voxels (a downsampled point lies within about half a voxel of the surface,
    /// on each side, plus noise).
    pub fn for_voxel(voxel: f64) -> Self {
        Self {
            radii: vec![3.0 * voxel, 2.0 * voxel, 1.5 * voxel],
            iterations: 10,
            fit_radius: 1.5 * voxel,
            min_fitness: 0.3,
            min_relative_fitness: 0.8,
            max_shared: 0.5,
        }
    }

    fn check(&self) -> Result<()> {
        for &r in &self.radii {
            check_positive("radii", r)?;
        }
        check_positive("fit_radius", self.fit_radius)?;
        for (name, v) in [
            ("min_fitness", self.min_fitness),
            ("min_relative_fitness", self.min_relative_fitness),
            ("max_shared", self.max_shared),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::InvalidParameter {
                    name,
                    value: v.to_string(),
                    reason: "must lie in [0, 1]",
                });
            }
        }
        Ok(())
    }
}

/// One accepted pose.
#[derive(Debug, Clone, PartialEq)]
pub struct RefinedPose {
    /// `T_target_source` after ICP.
    pub pose: RigidTransform,
    /// Share of the model's points with a scan point within `fit_radius`.
    pub fitness: f64,
    /// RMS distance from those model points to their nearest scan points.
    pub inlier_rmse: f64,
    /// Index of the input pose this one came from.
    pub origin: usize,
}

/// Refines every pose by ICP against `target` (in parallel on the current rayon pool), then
/// keeps the poses that pass [`RefineParams`]' rules, best fitness first (ties: input order).
/// The result does not depend on the number of threads.
pub fn refine_poses(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    poses: &[RigidTransform],
    params: &RefineParams,
) -> Result<Vec<RefinedPose>> {
    check_points(source, "source points", 3)?;
    check_points(target, "target points", 3)?;
    params.check()?;
    if let Some(row) = poses.iter().position(|p| {
        !(p.rotation.iter().all(|v| v.is_finite()) && p.translation.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::NonFinite { what: "poses", row });
    }
    let index = PointIndex::new(target)?;
    let fitted: Vec<(RigidTransform, Explained)> = poses
        .par_iter()
        .map(|pose| {
            let refined = icp(source, target, &index, *pose, params);
            (
                refined,
                explained(source, &index, &refined, params.fit_radius),
            )
        })
        .collect();

    let best = fitted.iter().map(|(_, e)| e.fitness).fold(0.0, f64::max);
    let floor = params.min_fitness.max(params.min_relative_fitness * best);
    let mut order: Vec<usize> = (0..fitted.len()).collect();
    order.sort_by(|&a, &b| {
        fitted[b]
            .1
            .fitness
            .total_cmp(&fitted[a].1.fitness)
            .then(a.cmp(&b))
    });
    let mut claimed = vec![false; target.len()];
    let mut kept = Vec::new();
    for k in order {
        let (pose, e) = &fitted[k];
        if e.fitness < floor || e.targets.is_empty() {
            continue;
        }
        let shared = e.targets.iter().filter(|&&j| claimed[j]).count();
        if shared as f64 > params.max_shared * e.targets.len() as f64 {
            continue;
        }
        for &j in &e.targets {
            claimed[j] = true;
        }
        kept.push(RefinedPose {
            pose: *pose,
            fitness: e.fitness,
            inlier_rmse: e.rmse,
            origin: k,
        });
    }
    Ok(kept)
}

/// What a pose explains: the share of model points near the scan, their RMS distance, and
/// the scan points they land on (sorted, distinct).
struct Explained {
    fitness: f64,
    rmse: f64,
    targets: Vec<usize>,
}

fn explained(
    source: &[[f64; 3]],
    index: &PointIndex,
    pose: &RigidTransform,
    radius: f64,
) -> Explained {
    let r_sq = radius * radius;
    let (mut sum, mut targets) = (0.0, Vec::new());
    for p in source {
        let (j, d_sq) = index.nearest(&pose.apply(*p));
        if d_sq < r_sq {
            sum += d_sq;
            targets.push(j);
        }
    }
    let hits = targets.len();
    targets.sort_unstable();
    targets.dedup();
    Explained {
        fitness: hits as f64 / source.len() as f64,
        rmse: if hits > 0 {
            (sum / hits as f64).sqrt()
        } else {
            0.0
        },
        targets,
    }
}

/// Point-to-point ICP over shrinking radii; a step that cannot be fitted (fewer than 3 model
/// points near the scan, or all on a line) keeps the pose it has.
fn icp(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    index: &PointIndex,
    mut pose: RigidTransform,
    params: &RefineParams,
) -> RigidTransform {
    // How far a rotation change can move a model point: rotations turn about the origin.
    let reach = source
        .iter()
        .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
        .fold(0.0, f64::max);
    for &radius in &params.radii {
        let r_sq = radius * radius;
        for _ in 0..params.iterations {
            let (mut from, mut to) = (Vec::new(), Vec::new());
            for p in source {
                let (j, d_sq) = index.nearest(&pose.apply(*p));
                if d_sq < r_sq {
                    from.push(*p);
                    to.push(target[j]);
                }
            }
            let Ok(pairs) = Correspondences::new(&from, &to) else {
                break;
            };
            let all: Vec<usize> = (0..pairs.len()).collect();
            let Some(next) = kabsch(&pairs, &all) else {
                break;
            };
            let moved = (next.rotation - pose.rotation).amax() * reach
                + (next.translation - pose.translation).amax();
            pose = next;
            // Converged: the last step moved no model point by more than a sliver of the radius.
            if moved < 1e-4 * radius {
                break;
            }
        }
    }
    pose
}

#[cfg(test)]
#[path = "../tests/refine.rs"]
mod tests;
