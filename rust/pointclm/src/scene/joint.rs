//! Several part types in one scan: each model's copies found on its own, then judged together,
//! so that a scan region one model's copy explains is not handed to another model's copy.
//!
//! Why after the fact rather than one joint search: each model keeps its own voxel, descriptors
//! and rules (a small box and a long one want different scales), and what they compete for is
//! the scan's points, which a common index of the scan settles.

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::pointcloud::{check_points, check_positive, voxel_downsample, PointIndex};

use super::register::{register_point_clouds, Candidate, SceneOptions, SceneRegistration};

/// One model's poses, as the joint check takes them.
#[derive(Debug, Clone)]
pub struct ModelPoses<'a> {
    /// The model's points (downsampled as its run used them).
    pub model: &'a [[f64; 3]],
    /// A scan point within this distance of a posed model point is explained by the pose (the
    /// model's run's fit radius: 1.5 of its voxels).
    pub radius: f64,
    /// The copies found: `T_target_source`, and the share of each copy's visible side where
    /// the sensor saw free space (NaN: not judged, counted as none).
    pub copies: Vec<(RigidTransform, f64)>,
    /// The ambiguous poses (sliding along a face), the same way; they never displace a copy.
    pub ambiguous: Vec<(RigidTransform, f64)>,
}

/// Which poses of each model the joint check keeps (by model, then by pose, in input order).
#[derive(Debug, Clone, PartialEq)]
pub struct JointVerdict {
    pub copies: Vec<Vec<bool>>,
    pub ambiguous: Vec<Vec<bool>>,
}

/// Judges every model's poses together on `scan` (any one resolution of the scan: the finest
/// run's downsampled scan is enough): every copy of every model, best first, is kept unless
/// more than `max_shared` of the scan points it explains are explained by a copy kept before
/// it; then the ambiguous poses likewise, after every copy. "Best" is the count of scan points
/// a pose explains times one minus its contradiction: the copy that explains more of the scan,
/// with less of it where the sensor saw free space, wins. A small box's pose on the top of a
/// long box explains part of what the long box's pose explains, and loses to it.
pub fn judge_jointly(
    scan: &[[f64; 3]],
    models: &[ModelPoses<'_>],
    max_shared: f64,
) -> Result<JointVerdict> {
    check_points(scan, "scan points", 1)?;
    if !(0.0..=1.0).contains(&max_shared) {
        return Err(Error::InvalidParameter {
            name: "max_shared",
            value: max_shared.to_string(),
            reason: "must lie in [0, 1]",
        });
    }
    for m in models {
        check_points(m.model, "model points", 1)?;
        check_positive("radius", m.radius)?;
    }
    let radius = models.iter().map(|m| m.radius).fold(0.0, f64::max);
    let index = PointIndex::with_cells(scan, radius.max(f64::MIN_POSITIVE))?;
    let mut verdict = JointVerdict {
        copies: models.iter().map(|m| vec![false; m.copies.len()]).collect(),
        ambiguous: models
            .iter()
            .map(|m| vec![false; m.ambiguous.len()])
            .collect(),
    };
    let mut claimed = vec![false; scan.len()];
    for ambiguous in [false, true] {
        let poses: Vec<(usize, usize, RigidTransform, f64)> = models
            .iter()
            .enumerate()
            .flat_map(|(m, mp)| {
                let list = if ambiguous { &mp.ambiguous } else { &mp.copies };
                list.iter()
                    .enumerate()
                    .map(move |(i, &(pose, contradiction))| (m, i, pose, contradiction))
            })
            .collect();
        let explained: Vec<Vec<usize>> = poses
            .par_iter()
            .map(|&(m, _, pose, _)| explained(&index, models[m].model, &pose, models[m].radius))
            .collect();
        let score = |k: usize| {
            let c = poses[k].3;
            explained[k].len() as f64 * (1.0 - if c.is_finite() { c } else { 0.0 })
        };
        let mut order: Vec<usize> = (0..poses.len()).collect();
        // Stable: equal scores keep the model order, then each model's own order.
        order.sort_by(|&a, &b| score(b).total_cmp(&score(a)));
        for k in order {
            let hits = &explained[k];
            let shared = hits.iter().filter(|&&h| claimed[h]).count();
            if !hits.is_empty() && shared as f64 > max_shared * hits.len() as f64 {
                continue;
            }
            for &h in hits {
                claimed[h] = true;
            }
            let (m, i, _, _) = poses[k];
            match ambiguous {
                false => verdict.copies[m][i] = true,
                true => verdict.ambiguous[m][i] = true,
            }
        }
    }
    Ok(verdict)
}

/// The scan points (ascending, distinct) within `radius` of some point of `model` at `pose`.
/// Every one within reach, not only each model point's nearest as verification counts them
/// ([`super::peeling::explained_scan_points`]): the models' voxels differ from the scan's here,
/// and a coarse model would claim only a fraction of the fine scan it covers.
fn explained(
    index: &PointIndex,
    model: &[[f64; 3]],
    pose: &RigidTransform,
    radius: f64,
) -> Vec<usize> {
    let mut hits: Vec<usize> = model
        .iter()
        .flat_map(|&p| index.within(&pose.apply(p), radius).map(|(i, _)| i))
        .collect();
    hits.sort_unstable();
    hits.dedup();
    hits
}

/// [`register_point_clouds`] of each of `models` in `scan`, then [`judge_jointly`]: one result
/// per model, in order, each holding only the copies (and ambiguous poses) the joint check
/// keeps. Each model gets its own default voxel unless `options.voxel_size` is set; the scan
/// they compete for is downsampled at the finest of them.
pub fn register_models(
    models: &[&[[f64; 3]]],
    scan: &[[f64; 3]],
    options: &SceneOptions,
) -> Result<Vec<SceneRegistration>> {
    if models.is_empty() {
        return Err(Error::InvalidParameter {
            name: "models",
            value: "[]".into(),
            reason: "give at least one model",
        });
    }
    let mut runs = models
        .iter()
        .map(|m| register_point_clouds(m, scan, options))
        .collect::<Result<Vec<_>>>()?;
    let finest = runs
        .iter()
        .map(|r| r.voxel_size)
        .fold(f64::INFINITY, f64::min);
    let common = voxel_downsample(scan, finest)?;
    let posed = |c: &[Candidate]| c.iter().map(|c| (c.pose, c.contradiction)).collect();
    let judged: Vec<ModelPoses> = runs
        .iter()
        .map(|r| ModelPoses {
            model: &r.source.points,
            radius: 1.5 * r.voxel_size,
            copies: posed(&r.candidates),
            ambiguous: posed(&r.ambiguous),
        })
        .collect();
    let max_shared = crate::pointcloud::RefineParams::default().max_shared;
    let verdict = judge_jointly(&common, &judged, max_shared)?;
    for (m, run) in runs.iter_mut().enumerate() {
        let keep = |list: &mut Vec<Candidate>, mask: &[bool]| {
            let mut it = mask.iter();
            list.retain(|_| *it.next().unwrap_or(&true));
        };
        keep(&mut run.candidates, &verdict.copies[m]);
        keep(&mut run.ambiguous, &verdict.ambiguous[m]);
    }
    Ok(runs)
}

#[cfg(test)]
#[path = "../tests/joint.rs"]
mod tests;
