//! The last stage on clouds: each pose the correspondences gave is refined by ICP against the
//! scan and checked against it.
//!
//! Why: a pose fitted to a few FPFH matches is off by a few voxels and degrees (a match lands
//! anywhere within about a voxel of the true point), and realistic scenes hold consistent
//! groups of wrong matches that yield wrong poses. The clouds settle both. ICP pulls a nearly
//! right pose onto the copy, and the share of the model the scan then explains (Open3D's
//! `fitness`) tells a copy from a pose floating over clutter. But a copy hidden in part by its
//! neighbours shows only part of itself, so with the sensor's position each pose is judged by
//! what the sensor could see of the model at that pose ([`super::visibility`]): the share of
//! it the scan explains, and the share where the sensor saw free space. Poses that converge
//! onto a copy that a surer pose already explains are duplicates.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::icp::{icp_paired, previous_pair};
use super::normals::{estimate_normals, Orientation};
use super::terraces::resolving_terraces;
use super::visibility::{DepthMap, Sight};
use super::{check_normals, check_points, check_positive, PointIndex};
use crate::config::{Declared, Unit};
use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;

/// Neighbours a scan normal is fitted to, as `describe`'s default.
const NORMAL_MAX_NN: usize = 30;

crate::config::config! {
    /// Lengths (in the clouds' units) and acceptance rules of [`refine_poses`], each declared
    /// once here with its default, unit and range ([`Declared::FIELDS`]). The lengths'
    /// defaults are for clouds downsampled at a voxel of 1: [`RefineParams::for_voxel`]
    /// scales them to another voxel.
    #[derive(Debug, Clone, PartialEq)]
    pub struct RefineParams {
        /// Refine each pose by point-to-plane ICP before judging it; false: verification
        /// only, the poses are judged as given.
        pub icp: bool = true => Unit::Unitless;
        /// ICP's first (coarsest) stage: model points farther than this from the scan are
        /// left out of the fit. 3 voxels: a pose fitted to descriptor matches is off by a few
        /// voxels.
        pub icp_radius_coarse: f64 = 3.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// ICP's second stage radius (2 voxels).
        pub icp_radius_middle: f64 = 2.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// ICP's last stage radius: the fitness radius (1.5 voxels), so that ICP ends on the
        /// points verification counts.
        pub icp_radius_fine: f64 = 1.5 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// At most this many ICP iterations per stage (a stage ends early once the pose stops
        /// moving).
        pub iterations: usize = 10 => Unit::Unitless, [1, 1000];
        /// The scan's normals for point-to-plane ICP are fitted to its points within this
        /// distance (at most 30 of them): 2 voxels hold about 12 points of a surface. Within
        /// twice it (at most 120) where the scan's depth steps make flat terraces at this
        /// radius ([`super::terraces`]).
        pub normal_radius: f64 = 2.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// A model point is explained when a scan point lies within this distance: a
        /// downsampled point lies within about half a voxel of the surface on each side,
        /// plus noise (1.5 voxels).
        pub fit_radius: f64 = 1.5 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// With a viewpoint: poses explaining a smaller share of what the sensor could see of
        /// the model at that pose are rejected. The exact poses of the validation matrix's
        /// copies (1148, after ICP) show 0.83 or more on 33 of 35 cells, 0.79 on a box pile
        /// and 0.75 on `combo6` (4 lost; `benchmarks/results/matrix/exact_rules.md`).
        pub min_visible_fitness: f64 = 0.85 => Unit::Unitless, [0.0, 1.0];
        /// With a viewpoint: poses putting more than this share of their visible points where
        /// the sensor saw free space are rejected. Point-to-plane ICP settles a right pose on
        /// the surface, so a right pose leaves almost none: exact poses at most 0.011 on 28
        /// of 35 validation-matrix cells, 0.017-0.061 on the bracket, the fandisk, single
        /// boxes, a box row and `combo1`, up to 0.19 on box piles and `combo6`, the largest
        /// where ICP moved the pose 2.5-5.5 voxels off (18 of 1148 lost). Forgiving the copy's
        /// outline lets wrong poses on clutter through (BENCHMARKS.md, exact-pose verification).
        pub max_contradiction: f64 = 0.01 => Unit::Unitless, [0.0, 1.0];
        /// With a viewpoint: a model point the scan does not explain is judged (seen or
        /// contradicted) only where its surface faces the sensor within this angle, in degrees
        /// (90: everywhere). A range sensor rarely returns from surfaces seen nearly edge-on,
        /// so unexplained points there say nothing about the pose; flat-faced parts have many.
        pub max_incidence_deg: f64 = 75.0 => Unit::Unitless, [0.0, 90.0];
        /// With a viewpoint: poses of which the sensor could see less than this share of the
        /// model are rejected (too little to judge). Copies at least 30 % visible show 0.12 or
        /// more on every validation-matrix cell (two single boxes below 0.15).
        pub min_seen: f64 = 0.15 => Unit::Unitless, [0.0, 1.0];
        /// Width of a depth-map cell at the scan's median range: a downsampled surface has a
        /// point about every voxel, so cells of 1.5 voxels on a surface are rarely empty.
        pub depth_cell: f64 = 1.5 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// Ranges closer than this along a ray are one surface: noise plus the depth spread
        /// of a slanted surface within a cell (3 voxels).
        pub depth_tolerance: f64 = 3.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// A scan looks like one view from a point when at most `max_hidden_scan` of it lies
        /// more than `trust_tolerance` behind another scan point in a cell `trust_cell` wide
        /// (a single view has almost none: slanted surfaces and edges). A viewpoint guessed
        /// from the scan is kept only then; one the caller gives is used all the same (and
        /// disputed with a warning).
        pub trust_cell: f64 = 1.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// See `trust_cell`.
        pub trust_tolerance: f64 = 5.0 => Unit::Length, [f64::MIN_POSITIVE, f64::MAX];
        /// See `trust_cell`: single range scans hide 2-7 % of themselves there (slanted
        /// surfaces and edges), the same scans seen from elsewhere 20-70 %.
        pub max_hidden_scan: f64 = 0.12 => Unit::Unitless, [0.0, 1.0];
        /// Without a viewpoint: poses explaining a smaller share of the model are rejected.
        pub min_fitness: f64 = 0.3 => Unit::Unitless, [0.0, 1.0];
        /// Without a viewpoint: poses explaining less than this share of the best pose's
        /// fitness are rejected (copies seen alike by one sensor, which heaps break).
        pub min_relative_fitness: f64 = 0.8 => Unit::Unitless, [0.0, 1.0];
        /// A pose is a duplicate when more than this share of the scan points it explains are
        /// already explained by a surer pose.
        pub max_shared: f64 = 0.5 => Unit::Unitless, [0.0, 1.0];
        /// Poses are not kept when the model slid along the surface it explains (by that
        /// surface's spread, either way along its two main directions) still explains more
        /// than this share of what it explains in place (1: never). A patch lying on a larger
        /// surface of its shape (a flat face on a table or a wall, or the top of a box flush
        /// with its neighbours') fits anywhere on it: the fit says nothing about where along
        /// the face the object is, however well it explains the scan. Such poses are an
        /// ambiguity, not an error: they come back apart, in [`Refined::sliding`].
        pub max_slid_fitness: f64 = 0.9 => Unit::Unitless, [0.0, 1.0];
        /// Poses are rejected when fewer than this share of the model points the scan
        /// explains lie on a surface turned like the scan's there (normals, of either sign,
        /// within `normal_agreement_deg`; 0 turns the test off). A right pose lies along the
        /// surface it explains; a model cut by a surface (sunk into a floor or wall, whose
        /// noise band holds the cut) meets it across. Unrelated directions agree by chance 13 %
        /// of the time at 30 degrees; on 12 validation-matrix cells every right pose returned
        /// and every exact pose had 0.47 or more (the dragon's the lowest, time-of-flight and
        /// narrow-camera cells included), the wrong ones a median 0.35 (poses sunk into a
        /// time-of-flight floor 0.13-0.47).
        pub min_normal_agreement: f64 = 0.4 => Unit::Unitless, [0.0, 1.0];
        /// See `min_normal_agreement`, in degrees: about the spread of normals fitted to a
        /// noisy range scan within `normal_radius`.
        pub normal_agreement_deg: f64 = 30.0 => Unit::Unitless, [0.0, 90.0];
    }
}

impl RefineParams {
    /// These parameters for scoring only: no rule rejects (but a pose that explains nothing),
    /// duplicates are kept.
    pub fn keeping_all(&self) -> Self {
        Self {
            min_fitness: 0.0,
            min_relative_fitness: 0.0,
            min_visible_fitness: 0.0,
            max_contradiction: 1.0,
            min_seen: 0.0,
            max_slid_fitness: 1.0,
            max_shared: 1.0,
            min_normal_agreement: 0.0,
            ..self.clone()
        }
    }

    /// The defaults for clouds downsampled at `voxel`: every length of
    /// [`RefineParams::default`] (in voxels) times `voxel`.
    pub fn for_voxel(voxel: f64) -> Self {
        Self::default().scaled(voxel)
    }

    /// The ICP stages' radii, coarse to fine; empty without ICP.
    pub fn radii(&self) -> Vec<f64> {
        if self.icp {
            vec![
                self.icp_radius_coarse,
                self.icp_radius_middle,
                self.icp_radius_fine,
            ]
        } else {
            Vec::new()
        }
    }

    fn check(&self) -> Result<()> {
        match self.out_of_range() {
            None => Ok(()),
            Some((field, value)) => Err(Error::InvalidParameter {
                name: field.name,
                value: value.to_string(),
                reason: match field.range {
                    Some((0.0, 1.0)) => "must lie in [0, 1]",
                    Some((0.0, 90.0)) => "must lie in [0, 90] degrees",
                    Some((1.0, _)) => "must be a count >= 1 within its bound",
                    _ => "must be a positive finite number",
                },
            }),
        }
    }
}

/// One accepted pose.
#[derive(Debug, Clone, PartialEq)]
pub struct RefinedPose {
    /// `T_target_source` after ICP.
    pub pose: RigidTransform,
    /// How sure the pose is, in [0, 1]: `visible_fitness * (1 - contradiction)` with a
    /// viewpoint, `fitness` without.
    pub confidence: f64,
    /// Share of the model's points with a scan point within `fit_radius`.
    pub fitness: f64,
    /// Share of what the sensor could see of the model at this pose that the scan explains
    /// (NaN without a trusted viewpoint).
    pub visible_fitness: f64,
    /// Share of what the sensor could see of the model at this pose that lies where the
    /// sensor saw free space (NaN without a trusted viewpoint).
    pub contradiction: f64,
    /// Share of the model's points the sensor could see at this pose (NaN without a trusted
    /// viewpoint).
    pub seen: f64,
    /// RMS distance from the explained model points to their nearest scan points.
    pub inlier_rmse: f64,
    /// What the model slid along the surface it explains still explains, as a share of what
    /// it explains in place (see [`RefineParams::max_slid_fitness`]; NaN where not measured:
    /// rejected by another rule first, or with the rule off).
    pub slid_fitness: f64,
    /// The same over the explained model points the sensor could see at this pose (NaN
    /// without a trusted viewpoint, or when it sees none): how tightly the visible side
    /// lies on the scan, without the points explained only by surfaces the model hides or
    /// that hide it.
    pub visible_rmse: f64,
    /// Index of the input pose this one came from.
    pub origin: usize,
}

/// Why verification did not keep a pose: the rule (the [`RefineParams`] field that rejected
/// it, or `"explains_nothing"`), the pose's value and the threshold it had to meet.
#[derive(Debug, Clone, PartialEq)]
pub struct Rejection {
    /// Index of the input pose.
    pub origin: usize,
    /// The rule: `min_seen`, `min_visible_fitness`, `max_contradiction`, `min_fitness`,
    /// `min_relative_fitness` (the threshold is then that share of the best pose's fitness),
    /// `max_slid_fitness`, `max_shared` (a duplicate of a surer pose) or `explains_nothing`.
    pub rule: &'static str,
    /// The pose's value of what the rule measures.
    pub value: f64,
    /// What it had to reach (a floor) or stay within (a ceiling).
    pub threshold: f64,
}

/// The accepted poses, surest first, which rules judged them, and why each other pose was
/// rejected.
#[derive(Debug, Clone, PartialEq)]
pub struct Refined {
    pub poses: Vec<RefinedPose>,
    /// True when the poses were judged by what the sensor could see from the viewpoint;
    /// false when no viewpoint was given.
    pub by_visibility: bool,
    /// One per input pose not kept, by input order: the first rule it failed.
    pub rejected: Vec<Rejection>,
    /// The poses that pass every rule but slide along a face (`max_slid_fitness`, also in
    /// `rejected`), surest first, without those sharing more than `max_shared` of their scan
    /// points with a kept pose or a surer sliding one. Their confidence is lowered by the
    /// slide: times `(1 - slid_fitness) / (1 - max_slid_fitness)`, the share the slide
    /// loses against the least a pose must lose to be kept.
    pub sliding: Vec<RefinedPose>,
}

/// Refines every pose by point-to-plane ICP against `target` (in parallel on the current rayon
/// pool), then keeps the poses that pass [`RefineParams`]' rules, surest first (ties: input
/// order). `target_normals` are the scan's unit normals (either sign; e.g. those FPFH used);
/// without them they are estimated within `normal_radius`.
///
/// With `viewpoint` (the sensor's position) each pose is judged by what the sensor could see
/// of the model at that pose, even where the scan does not look like one view from there
/// ([`looks_like_one_view`], which callers check to warn); without it, by the share of the
/// model explained, absolute and relative to the best pose. The result does not depend on the number of
/// threads.
pub fn refine_poses(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    target_normals: Option<&[[f64; 3]]>,
    poses: &[RigidTransform],
    viewpoint: Option<[f64; 3]>,
    params: &RefineParams,
) -> Result<Refined> {
    RefineContext::new(source, target, target_normals, viewpoint, params)?.refine(poses, params)
}

/// What [`refine_poses`] derives from the clouds alone, whatever the poses: the scan's
/// index, its normals, the depth maps from the viewpoint and the model's normals. Why apart:
/// `register_point_clouds` refines against the same scan about six times per call (the first
/// pass, each peeling round, the half-turned alternatives), and this part cost 6.5 ms of
/// each call on one thread against 3.3 ms per pose.
pub struct RefineContext {
    source: Vec<[f64; 3]>,
    target: Vec<[f64; 3]>,
    index: PointIndex,
    /// Given, or estimated when the context's parameters run ICP; empty otherwise.
    normals: Vec<[f64; 3]>,
    depth: Option<DepthMap>,
    model_normals: Vec<[f64; 3]>,
    /// The model's normals from its nearest points, for their agreement with the scan's.
    agreement_normals: Vec<[f64; 3]>,
    /// The parameters the context was built with (their lengths and sensor model must match
    /// every later call's).
    built: RefineParams,
}

impl RefineContext {
    /// Checks the clouds, the viewpoint and `params`, then builds what every call shares.
    pub fn new(
        source: &[[f64; 3]],
        target: &[[f64; 3]],
        target_normals: Option<&[[f64; 3]]>,
        viewpoint: Option<[f64; 3]>,
        params: &RefineParams,
    ) -> Result<Self> {
        check_inputs(source, target, &[], viewpoint, params)?;
        let index = PointIndex::with_cells(target, params.fit_radius)?;
        let normals = match target_normals {
            Some(given) => checked_normals(target, given)?.to_vec(),
            // Point-to-plane ICP needs them; without ICP, none.
            None if !params.icp => Vec::new(),
            None => scan_normals(target, &index, params, viewpoint)?,
        };
        // A given viewpoint is the sensor's: the caller's word stands even where the scan
        // does not look like one view from it (`looks_like_one_view` tells the caller).
        let depth =
            viewpoint.map(|v| DepthMap::new(target, v, params.depth_cell, params.depth_tolerance));
        let model_index = PointIndex::new(source)?;
        let model_normals = match depth {
            Some(_) => unsigned_normals(source, &model_index, params)?,
            None => Vec::new(),
        };
        let agreement_normals = nearest_normals(source, &model_index);
        Ok(Self {
            source: source.to_vec(),
            target: target.to_vec(),
            index,
            normals,
            depth,
            model_normals,
            agreement_normals,
            built: params.clone(),
        })
    }

    /// [`refine_poses`] of `poses` with `params`, whose thresholds and ICP schedule may differ
    /// from the context's but not the lengths and sensor model it was built with.
    pub fn refine(&self, poses: &[RigidTransform], params: &RefineParams) -> Result<Refined> {
        check_inputs(&self.source, &self.target, poses, None, params)?;
        let b = &self.built;
        let same = [
            (b.fit_radius, params.fit_radius),
            (b.normal_radius, params.normal_radius),
            (b.depth_cell, params.depth_cell),
            (b.depth_tolerance, params.depth_tolerance),
            (b.trust_cell, params.trust_cell),
            (b.trust_tolerance, params.trust_tolerance),
            (b.max_hidden_scan, params.max_hidden_scan),
        ];
        if same.iter().any(|(x, y)| x.to_bits() != y.to_bits()) {
            return Err(Error::InvalidParameter {
                name: "params",
                value: "lengths or sensor model".into(),
                reason: "must be those the refinement context was built with",
            });
        }
        let estimated;
        let normals: &[[f64; 3]] = if self.normals.is_empty() && params.icp {
            estimated = scan_normals(&self.target, &self.index, params, None)?;
            &estimated
        } else {
            &self.normals
        };
        let sensor = self.depth.as_ref().map(|depth| Sensor {
            depth,
            model_normals: &self.model_normals,
            min_cos: params.max_incidence_deg.to_radians().cos(),
            reach: radius(&self.source),
        });
        let (source, target) = (&self.source[..], &self.target[..]);
        let radii = params.radii();
        let agreement_cos = params.normal_agreement_deg.to_radians().cos();
        let fitted: Vec<(RigidTransform, Judged)> = poses
            .par_iter()
            .map(|pose| {
                let (refined, paired) = icp_paired(
                    source,
                    target,
                    normals,
                    &self.index,
                    *pose,
                    &radii,
                    params.iterations,
                    self.depth.as_ref(),
                );
                let mut judged = judge(
                    source,
                    target,
                    &self.index,
                    sensor.as_ref(),
                    &refined,
                    &paired,
                    params.fit_radius,
                );
                judged.normal_agreement = normal_agreement(
                    &self.agreement_normals,
                    normals,
                    &refined,
                    &judged.nearest,
                    agreement_cos,
                );
                (refined, judged)
            })
            .collect();
        let mut verdicts = pass_rules(&fitted, self.depth.is_some(), params);
        let mut slid = vec![f64::NAN; fitted.len()];
        if params.max_slid_fitness < 1.0 {
            slid = fitted
                .par_iter()
                .zip(&verdicts)
                .map(|((pose, j), verdict)| match verdict {
                    None => {
                        slid_fitness(source, pose, &self.index, &j.explained, params.fit_radius)
                    }
                    Some(_) => f64::NAN,
                })
                .collect();
        }
        let mut slides = vec![false; fitted.len()];
        for (k, verdict) in verdicts.iter_mut().enumerate() {
            if verdict.is_none() && slid[k] > params.max_slid_fitness {
                slides[k] = true;
                *verdict = Some(Rejection {
                    origin: k,
                    rule: "max_slid_fitness",
                    value: slid[k],
                    threshold: params.max_slid_fitness,
                });
            }
        }
        let mut claimed = vec![false; target.len()];
        let passed: Vec<bool> = verdicts.iter().map(Option::is_none).collect();
        let (kept, duplicates) = keep_surest(&fitted, &passed, &slid, &mut claimed, params);
        // The sliding poses, judged after every kept one: a slide never takes a kept pose's
        // points.
        let (mut sliding, _) = keep_surest(&fitted, &slides, &slid, &mut claimed, params);
        let room = 1.0 - params.max_slid_fitness;
        for r in &mut sliding {
            r.confidence *= ((1.0 - r.slid_fitness) / room).clamp(0.0, 1.0);
        }
        sliding.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
        let mut rejected: Vec<Rejection> = verdicts.into_iter().flatten().collect();
        rejected.extend(duplicates);
        rejected.sort_by_key(|r| r.origin);
        Ok(Refined {
            poses: kept,
            by_visibility: self.depth.is_some(),
            rejected,
            sliding,
        })
    }

    /// Per point of `points`, whether a scan point lies strictly within `radius` of it, in
    /// parallel on the current rayon pool.
    pub fn near_mask(&self, points: &[[f64; 3]], radius: f64) -> Result<Vec<bool>> {
        check_points(points, "points", 0)?;
        check_positive("radius", radius)?;
        Ok(points
            .par_iter()
            .map(|p| self.index.any_within(p, radius))
            .collect())
    }

    /// [`super::covariance::pose_covariances`] of `poses` against the context's scan and its
    /// normals (estimated as ICP's when the context holds none), over the model points within
    /// `radius` of the scan.
    pub fn pose_covariances(
        &self,
        poses: &[RigidTransform],
        radius: f64,
    ) -> Result<Vec<super::covariance::PoseCovariance>> {
        let estimated;
        let normals: &[[f64; 3]] = if self.normals.is_empty() {
            estimated = scan_normals(&self.target, &self.index, &self.built, None)?;
            &estimated
        } else {
            &self.normals
        };
        super::covariance::pose_covariances(
            &self.source,
            &self.index,
            &self.target,
            normals,
            poses,
            radius,
        )
    }

    /// The model the context was built with.
    pub fn source(&self) -> &[[f64; 3]] {
        &self.source
    }

    /// The scan the context was built with.
    pub fn target(&self) -> &[[f64; 3]] {
        &self.target
    }

    /// The scan's index (with a grid of cells `fit_radius` wide): the one index of the scan
    /// that the scene's stages share.
    pub fn index(&self) -> &PointIndex {
        &self.index
    }

    /// The share of `points` (in the source's frame) that each of `poses` puts strictly
    /// within `radius` of a scan point, in parallel on the current rayon pool. Why here:
    /// peeling screens about a hundred voted poses a round by what they already hold before
    /// ICP, and the context's scan grid answers each point with the first neighbour found.
    pub fn near_shares(
        &self,
        poses: &[RigidTransform],
        points: &[[f64; 3]],
        radius: f64,
    ) -> Result<Vec<f64>> {
        check_points(points, "points", 1)?;
        check_positive("radius", radius)?;
        let n = points.len() as f64;
        Ok(poses
            .par_iter()
            .map(|pose| {
                let near = points
                    .iter()
                    .filter(|&&p| self.index.any_within(&pose.apply(p), radius))
                    .count();
                near as f64 / n
            })
            .collect())
    }
}

/// Whether `scan` looks like one view from `viewpoint`: at most `max_hidden_scan` of it lies
/// more than `trust_tolerance` behind another scan point along the sensor's rays (cells
/// `trust_cell` wide). A single range scan has almost none there (slanted surfaces and
/// edges: 2-7 % on the benchmark scenes, 4 % on a Kinect frame), while the same scans seen
/// from points other than their sensor have 20-70 %. (A heap seen at a coarse voxel can
/// reach a fifth: every cell straddling a depth edge counts.)
///
/// Errors: non-finite points or viewpoint, and parameters [`refine_poses`] would refuse.
pub fn looks_like_one_view(
    scan: &[[f64; 3]],
    viewpoint: [f64; 3],
    params: &RefineParams,
) -> Result<bool> {
    check_points(scan, "scan points", 0)?;
    check_viewpoint(viewpoint)?;
    params.check()?;
    Ok(one_view(scan, viewpoint, params))
}

/// [`looks_like_one_view`] on checked input.
fn one_view(scan: &[[f64; 3]], viewpoint: [f64; 3], params: &RefineParams) -> bool {
    DepthMap::new(scan, viewpoint, params.trust_cell, params.trust_tolerance).hidden_share(scan)
        <= params.max_hidden_scan
}

fn check_viewpoint(viewpoint: [f64; 3]) -> Result<()> {
    if viewpoint.iter().all(|c| c.is_finite()) {
        Ok(())
    } else {
        Err(Error::NonFinite {
            what: "viewpoint",
            row: 0,
        })
    }
}

/// Normals within `normal_radius`, of either sign: neither point-to-plane distances nor the
/// incidence test depend on it.
fn unsigned_normals(
    points: &[[f64; 3]],
    index: &PointIndex,
    params: &RefineParams,
) -> Result<Vec<[f64; 3]>> {
    let towards = Orientation::Towards([0.0; 3]);
    estimate_normals(points, index, params.normal_radius, NORMAL_MAX_NN, towards)
}

/// The scan's normals within `normal_radius`, of either sign, or within twice it where its
/// depth steps seen from `viewpoint` (else the origin) make terraces at `normal_radius`
/// ([`resolving_terraces`]).
fn scan_normals(
    points: &[[f64; 3]],
    index: &PointIndex,
    params: &RefineParams,
    viewpoint: Option<[f64; 3]>,
) -> Result<Vec<[f64; 3]>> {
    let fine = unsigned_normals(points, index, params)?;
    let eye = viewpoint.unwrap_or([0.0; 3]);
    let towards = Orientation::Towards([0.0; 3]);
    let shape = (params.normal_radius, NORMAL_MAX_NN);
    Ok(resolving_terraces(points, index, fine, shape, towards, eye)?.0)
}

/// Normals from each point's `AGREEMENT_NN` nearest points, of either sign: a plane fit
/// needs about a dozen whatever the model's spacing, which a model given to `refine_poses`
/// need not share with the voxel (a sparse model's disc of `normal_radius` may hold three).
fn nearest_normals(points: &[[f64; 3]], index: &PointIndex) -> Vec<[f64; 3]> {
    let towards = Orientation::Towards([0.0; 3]);
    super::normals::nearest_k_normals(points, index, AGREEMENT_NN, towards)
}

/// See [`nearest_normals`].
const AGREEMENT_NN: usize = 12;

/// Given target normals, one per target point and finite.
fn checked_normals<'a>(target: &[[f64; 3]], normals: &'a [[f64; 3]]) -> Result<&'a [[f64; 3]]> {
    let one_per = "target normals (one per target point)";
    check_normals(normals, target.len(), "target normals", one_per)?;
    Ok(normals)
}

fn check_inputs(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    poses: &[RigidTransform],
    viewpoint: Option<[f64; 3]>,
    params: &RefineParams,
) -> Result<()> {
    check_points(source, "source points", 3)?;
    check_points(target, "target points", 3)?;
    params.check()?;
    if let Some(row) = poses.iter().position(|p| {
        !(p.rotation.iter().all(|v| v.is_finite()) && p.translation.iter().all(|v| v.is_finite()))
    }) {
        return Err(Error::NonFinite { what: "poses", row });
    }
    if let Some(v) = viewpoint {
        check_viewpoint(v)?;
    }
    Ok(())
}

/// Which fitted poses fail the rules on what they explain and what the sensor saw (all but
/// the slide, which is dearer and is only asked of the others), and the first rule each fails.
fn pass_rules(
    fitted: &[(RigidTransform, Judged)],
    by_visibility: bool,
    params: &RefineParams,
) -> Vec<Option<Rejection>> {
    let best = fitted.iter().map(|(_, j)| j.fitness).fold(0.0, f64::max);
    let relative = params.min_relative_fitness * best;
    let floor = params.min_fitness.max(relative);
    fitted
        .iter()
        .enumerate()
        .map(|(origin, (_, j))| {
            let fails = |rule, value, threshold| {
                Some(Rejection {
                    origin,
                    rule,
                    value,
                    threshold,
                })
            };
            let first = if by_visibility {
                if below(j.seen, params.min_seen) {
                    fails("min_seen", j.seen, params.min_seen)
                } else if below(j.visible_fitness, params.min_visible_fitness) {
                    let v = j.visible_fitness;
                    fails("min_visible_fitness", v, params.min_visible_fitness)
                } else if above(j.contradiction, params.max_contradiction) {
                    let v = j.contradiction;
                    fails("max_contradiction", v, params.max_contradiction)
                } else {
                    None
                }
            } else if below(j.fitness, floor) {
                if params.min_fitness >= relative {
                    fails("min_fitness", j.fitness, params.min_fitness)
                } else {
                    fails("min_relative_fitness", j.fitness, relative)
                }
            } else {
                None
            };
            // Not measured (no normals, NaN): the rule has nothing to say.
            let a = j.normal_agreement;
            first.or_else(|| {
                (a < params.min_normal_agreement)
                    .then(|| fails("min_normal_agreement", a, params.min_normal_agreement))
                    .flatten()
            })
        })
        .collect()
}

/// Whether `value` misses the floor `threshold` (a NaN value misses every rule).
fn below(value: f64, threshold: f64) -> bool {
    value.is_nan() || value < threshold
}

/// Whether `value` exceeds the ceiling `threshold` (a NaN value misses every rule).
fn above(value: f64, threshold: f64) -> bool {
    value.is_nan() || value > threshold
}

/// The fitted poses that are `eligible`, surest first (ties: input order), each dropped when
/// it explains no scan point or more than `max_shared` of the scan points it explains are
/// claimed (by a surer kept pose, or before the call: `claimed` holds the scan points kept
/// poses explain, in and out); and the rejections of those dropped.
fn keep_surest(
    fitted: &[(RigidTransform, Judged)],
    eligible: &[bool],
    slid: &[f64],
    claimed: &mut [bool],
    params: &RefineParams,
) -> (Vec<RefinedPose>, Vec<Rejection>) {
    let mut order: Vec<usize> = (0..fitted.len()).collect();
    order.sort_by(|&a, &b| {
        fitted[b]
            .1
            .confidence
            .total_cmp(&fitted[a].1.confidence)
            .then(a.cmp(&b))
    });
    let mut kept = Vec::new();
    let mut dropped = Vec::new();
    for k in order {
        let (pose, j) = &fitted[k];
        if !eligible[k] {
            continue;
        }
        if j.targets.is_empty() {
            dropped.push(Rejection {
                origin: k,
                rule: "explains_nothing",
                value: 0.0,
                threshold: 1.0,
            });
            continue;
        }
        let shared = j.targets.iter().filter(|&&t| claimed[t]).count();
        if shared as f64 > params.max_shared * j.targets.len() as f64 {
            dropped.push(Rejection {
                origin: k,
                rule: "max_shared",
                value: shared as f64 / j.targets.len() as f64,
                threshold: params.max_shared,
            });
            continue;
        }
        for &t in &j.targets {
            claimed[t] = true;
        }
        kept.push(RefinedPose {
            pose: *pose,
            confidence: j.confidence,
            fitness: j.fitness,
            visible_fitness: j.visible_fitness,
            contradiction: j.contradiction,
            seen: j.seen,
            inlier_rmse: j.rmse,
            visible_rmse: j.visible_rmse,
            slid_fitness: slid[k],
            origin: k,
        });
    }
    (kept, dropped)
}

/// How far from a rotation a 3x3 block may be (`||R^T R - I||_F`) and still be taken for
/// one: poses written with 6 to 8 significant digits, or composed from several such, are
/// off by 1e-6 to 1e-4; 1e-3 moves no point of a unit-sized object by more than 1e-3.
pub const MAX_ROTATION_DEVIATION: f64 = 1e-3;

/// The rotation nearest to `m` (its polar factor, from the SVD) when `m` is a rotation up to
/// rounding: `||m^T m - I||_F <= MAX_ROTATION_DEVIATION` and `det m > 0`. Otherwise the
/// deviation found, for the caller's message.
pub fn nearest_rotation(m: &Matrix3<f64>) -> std::result::Result<Matrix3<f64>, f64> {
    let deviation = (m.transpose() * m - Matrix3::identity()).norm();
    if !(deviation <= MAX_ROTATION_DEVIATION && m.determinant() > 0.0) {
        return Err(deviation);
    }
    let svd = m.svd(true, true);
    match (svd.u, svd.v_t) {
        (Some(u), Some(v_t)) => Ok(u * v_t),
        _ => Err(deviation),
    }
}

/// What a pose explains and what the sensor could see of it.
struct Judged {
    fitness: f64,
    visible_fitness: f64,
    contradiction: f64,
    seen: f64,
    confidence: f64,
    rmse: f64,
    visible_rmse: f64,
    /// The scan points the model lands on (sorted, distinct).
    targets: Vec<usize>,
    /// Which model points the scan explains at this pose.
    explained: Vec<bool>,
    /// Each model point's nearest scan point within the fit radius (`u32::MAX`: none).
    nearest: Vec<u32>,
    /// The share of the explained model points whose normal agrees with the scan's (NaN:
    /// not measured).
    normal_agreement: f64,
}

/// The sensor that judges poses: its depth map, and the model's normals with the incidence
/// beyond which an unexplained model point is not judged (empty normals: none).
struct Sensor<'a> {
    depth: &'a DepthMap,
    model_normals: &'a [[f64; 3]],
    min_cos: f64,
    /// The model's radius about its centroid: how far around a ray without a return the
    /// scan must have returns for the sensor to have looked there ([`DepthMap::judge`]).
    reach: f64,
}

/// `paired`: each model point's scan point at ICP's last step
/// ([`super::icp::NO_PAIR`]: none), which bounds its search (empty: none known).
fn judge(
    source: &[[f64; 3]],
    target: &[[f64; 3]],
    index: &PointIndex,
    sensor: Option<&Sensor>,
    pose: &RigidTransform,
    paired: &[u32],
    radius: f64,
) -> Judged {
    let posed: Vec<[f64; 3]> = source.iter().map(|p| pose.apply(*p)).collect();
    let near = |i: usize| previous_pair(*paired.get(i)?, target, &posed[i]);
    let (dist_sq, nearest, targets, hits, rmse) = explain(index, &posed, radius, near);
    let explained: Vec<bool> = dist_sq.iter().map(|d| !d.is_nan()).collect();
    let n = source.len() as f64;
    let fitness = hits as f64 / n;
    let Some(sensor) = sensor else {
        return Judged {
            fitness,
            visible_fitness: f64::NAN,
            contradiction: f64::NAN,
            seen: f64::NAN,
            confidence: fitness,
            rmse,
            visible_rmse: f64::NAN,
            targets,
            explained,
            nearest,
            normal_agreement: f64::NAN,
        };
    };
    let grazing = grazing(sensor, pose, &posed);
    let (seen, contradicted, visible_sq) = sensor_verdict(sensor, &posed, &dist_sq, hits, &grazing);
    let share = |k: usize| {
        if seen > 0 {
            k as f64 / seen as f64
        } else {
            0.0
        }
    };
    let (visible_fitness, contradiction) = (share(hits), share(contradicted));
    Judged {
        fitness,
        visible_fitness,
        contradiction,
        seen: seen as f64 / n,
        confidence: visible_fitness * (1.0 - contradiction),
        rmse,
        visible_rmse: visible_sq.sqrt(),
        targets,
        explained,
        nearest,
        normal_agreement: f64::NAN,
    }
}

/// The share of the model points with a nearest scan point (`nearest`, `u32::MAX`: none)
/// whose normal, turned by `pose`, lies within `acos(min_cos)` of that scan point's, either
/// sign (NaN without scan normals or without such points).
fn normal_agreement(
    model_normals: &[[f64; 3]],
    scan_normals: &[[f64; 3]],
    pose: &RigidTransform,
    nearest: &[u32],
    min_cos: f64,
) -> f64 {
    if scan_normals.is_empty() {
        return f64::NAN;
    }
    let (mut pairs, mut agree) = (0usize, 0usize);
    for (n, &j) in model_normals.iter().zip(nearest) {
        let Some(m) = scan_normals.get(j as usize) else {
            continue;
        };
        let turned = pose.rotation * nalgebra::Vector3::from(*n);
        pairs += 1;
        if turned.dot(&nalgebra::Vector3::from(*m)).abs() >= min_cos {
            agree += 1;
        }
    }
    if pairs == 0 {
        f64::NAN
    } else {
        agree as f64 / pairs as f64
    }
}

/// What the model slid along the surface it explains still explains, as a share of what it
/// explains in place (at most 1; 0 when it explains too little to slide): the posed model
/// shifted by the explained points' spread along each of their two main directions, both
/// ways, and the largest count kept. Why those shifts: a patch of extent `L` slid by its
/// spread (`L / sqrt(12)` when even) leaves its own support with about 30 % of its points, so
/// a pose that is where the scan puts the object loses them, while one on a larger surface of
/// its shape keeps them all.
fn slid_fitness(
    source: &[[f64; 3]],
    pose: &RigidTransform,
    index: &PointIndex,
    explained: &[bool],
    radius: f64,
) -> f64 {
    let hits = explained.iter().filter(|&&e| e).count();
    if hits < 3 {
        return 0.0;
    }
    let posed: Vec<[f64; 3]> = source.iter().map(|p| pose.apply(*p)).collect();
    let pts: Vec<Vector3<f64>> = posed
        .iter()
        .zip(explained)
        .filter(|(_, &e)| e)
        .map(|(p, _)| Vector3::from(*p))
        .collect();
    let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    let cov = pts
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>()
        / pts.len() as f64;
    let eig = nalgebra::SymmetricEigen::new(cov);
    let mut axes: Vec<(f64, Vector3<f64>)> = (0..3)
        .map(|k| {
            (
                eig.eigenvalues[k].max(0.0),
                eig.eigenvectors.column(k).into_owned(),
            )
        })
        .collect();
    axes.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut most = 0usize;
    for (var, axis) in &axes[..2] {
        for sign in [1.0, -1.0] {
            let shift = axis * (sign * var.sqrt());
            let kept = posed
                .iter()
                .filter(|p| {
                    let q = Vector3::from(**p) + shift;
                    index.any_within(&[q.x, q.y, q.z], radius)
                })
                .count();
            most = most.max(kept);
        }
    }
    most.min(hits) as f64 / hits as f64
}

/// Each posed model point's squared distance to the nearest scan point within `radius` (NaN
/// where none: the point is not explained); the scan points that explain them (sorted,
/// distinct), how many model points are explained, and their RMS distance. `near(i)`: a
/// scan point known near model point `i`, with its squared distance (it only bounds the
/// search: [`PointIndex::nearest_within_near`]).
fn explain(
    index: &PointIndex,
    posed: &[[f64; 3]],
    radius: f64,
    near: impl Fn(usize) -> Option<(usize, f64)>,
) -> (Vec<f64>, Vec<u32>, Vec<usize>, usize, f64) {
    let (mut sum, mut targets) = (0.0, Vec::new());
    let mut nearest = vec![u32::MAX; posed.len()];
    let dist_sq: Vec<f64> = posed
        .iter()
        .enumerate()
        .map(
            |(i, q)| match index.nearest_within_near(q, radius, near(i)) {
                Some((j, d_sq)) => {
                    sum += d_sq;
                    targets.push(j);
                    nearest[i] = j as u32;
                    d_sq
                }
                None => f64::NAN,
            },
        )
        .collect();
    let hits = targets.len();
    targets.sort_unstable();
    targets.dedup();
    let rmse = if hits > 0 {
        (sum / hits as f64).sqrt()
    } else {
        0.0
    };
    (dist_sq, nearest, targets, hits, rmse)
}

/// How many posed model points the sensor could see, how many of those lie where it saw free
/// space, and the mean squared distance of the explained points (`dist_sq` not NaN; `hits`
/// of them) its depth map does not hide (NaN: none). A point the scan explains was evidently
/// seen, whatever its depth cell says (cells straddle occlusion edges), so it counts as seen;
/// the others count by the sensor's verdict (not at all where it did not look: past the
/// scan's edge). Why the hidden explained points are left out of the distance: a
/// model point behind the model's own front, or behind a nearer surface, is explained by
/// whatever surface lies near it, not by the side of the copy the sensor saw.
fn sensor_verdict(
    sensor: &Sensor,
    posed: &[[f64; 3]],
    dist_sq: &[f64],
    hits: usize,
    grazing: &[bool],
) -> (usize, usize, f64) {
    let (mut seen, mut contradicted) = (hits, 0usize);
    let (mut sum, mut visible) = (0.0, 0usize);
    let verdicts = sensor
        .depth
        .judge(posed, sensor.reach)
        .into_iter()
        .zip(grazing);
    for ((sight, graze), &d_sq) in verdicts.zip(dist_sq) {
        match (sight, !d_sq.is_nan()) {
            (Sight::Hidden, _) | (Sight::Unobserved, false) => {}
            (_, true) => {
                sum += d_sq;
                visible += 1;
            }
            _ if *graze => {}
            (Sight::Seen, false) => seen += 1,
            (Sight::Contradicted, false) => {
                seen += 1;
                contradicted += 1;
            }
        }
    }
    let mean_sq = if visible > 0 {
        sum / visible as f64
    } else {
        f64::NAN
    };
    (seen, contradicted, mean_sq)
}

/// The largest distance of `points` from their centroid.
fn radius(points: &[[f64; 3]]) -> f64 {
    let n = points.len().max(1) as f64;
    let c = points
        .iter()
        .fold(Vector3::zeros(), |c, p| c + Vector3::from(*p))
        / n;
    points
        .iter()
        .map(|p| (Vector3::from(*p) - c).norm())
        .fold(0.0, f64::max)
}

/// Which posed model points the sensor sees at grazing incidence (their surface within
/// `acos(min_cos)` of edge-on): a range sensor rarely returns there.
fn grazing(sensor: &Sensor, pose: &RigidTransform, posed: &[[f64; 3]]) -> Vec<bool> {
    if sensor.model_normals.is_empty() {
        return vec![false; posed.len()];
    }
    let eye = nalgebra::Vector3::from(sensor.depth.viewpoint());
    posed
        .iter()
        .zip(sensor.model_normals)
        .map(|(p, n)| {
            let n = pose.rotation * nalgebra::Vector3::from(*n);
            let to_eye = (eye - nalgebra::Vector3::from(*p)).normalize();
            n.dot(&to_eye).abs() < sensor.min_cos
        })
        .collect()
}

#[cfg(test)]
#[path = "../tests/refine.rs"]
mod tests;
