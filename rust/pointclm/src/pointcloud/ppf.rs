//! Pose hypotheses from point pair features voted in a hash table (Drost et al., "Model
//! globally, match locally", CVPR 2010): the classic generator of a bin-picking cell.
//!
//! Why beside the descriptor matches: in a heap of identical parts a part's local shape is
//! mostly its neighbours' (FPFH's radius takes in the copies around it), so few of a hidden
//! copy's descriptor matches are true and the correspondence stage never proposes its pose
//! (BENCHMARKS.md, bins). A point pair feature is the distance and three angles between
//! two oriented points; two points of one copy give the model's feature wherever the copy
//! lies, so a copy needs only its own visible points, not a clean neighbourhood.
//!
//! The model's pairs are tabled once ([`PpfModel::new`]). Each scene reference point pairs
//! with the scene points within the model's diameter, looks each pair up and votes for
//! (model point, rotation about the normal); its best cell is a pose. Poses are clustered and
//! returned by their summed votes, to be refined and verified like any other candidate.

use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::hash::BuildHasherDefault;

use nalgebra::{Matrix3, Rotation3, Vector3};
use rayon::prelude::*;

use super::visibility::CellHasher;
use super::{check_normals, check_points, check_positive, PointIndex};
use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;

/// The quantisation and the limits of the voting. Lengths in the clouds' units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PpfParams {
    /// The step of both clouds' sampling (one point per cube of this side) and of the pair
    /// distance's bins. Drost et al. use a twentieth of the model's diameter.
    pub distance_step: f64,
    /// Bins of each of the three angles over [0, pi]; the rotation about the reference
    /// normal has twice as many over [0, 2 pi).
    pub angle_bins: usize,
    /// Pairs farther apart are not tabled nor voted: the model's diameter.
    pub max_distance: f64,
    /// Every `reference_stride`-th sampled scene point is a reference point.
    pub reference_stride: usize,
    /// Poses (clusters) returned at most, most voted first.
    pub max_poses: usize,
    /// Two hypotheses join one cluster when their translations lie within this distance...
    pub cluster_distance: f64,
    /// ...and their rotations within this angle (radians).
    pub cluster_angle: f64,
}

impl PpfParams {
    /// Drost et al.'s settings for a model of diameter `diameter`: sampling and distance bins
    /// of a twentieth of it, angles in 12-degree bins (15 over [0, pi]), every fifth scene
    /// point a reference, clusters within a tenth of the diameter and 24 degrees.
    pub fn for_diameter(diameter: f64) -> Self {
        Self {
            distance_step: diameter / 20.0,
            angle_bins: 15,
            max_distance: diameter,
            reference_stride: 5,
            max_poses: 200,
            cluster_distance: diameter / 10.0,
            cluster_angle: 24f64.to_radians(),
        }
    }

    fn check(&self) -> Result<()> {
        // First: `for_diameter` derives the other lengths from it.
        check_positive("max_distance (the model's diameter)", self.max_distance)?;
        check_positive("distance_step", self.distance_step)?;
        check_positive("cluster_distance", self.cluster_distance)?;
        check_positive("cluster_angle", self.cluster_angle)?;
        let bins_ok = (1..=180).contains(&self.angle_bins);
        let steps = self.max_distance / self.distance_step;
        if !bins_ok || !(1.0..=10_000.0).contains(&steps) {
            return Err(Error::InvalidParameter {
                name: "angle_bins / distance_step",
                value: format!("{} / {}", self.angle_bins, self.distance_step),
                reason: "need 1..=180 angle bins and 1..=10000 distance steps per diameter",
            });
        }
        for (name, v) in [
            ("reference_stride", self.reference_stride),
            ("max_poses", self.max_poses),
        ] {
            if v == 0 {
                return Err(Error::InvalidParameter {
                    name,
                    value: "0".into(),
                    reason: "must be at least 1",
                });
            }
        }
        Ok(())
    }

    /// Whether `key` is the feature of two points on one plane: parallel normals, both at a
    /// right angle to the line between the points. Such pairs are left out of the table (so
    /// they never vote): any plane of a scene (a bin's floor and walls, every face of every
    /// copy) holds them at every distance, so they say only "on a plane" and vote alike for
    /// every model point of every face, while for a flat-faced part they are a fifth of the
    /// model's pairs and most of the voting time. The pairs across faces, edges and curved
    /// surface, which fix a pose, all stay.
    fn is_coplanar(&self, key: u64) -> bool {
        let bins = self.angle_bins as u64;
        let (between_normals, second, first) =
            (key % bins, (key / bins) % bins, (key / bins / bins) % bins);
        let step = self.angle_step();
        // The bins whose range holds a right angle: one for an odd count, two for an even.
        let right = |k: u64| {
            let (lo, hi) = (k as f64 * step, (k + 1) as f64 * step);
            lo <= FRAC_PI_2 + 1e-12 && FRAC_PI_2 - 1e-12 <= hi
        };
        between_normals == 0 && right(first) && right(second)
    }

    fn angle_step(&self) -> f64 {
        PI / self.angle_bins as f64
    }

    fn alpha_bins(&self) -> usize {
        2 * self.angle_bins
    }

    /// An angle about a reference normal as a fraction of a turn in 32-bit fixed point. Why:
    /// the turn between two angles is then their wrapping difference and its bin a multiply
    /// and a shift, where floats took a compare, a conversion and a clamp per vote; voting
    /// took 1.6-1.9 times as long with them (the same poses).
    fn in_turns(alpha: f64) -> u32 {
        let turns = (alpha / TAU).rem_euclid(1.0);
        (turns * 4_294_967_296.0) as u64 as u32
    }

    /// The bin of a turn in fixed point ([`PpfParams::in_turns`]).
    fn bin_of(turn: u32, bins: u64) -> usize {
        ((u64::from(turn) * bins) >> 32) as usize
    }
}

/// One pose hypothesis: `T_scene_model` and the votes of the cluster it stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PpfPose {
    pub transform: RigidTransform,
    pub votes: u32,
}

/// An oriented point moved to the origin with its normal along +x.
#[derive(Debug, Clone, Copy)]
struct Frame {
    rotation: Matrix3<f64>,
    origin: Vector3<f64>,
}

impl Frame {
    fn new(point: &[f64; 3], normal: &[f64; 3]) -> Self {
        let n = Vector3::from(*normal);
        let n = if n.norm() > 0.0 {
            n.normalize()
        } else {
            Vector3::x()
        };
        let rotation = Rotation3::rotation_between(&n, &Vector3::x())
            .unwrap_or_else(|| Rotation3::from_axis_angle(&Vector3::y_axis(), PI));
        Self {
            rotation: *rotation.matrix(),
            origin: Vector3::from(*point),
        }
    }

    /// The angle of `p` about the frame's x axis, from its y axis.
    fn alpha(&self, p: &[f64; 3]) -> f64 {
        let q = self.rotation * (Vector3::from(*p) - self.origin);
        q.z.atan2(q.y)
    }
}

/// A model's point pairs, tabled by their quantised feature.
pub struct PpfModel {
    params: PpfParams,
    points: Vec<[f64; 3]>,
    frames: Vec<Frame>,
    /// Key -> range of `entries`. The keys are quantised features, not an adversary's, so
    /// FxHash's mixing serves (a lookup per scene pair).
    table: HashMap<u64, (u32, u32), BuildHasherDefault<CellHasher>>,
    /// The angle bins' edges as cosines, decreasing: an angle's bin without an arccosine.
    cos_edges: Vec<f64>,
    /// (the first vote cell of the reference model point, its pair's angle about the
    /// reference normal in fixed point: [`PpfParams::in_turns`]), by key.
    /// Why not binned (as Drost et al. do): binning both angles spreads each turn over two
    /// bins, and cost an eighth of the copies their pose on the validation bins.
    entries: Vec<(u32, u32)>,
}

impl PpfModel {
    /// Samples the model (one point per cube of `distance_step`) and tables every ordered
    /// pair within `max_distance`. `normals` must be unit and oriented outwards, as the
    /// scene's will be (towards the sensor). Errors: no points, non-finite input, a length
    /// mismatch, bad parameters.
    pub fn new(points: &[[f64; 3]], normals: &[[f64; 3]], params: PpfParams) -> Result<Self> {
        params.check()?;
        let cos_edges = (1..params.angle_bins)
            .map(|k| (k as f64 * params.angle_step()).cos())
            .collect::<Vec<_>>();
        check_points(points, "model points", 2)?;
        check_normals(
            normals,
            points.len(),
            "model normals",
            "model normals (one per point)",
        )?;
        let rows = one_per_cell(
            points,
            &(0..points.len()).collect::<Vec<_>>(),
            params.distance_step,
        );
        let pts: Vec<[f64; 3]> = rows.iter().map(|&i| points[i]).collect();
        let nrm: Vec<[f64; 3]> = rows.iter().map(|&i| normals[i]).collect();
        let frames: Vec<Frame> = pts
            .iter()
            .zip(&nrm)
            .map(|(p, n)| Frame::new(p, n))
            .collect();
        let mut keyed: Vec<(u64, u32, u32)> = Vec::new();
        for i in 0..pts.len() {
            for j in 0..pts.len() {
                // The key bounds the distance (and leaves out i == j).
                if let Some(key) =
                    feature_key(&pts[i], &nrm[i], &pts[j], &nrm[j], &params, &cos_edges)
                        .filter(|&key| !params.is_coplanar(key))
                {
                    let cell = (i * params.alpha_bins()) as u32;
                    keyed.push((key, cell, PpfParams::in_turns(frames[i].alpha(&pts[j]))));
                }
            }
        }
        keyed.sort_unstable_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut table = HashMap::default();
        let mut start = 0usize;
        while start < keyed.len() {
            let key = keyed[start].0;
            let end = start + keyed[start..].iter().take_while(|e| e.0 == key).count();
            table.insert(key, (start as u32, end as u32));
            start = end;
        }
        let entries = keyed.into_iter().map(|(_, i, a)| (i, a)).collect();
        Ok(Self {
            params,
            points: pts,
            frames,
            table,
            cos_edges,
            entries,
        })
    }

    /// The sampled model points the table holds.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Always false: construction needs points.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Pose hypotheses for the scene points `rows` of `points` (with their `normals`),
    /// most voted first. The sampled scene points are taken as references from the
    /// `offset % reference_stride`-th on (so that repeated calls can vote from other points).
    /// Deterministic whatever the number of threads. Errors: non-finite input, a length
    /// mismatch, a row out of range.
    pub fn poses(
        &self,
        points: &[[f64; 3]],
        normals: &[[f64; 3]],
        rows: &[usize],
        offset: usize,
    ) -> Result<Vec<PpfPose>> {
        check_points(points, "scene points", 0)?;
        check_normals(
            normals,
            points.len(),
            "scene normals",
            "scene normals (one per point)",
        )?;
        if let Some(&bad) = rows.iter().find(|&&r| r >= points.len()) {
            return Err(Error::InvalidParameter {
                name: "rows",
                value: bad.to_string(),
                reason: "a row beyond the scene's points",
            });
        }
        let p = &self.params;
        let sampled = one_per_cell(points, rows, p.distance_step);
        if sampled.len() < 2 {
            return Ok(Vec::new());
        }
        let spts: Vec<[f64; 3]> = sampled.iter().map(|&i| points[i]).collect();
        let snrm: Vec<[f64; 3]> = sampled.iter().map(|&i| normals[i]).collect();
        let index = PointIndex::new(&spts)?;
        let references: Vec<usize> = (offset % p.reference_stride..spts.len())
            .step_by(p.reference_stride)
            .collect();
        let cells = self.points.len() * p.alpha_bins();
        let hypotheses: Vec<(RigidTransform, u32)> = references
            .par_iter()
            .map_init(
                || vec![0u32; cells],
                |votes, &r| self.vote(&spts, &snrm, &index, r, votes),
            )
            .flatten()
            .collect();
        Ok(cluster(hypotheses, p))
    }

    /// The best pose of scene reference point `r`, if any pair voted.
    fn vote(
        &self,
        spts: &[[f64; 3]],
        snrm: &[[f64; 3]],
        index: &PointIndex,
        r: usize,
        votes: &mut [u32],
    ) -> Option<(RigidTransform, u32)> {
        let p = &self.params;
        let n_alpha = p.alpha_bins();
        let alpha_step = TAU / n_alpha as f64;
        let bins = n_alpha as u64;
        let frame = Frame::new(&spts[r], &snrm[r]);
        votes.fill(0);
        for (i, _) in index.within(&spts[r], p.max_distance) {
            if i == r {
                continue;
            }
            let Some(key) = feature_key(&spts[r], &snrm[r], &spts[i], &snrm[i], p, &self.cos_edges)
            else {
                continue;
            };
            let Some(&(a, b)) = self.table.get(&key) else {
                continue;
            };
            let alpha_s = PpfParams::in_turns(frame.alpha(&spts[i]));
            for &(first, alpha_m) in &self.entries[a as usize..b as usize] {
                // The turn from the model pair's angle to the scene pair's.
                let bin = PpfParams::bin_of(alpha_s.wrapping_sub(alpha_m), bins);
                votes[first as usize + bin] += 1;
            }
        }
        // The first best cell: ties go to the lowest model point and angle.
        let best = votes.iter().copied().max()?;
        if best == 0 {
            return None;
        }
        let cell = votes.iter().position(|&v| v == best)?;
        let (m, bin) = (cell / n_alpha, cell % n_alpha);
        let theta = (bin as f64 + 0.5) * alpha_step;
        let turn = Rotation3::from_axis_angle(&Vector3::x_axis(), theta);
        let model = &self.frames[m];
        // x_scene = s_r + R_s^T R_x(theta) R_m (x - m_r)
        let rotation = frame.rotation.transpose() * turn.matrix() * model.rotation;
        let translation = frame.origin - rotation * model.origin;
        Some((
            RigidTransform {
                rotation,
                translation,
            },
            best,
        ))
    }
}

/// Greedy clustering of the hypotheses, most voted first: each joins the first cluster whose
/// founding pose lies within the translation and rotation bounds, else founds one. The
/// clusters' founding poses by summed votes (ties: the earlier founded).
fn cluster(mut hypotheses: Vec<(RigidTransform, u32)>, p: &PpfParams) -> Vec<PpfPose> {
    // Stable: equal votes keep the references' order.
    hypotheses.sort_by_key(|h| std::cmp::Reverse(h.1));
    let max_d2 = p.cluster_distance * p.cluster_distance;
    let min_trace = 1.0 + 2.0 * p.cluster_angle.cos();
    let mut clusters: Vec<PpfPose> = Vec::new();
    for (t, v) in hypotheses {
        let home = clusters.iter_mut().find(|c| {
            (c.transform.translation - t.translation).norm_squared() <= max_d2
                && (c.transform.rotation.transpose() * t.rotation).trace() >= min_trace
        });
        match home {
            Some(c) => c.votes += v,
            None => clusters.push(PpfPose {
                transform: t,
                votes: v,
            }),
        }
    }
    clusters.sort_by_key(|c| std::cmp::Reverse(c.votes));
    clusters.truncate(p.max_poses);
    clusters
}

/// The quantised feature of the oriented pair (p1, n1) -> (p2, n2): distance, the two
/// normals' angles to the line between them, and the angle between the normals. None for
/// coincident points or a distance beyond the table.
fn feature_key(
    p1: &[f64; 3],
    n1: &[f64; 3],
    p2: &[f64; 3],
    n2: &[f64; 3],
    params: &PpfParams,
    cos_edges: &[f64],
) -> Option<u64> {
    let d = Vector3::from(*p2) - Vector3::from(*p1);
    let dist = d.norm();
    if dist <= 0.0 || dist > params.max_distance {
        return None;
    }
    let d = d / dist;
    let (n1, n2) = (Vector3::from(*n1), Vector3::from(*n2));
    let bins = params.angle_bins as u64;
    // The angle's bin is the number of bin edges whose cosine its cosine does not exceed.
    let angle = |a: &Vector3<f64>, b: &Vector3<f64>| {
        let c = a.dot(b) / (a.norm() * b.norm()).max(f64::MIN_POSITIVE);
        cos_edges.partition_point(|&e| e >= c) as u64
    };
    let dist_bin = (dist / params.distance_step) as u64;
    Some(((dist_bin * bins + angle(&n1, &d)) * bins + angle(&n2, &d)) * bins + angle(&n1, &n2))
}

/// The first of `rows` (in their order) in each cube of side `cell`: a sampling that keeps
/// original points, so that their normals stay the estimated ones.
fn one_per_cell(points: &[[f64; 3]], rows: &[usize], cell: f64) -> Vec<usize> {
    let mut seen = std::collections::HashSet::with_capacity(rows.len());
    rows.iter()
        .copied()
        .filter(|&i| {
            let key = points[i].map(|v| (v / cell).floor() as i64);
            seen.insert(key)
        })
        .collect()
}

#[cfg(test)]
#[path = "../tests/ppf.rs"]
mod tests;
