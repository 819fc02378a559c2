//! [`register_point_clouds`]: a model and a scan in, the pose of every copy out, as named
//! stages over one description of each cloud and one index of the scan: sensor and viewpoint
//! ([`describe_scan`]), description, matching, proposals (the correspondence stage),
//! verification, peeling, turned alternatives
//! ([`resolve_flips`](super::resolve_flips)), ranking.
//!
//! This is the training-free path, in heaps too (the ranked mutual check once many copies are
//! found, point pair voting when the scan is said to be a heap), with a known sensor position
//! or one estimated from the scan and confirmed by the first pass: the Python package's
//! `register_point_clouds` without a learned model runs the same stages with the same
//! arithmetic (poses equal to rounding), and adds the learned embedding.

use crate::config::Config;
use crate::correspondences::{Correspondences, Features, DEFAULT_NORMAL_TOLERANCE};
use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::matching::{match_features_given, nearest_sources, MatchingConfig, NearestSources};
use crate::pipeline::{register, Registration};
use crate::pointcloud::{
    check_points, check_positive, describe, isolated_points, looks_like_one_view, nearest_rotation,
    voxel_downsample, DescribeParams, Described, Orientation, PpfModel, PpfParams, RefineContext,
    RefineParams, Refined, RefinedPose,
};
use nalgebra::Matrix3;
use std::time::Instant;

use super::descriptor::Descriptor;
use super::embedder::{similarity, Embedder};
use super::faces::{FaceProposer, ModelPlanes, Proposals};
use super::flips::resolve_flips_with_symmetry;
use super::peeling::{not_duplicates, unexplained};
use super::ranking::{fit_tightness, loose_poses, pose_stability, stability_factor};
use super::sensor::describe_scan;
use super::voxel::default_voxel_size;
use super::SceneRules;
use super::{mean_point, median};
use crate::symmetry::{canonical_pose, ModelSymmetry, Symmetry};

/// How [`register_point_clouds`] runs; [`SceneOptions::default`] is the Python package's
/// defaults for this path.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneOptions {
    /// The voxel the clouds are described at; `None`: [`default_voxel_size`].
    pub voxel_size: Option<f64>,
    /// The position of the sensor that took the scan (one view): the scan's normals face it,
    /// and verification judges each pose by what the sensor could see of it. `None`: guessed
    /// from the scan ([`describe_scan`]) and confirmed by the first pass, else poses are
    /// judged by the share of the model explained.
    pub viewpoint: Option<[f64; 3]>,
    /// Matching of every pass: the `top_k` most similar mutual matches, `n_samples` of them
    /// drawn at random. `matching.k` > 1 pairs each scan point with its `k` most similar
    /// model points: a model point has one true match per copy, and with `k` = 1 a scan
    /// point proposes only the model point it likes best, so copies whose points prefer
    /// another part of the model get few matches. Only the plain (`k` = 1) mutual check is
    /// relaxed in a heap.
    pub matching: MatchingConfig,
    /// The correspondence stage's config, in the clouds' units; `None`: [`cloud_config`]
    /// (without `refine`, [`Config::default`]'s thresholds scaled by [`config_for_voxel`]).
    pub config: Option<Config>,
    /// ICP on every proposal and verification on the clouds, then peeling, turned
    /// alternatives and ranking. `false`: the correspondence stage's poses as it gives them,
    /// one pass, each scored on the clouds (nothing rejected, duplicates kept) and in the
    /// stage's order (most inliers first); the correspondence stage's config is then
    /// [`Config::default`]'s (its density pruning and a-contrario test judge the groups, as
    /// nothing after them does). Why offered: to see what the correspondence stage alone
    /// proposes, or to refine the poses elsewhere.
    pub refine: bool,
    /// Further passes over the scan points no accepted copy explains (peeling).
    pub peel: bool,
    /// Whether the scan is a heap of identical parts: `Some(true)`, every pass ranks its
    /// mutual matches as in a heap and each peeling round also votes with point pair
    /// features; `None`, passes rank as in a heap once `heap_min_copies` copies are accepted;
    /// `Some(false)`, never.
    pub heap: Option<bool>,
    /// In a heap, a match is kept when the scan point is among its model point's `heap_rank`
    /// most similar scan points still unexplained (`None` or 1: the plain mutual check).
    pub heap_rank: Option<usize>,
    /// Make the mutual check local, in cubes of the scan ([`MutualWindow`]); needs
    /// `matching.mutual` and `matching.k` = 1. `None`: scene-wide (ranked in a heap, with
    /// `heap_rank`).
    pub mutual_window: Option<MutualWindow>,
    /// Give the correspondence stage the unit normals at both ends of each correspondence
    /// (their angles join the length test; an embedder that reads normals gets them anyway).
    pub pair_normals: bool,
    /// Try turned alternatives of every accepted pose before ranking
    /// ([`resolve_flips`](super::resolve_flips)): half turns, quarter turns and the turns peeling's duplicates make with the copy they
    /// lie on.
    pub flips: bool,
    /// Seeds the sampling of matches and the correspondence stage (pass `r` uses `seed + r`).
    pub seed: u64,
    /// The model's proper symmetries: every returned pose is the canonical one among its
    /// equivalents ([`crate::symmetry::canonical_pose`]), and the turned-alternatives stage
    /// skips turns that are symmetries. `None`: none declared.
    pub symmetry: Option<ModelSymmetry>,
    /// Which poses verification judges: the descriptors' clusters alone, or with each model
    /// face laid on each planar patch of the scan ([`Proposals`]; `Auto` decides by the
    /// model's share of large flat faces).
    pub proposals: Proposals,
    /// The local descriptor both clouds are matched by (FPFH, or a learned one).
    pub descriptor: Descriptor,
    /// The scene-wide rules.
    pub scene: SceneRules,
}

impl Default for SceneOptions {
    fn default() -> Self {
        Self {
            voxel_size: None,
            viewpoint: None,
            matching: MatchingConfig {
                mutual: true,
                ..MatchingConfig::default()
            },
            config: None,
            refine: true,
            peel: true,
            heap: None,
            heap_rank: Some(64),
            mutual_window: None,
            pair_normals: false,
            flips: true,
            seed: 0,
            symmetry: None,
            proposals: Proposals::Auto,
            descriptor: Descriptor::Fpfh,
            scene: SceneRules::default(),
        }
    }
}

/// The windowed mutual check of [`SceneOptions::mutual_window`]: the scan is covered by
/// overlapping cubes of a side (a grid of stride half the side), and a pair counts as mutual
/// when the model point is the scan point's most similar and the scan point is the model
/// point's most similar among the scan points of some cube (its 64 most similar looked at).
///
/// Why: in a heap of identical parts a model point has one true match per visible copy, and
/// the scene-wide mutual check keeps at most one of them; within a cube about a part wide
/// each copy keeps its own, while the check still drops most of the pairs a model point would
/// not choose. It costs about 1.75 times the time on heaps for a small gain (BENCHMARKS.md,
/// bins), hence not the default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MutualWindow {
    /// Every pass, in cubes of this many model diagonals (the model as given).
    Diagonals(f64),
    /// Scene-wide until the passes match as in a heap ([`SceneOptions::heap`]), then in cubes
    /// of `SceneRules::heap_window` model diagonals with every match kept (no sampling), in
    /// place of the ranked check (`heap_rank` is then unused).
    Auto,
}

/// One copy of the model in the scan, refined and verified.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// `T_target_source` after ICP.
    pub pose: RigidTransform,
    /// The pass of the correspondence stage that proposed it (0: the whole scan).
    pub pass_index: usize,
    /// Its instance in that pass's [`Registration`]; from `instances.len()` on, the pose that
    /// point pair voting proposed at `instance - instances.len()` in [`Pass::voted`], and past
    /// those, a face pose of [`Pass::faces`].
    pub instance: usize,
    /// How sure the pose is, in [0, 1] (surest first): verification's confidence times the
    /// ranking's tightness and stability factors.
    pub confidence: f64,
    /// Share of the model's points with a scan point within 1.5 voxels.
    pub fitness: f64,
    /// RMS distance of those points to their nearest scan points.
    pub inlier_rmse: f64,
    /// With a trusted viewpoint: share of what the sensor could see of the model that the
    /// scan explains (NaN otherwise).
    pub visible_fitness: f64,
    /// With a trusted viewpoint: share of it lying where the sensor saw free space.
    pub contradiction: f64,
    /// With a trusted viewpoint: share of the model the sensor could see at the pose.
    pub seen: f64,
    /// With a trusted viewpoint: RMS distance of the explained points the sensor could see.
    pub visible_rmse: f64,
    /// What the model slid along the face it explains still explains, as a share of what it
    /// explains in place ([`RefineParams::max_slid_fitness`]; NaN where not measured).
    pub slid_fitness: f64,
}

/// One pass of the correspondence stage.
#[derive(Debug, Clone)]
pub struct Pass {
    /// Rows `(model point | scan point)` of the downsampled clouds; `None` when matching left
    /// fewer than 3, too few for a pose (pass 0 only: a later pass with so few is not kept,
    /// peeling stops there).
    pub correspondences: Option<Correspondences>,
    /// The mutual descriptor matches that survived matching: the rows of `correspondences`,
    /// or how few there were without them.
    pub matches: usize,
    /// The correspondence stage's result over them ([`Registration::default`], empty, without
    /// them).
    pub registration: Registration,
    /// Indices into [`SceneRegistration::target`]'s points of the scan points matched.
    pub scan_points: Vec<usize>,
    /// Copies this pass added to the accepted ones.
    pub added: usize,
    /// Poses proposed by point pair voting over `scan_points` (in a scan said to be a heap).
    pub voted: Vec<RigidTransform>,
    /// Poses laying a model face on a planar patch of `scan_points`, refined after `voted`
    /// ([`SceneOptions::proposals`]): a candidate's instance from `instances.len() +
    /// voted.len()` on names one of these.
    pub faces: Vec<RigidTransform>,
    /// Poses of this pass that passed verification on a copy already accepted (peeling's
    /// duplicate check): their rotations relative to that copy's pose are the scene's own
    /// alternatives for the turned-alternatives stage.
    pub duplicates: Vec<RigidTransform>,
}

/// The result of [`register_point_clouds`].
#[derive(Debug, Clone)]
pub struct SceneRegistration {
    /// The copies found, surest first.
    pub candidates: Vec<Candidate>,
    /// Poses that fit the scan as well but slide along a face (a box flush with its
    /// neighbours, or a flat face lying on a larger plane): where along that face the copy
    /// lies, the scan does not say. Surest first, confidence lowered by the slide
    /// ([`Refined::sliding`]), none sharing more than `max_shared` of its scan points with a
    /// candidate or a surer one. Not in `candidates`: the caller decides, with each one's
    /// information matrix.
    pub ambiguous: Vec<Candidate>,
    /// Every pass: pass 0 over the whole scan, then one per peeling round.
    pub passes: Vec<Pass>,
    /// The model, downsampled and described.
    pub source: Described,
    /// The scan, downsampled (strays dropped when many) and described.
    pub target: Described,
    pub voxel_size: f64,
    /// The correspondence stage's config, in the clouds' units.
    pub config: Config,
    /// Whether the poses were judged by what the sensor could see from the viewpoint.
    pub by_visibility: bool,
    /// The sensor position the poses were judged by (given, or a guess the first pass
    /// confirmed); `None`: none.
    pub viewpoint: Option<[f64; 3]>,
    /// A guessed sensor position the first pass did not confirm.
    pub unconfirmed_viewpoint: Option<[f64; 3]>,
    /// Whether the scan does not look like one view from the viewpoint given
    /// ([`looks_like_one_view`]); verification used it all the same.
    pub viewpoint_disputed: bool,
    /// How the scan's normals were oriented, in words.
    pub orientation: String,
    /// Whether the model's faces were laid on the scan's planar patches
    /// ([`SceneOptions::proposals`]).
    pub face_proposals: bool,
    /// The share of the downsampled model in planar faces wider than the FPFH disc (what
    /// `Proposals::Auto` and `Descriptor::Auto` decide by); NaN when neither needs it.
    pub planar_share: f64,
    /// The descriptor the clouds were matched by ([`Descriptor::name`]; `Descriptor::Auto`
    /// decided for the model: "fpfh" or "fpfh+learned").
    pub descriptor: &'static str,
    /// The model's symmetries the poses were made canonical by (declared, or detected).
    pub symmetry: Option<Symmetry>,
    /// Seconds spent in each stage after the clouds were described (theirs are in
    /// `source.timings` and `target.timings`).
    pub timings: SceneTimings,
}

/// Seconds per stage of [`register_point_clouds`] after description.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SceneTimings {
    /// Matching of the first pass.
    pub matching: f64,
    /// The learned embedding of the first pass's correspondences (0 without one).
    pub embedding: f64,
    /// The correspondence stage of the first pass (its own stages in its `Registration`).
    pub registration: f64,
    /// ICP and verification of the first pass's poses (and the viewpoint's confirmation).
    pub refinement: f64,
    /// Every peeling round.
    pub peeling: f64,
    /// Turned alternatives and the final ranking.
    pub flips: f64,
}

/// `Config::sigma_d` on clouds, in voxels: a right descriptor match lands within about a voxel
/// of the true point on each side, so pairwise length differences are off by up to about 2
/// voxels; at 3 their consistency stays above 0.5.
pub const SIGMA_D_VOXELS: f64 = 3.0;

/// `Config::default()`'s inlier threshold on clouds, in voxels: the same voxel on each side
/// bounds a right pose's residual (the synthetic ratio, twice sigma_d, lets a wrong pose
/// collect as many chance inliers on a dense scan as a right one; chosen on the validation
/// models: MF 17.6 -> 20.5).
pub const INLIER_VOXELS: f64 = 2.0;

/// The correspondence stage's thresholds for poses that verification on the clouds judges next,
/// in the synthetic units of [`Config::default`]: verification judges every proposal far
/// better than a count of correspondences can, so the stage proposes every plausible group
/// (`tau_s` 0.8, `tau_n` 1: almost no density pruning; clusters of 3; no a-contrario test).
/// Chosen on 200 realistic scenes of the five non-bunny models (BENCHMARKS.md).
pub fn cloud_base_config(cluster_level: Option<f64>) -> Config {
    Config {
        tau_s: 0.8,
        tau_n: 1,
        min_cluster_size: 3,
        max_nfa: None,
        cluster_level,
        ..Config::default()
    }
}

/// `base` (synthetic units) in the units of clouds described at `voxel`: sigma_d at
/// [`SIGMA_D_VOXELS`] voxels, the affinity in its ratio to sigma_d, and the inlier threshold at
/// [`INLIER_VOXELS`] voxels for `Config::default()`'s (others in proportion).
pub fn config_for_voxel(base: &Config, voxel: f64) -> Config {
    let mut scaled = base.scaled(SIGMA_D_VOXELS * voxel / base.sigma_d);
    let per_unit = INLIER_VOXELS * voxel / Config::default().inlier_threshold;
    scaled.inlier_threshold = base.inlier_threshold * per_unit;
    scaled
}

/// The correspondence stage's config for clouds described at `voxel`:
/// [`cloud_base_config`] scaled by [`config_for_voxel`].
pub fn cloud_config(voxel: f64, cluster_level: Option<f64>) -> Config {
    config_for_voxel(&cloud_base_config(cluster_level), voxel)
}

/// Finds every copy of `model` (a complete object) in `scan`; see the module documentation.
/// Parallel on the current rayon pool; the result depends only on the inputs and the seed.
///
/// Errors are for input it cannot use (non-finite or too few points, bad options). A scan
/// whose descriptors leave fewer than 3 matches is an answer, not an error: no copy from
/// the descriptors (pass 0 without correspondences, [`Pass::matches`] saying how few), though
/// face proposals, which need no matches, may still find some.
pub fn register_point_clouds(
    model: &[[f64; 3]],
    scan: &[[f64; 3]],
    options: &SceneOptions,
) -> Result<SceneRegistration> {
    register_point_clouds_with(model, scan, options, None)
}

/// [`register_point_clouds`] with a learned embedding: `embedder` embeds every pass's
/// correspondences (with the cues it takes attached) and the correspondence stage prunes and
/// clusters with it. Give `options.config` the thresholds chosen with the network, in the
/// clouds' units.
pub fn register_point_clouds_with(
    model: &[[f64; 3]],
    scan: &[[f64; 3]],
    options: &SceneOptions,
    embedder: Option<&dyn Embedder>,
) -> Result<SceneRegistration> {
    check_points(model, "model points", 3)?;
    check_points(scan, "scan points", 3)?;
    let bad = options.scene.clone();
    if let Some((field, value)) = crate::config::Declared::out_of_range(&bad) {
        return Err(Error::InvalidParameter {
            name: field.name,
            value: value.to_string(),
            reason: "outside its declared range (see SceneRules::FIELDS)",
        });
    }
    let voxel = match options.voxel_size {
        Some(v) => {
            check_positive("voxel_size", v)?;
            v
        }
        None => default_voxel_size(model, Some(scan), &options.scene)?,
    };
    check_positive("voxel_size (the model has no extent: give one)", voxel)?;
    check_window(options)?;
    let mut run = Run::new(model, scan, voxel, options, embedder)?;
    let symmetry = match &options.symmetry {
        Some(s) => Some(s.resolve(model, &run.source.points)?),
        None => None,
    };
    let config = match &options.config {
        Some(c) => c.clone(),
        None if !options.refine => config_for_voxel(&Config::default(), voxel),
        None => cloud_config(
            voxel,
            options.peel.then_some(options.scene.peel_cluster_level),
        ),
    };
    let everything: Vec<usize> = (0..run.target.points.len()).collect();
    let heap = run.is_heap(0);
    let mut timings = SceneTimings::default();
    let mut clock = Instant::now();
    let mut lap = || {
        let seconds = clock.elapsed().as_secs_f64();
        clock = Instant::now();
        seconds
    };
    let matched = run.matched(&everything, options.seed, heap)?;
    timings.matching = lap();
    // Too few matches is what the data says (a scan without the model, or shapes the
    // descriptors cannot tell apart), not bad input: an empty stage, and the face proposals,
    // which need no matches, still run.
    let (corr, matches, registration) = match matched {
        Ok((corr, distances)) => {
            let features = run.features(&corr, &distances)?;
            timings.embedding = lap();
            let registration = register(&corr, features.as_ref(), &config, options.seed)?;
            let n = corr.len();
            (Some(corr), n, registration)
        }
        Err(got) => (None, got, Registration::default()),
    };
    let faces = match options.refine {
        true => run.face_poses(None)?,
        false => Vec::new(),
    };
    timings.registration = lap();
    let mut proposed = poses_of(&registration);
    proposed.extend(faces.iter().copied());
    let first = if !options.refine {
        run.scored(&proposed)?
    } else if run.guessed {
        run.confirm_viewpoint(&proposed)?
    } else {
        run.refine(&proposed, &run.rules.clone())?
    };
    timings.refinement = lap();
    run.keep_sliding(&first, 0, |origin| origin);
    let mut accepted = Accepted::from_pass(first, 0);
    let added = accepted.len();
    run.passes.push(Pass {
        correspondences: corr,
        matches,
        registration,
        scan_points: everything,
        added,
        voted: Vec::new(),
        faces,
        duplicates: Vec::new(),
    });
    if options.refine && options.peel && !accepted.is_empty() {
        accepted = run.peel(accepted, &config)?;
    }
    timings.peeling = lap();
    if options.refine && options.flips && !accepted.is_empty() {
        accepted = run.flipped(accepted, symmetry.as_ref())?;
    }
    let mut candidates = match options.refine {
        true => run.ranked(accepted)?,
        false => candidates(accepted),
    };
    let mut ambiguous = run.ambiguous(&candidates)?;
    if let Some(s) = &symmetry {
        for c in candidates.iter_mut().chain(&mut ambiguous) {
            c.pose = canonical_pose(&c.pose, s);
        }
    }
    timings.flips = lap();
    Ok(SceneRegistration {
        timings,
        candidates,
        ambiguous,
        passes: run.passes,
        by_visibility: run.by_visibility,
        viewpoint: run.viewpoint,
        unconfirmed_viewpoint: run.unconfirmed,
        viewpoint_disputed: run.disputed,
        orientation: run.orientation,
        face_proposals: run.faces.is_some(),
        planar_share: run.planar_share,
        descriptor: run.descriptor,
        symmetry,
        source: run.source,
        target: run.target,
        voxel_size: voxel,
        config,
    })
}

/// What every pass of one call shares.
struct Run<'o> {
    source: Described,
    target: Described,
    nearest: NearestSources,
    /// Each model row's nearest scan rows, nearest first (the ranked mutual check's
    /// candidates), found on first use.
    targets_of_sources: Option<NearestSources>,
    voter: Option<PpfModel>,
    /// Face proposals, when [`SceneOptions::proposals`] asks for them.
    faces: Option<FaceProposer>,
    planar_share: f64,
    /// The descriptor the clouds were matched by, decided ([`Descriptor::for_model`]).
    descriptor: &'static str,
    context: RefineContext,
    rules: RefineParams,
    voxel: f64,
    /// The model's bounding-box diagonal as given (the unit of `mutual_window`).
    model_diagonal: f64,
    options: &'o SceneOptions,
    embedder: Option<&'o dyn Embedder>,
    passes: Vec<Pass>,
    /// Every pass's poses that fit but slide along a face, with their (pass, instance).
    sliding: Accepted,
    by_visibility: bool,
    /// The sensor position verification judges by.
    viewpoint: Option<[f64; 3]>,
    /// Whether `viewpoint` is a guess the first pass must confirm.
    guessed: bool,
    /// A guess the first pass did not confirm.
    unconfirmed: Option<[f64; 3]>,
    /// The scan does not look like one view from the viewpoint given.
    disputed: bool,
    orientation: String,
}

impl<'o> Run<'o> {
    /// The clouds described, the scan's nearest model descriptors found once for every pass,
    /// and the refinement context (the one index of the scan every later stage uses).
    fn new(
        model: &[[f64; 3]],
        scan: &[[f64; 3]],
        voxel: f64,
        options: &'o SceneOptions,
        embedder: Option<&'o dyn Embedder>,
    ) -> Result<Self> {
        let centre = mean_point(model);
        let source = describe(
            model,
            None,
            &DescribeParams {
                orientation: Orientation::AwayFrom(centre),
                ..DescribeParams::for_voxel(voxel)
            },
        )?;
        let points = without_strays(voxel_downsample(scan, voxel)?, voxel, &options.scene)?;
        let scan = describe_scan(&points, voxel, options.viewpoint, &source, &options.scene)?;
        let needs_planes =
            options.proposals != Proposals::Descriptors || options.descriptor.by_shape();
        let planes = needs_planes
            .then(|| ModelPlanes::new(&source.points, &source.normals, voxel))
            .transpose()?;
        let planar_share = planes.as_ref().map_or(f64::NAN, |p| p.planar_share);
        let descriptor = options
            .descriptor
            .for_model(planar_share, options.scene.min_planar_share);
        let source = descriptor.apply(source, voxel)?;
        let target = descriptor.apply(scan.cloud, voxel)?;
        let k = options.matching.k;
        let nearest = nearest_sources(&source.descriptors, &target.descriptors, k)?;
        let rules = RefineParams::for_voxel(voxel);
        let disputed = match options.viewpoint {
            Some(v) => !looks_like_one_view(&target.points, v, &rules)?,
            None => false,
        };
        // A guess is kept only where the scan looks like one view from it: unlike the
        // caller's word, it has nothing else to stand on.
        let (viewpoint, guessed) = match (scan.viewpoint, scan.guessed) {
            (Some(v), true) if !looks_like_one_view(&target.points, v, &rules)? => (None, false),
            kept => kept,
        };
        let context = RefineContext::new(
            &source.points,
            &target.points,
            Some(&target.normals),
            viewpoint,
            &rules,
        )?;
        let faces = match (options.proposals, planes) {
            (Proposals::Descriptors, _) | (_, None) => None,
            (wanted, Some(planes)) => {
                let forced = wanted == Proposals::Faces;
                let faces = if forced || planar_share >= options.scene.min_planar_share {
                    planes.faces()?
                } else {
                    Vec::new()
                };
                let with = forced || !faces.is_empty();
                with.then(|| {
                    FaceProposer::new(
                        &source.points,
                        faces,
                        &target.points,
                        &target.normals,
                        context.index(),
                        voxel,
                        &options.scene,
                    )
                })
                .transpose()?
            }
        };
        Ok(Self {
            source,
            target,
            nearest,
            targets_of_sources: None,
            voter: None,
            faces,
            planar_share,
            descriptor: descriptor.name(),
            context,
            rules,
            voxel,
            model_diagonal: super::voxel::diagonal(model),
            options,
            embedder,
            passes: Vec::new(),
            sliding: Accepted {
                rows: Vec::new(),
                tags: Vec::new(),
            },
            by_visibility: false,
            viewpoint,
            guessed,
            unconfirmed: None,
            disputed,
            orientation: scan.orientation,
        })
    }

    /// Pass 0's poses refined and verified when the viewpoint is a guess (the origin of a
    /// scan in its sensor's frame, or the sensor position estimated from the scan): judged
    /// from there when that keeps the pose the model share ranks first, else without a
    /// viewpoint, which the run then keeps.
    ///
    /// Why: a scan looks like one view from many points near its sensor (at most 3 % of it
    /// covered all round from there), which is enough to orient normals but not to judge poses, where 1 %
    /// of a model in free space rejects them. A Stanford range scan 0.06-0.19 m from the
    /// origin looks like one view from it, and every pose fails there; a depth camera's frame
    /// keeps its surest copy. An estimate 10 degrees off costs about a twentieth of the
    /// realistic F1, 20 degrees a fifth (BENCHMARKS.md). ICP does not depend on the
    /// viewpoint, so the poses are refined once and judged both ways.
    fn confirm_viewpoint(&mut self, poses: &[RigidTransform]) -> Result<Refined> {
        let blind = RefineContext::new(
            &self.source.points,
            &self.target.points,
            Some(&self.target.normals),
            None,
            &self.rules,
        )?;
        let mut fitted = blind.refine(poses, &self.rules.keeping_all())?.poses;
        // Back in the input order, so that both verdicts break ties as one refinement would.
        fitted.sort_by_key(|r| r.origin);
        let refitted: Vec<RigidTransform> = fitted.iter().map(|r| handed(r.pose)).collect();
        let source: Vec<usize> = fitted.iter().map(|r| r.origin).collect();
        let judge = RefineParams {
            icp: false,
            ..self.rules.clone()
        };
        let in_input = |mut judged: Refined| {
            for r in judged.poses.iter_mut().chain(&mut judged.sliding) {
                r.origin = source[r.origin];
            }
            judged
        };
        let seen = in_input(self.context.refine(&refitted, &judge)?);
        let without = in_input(blind.refine(&refitted, &judge)?);
        let kept: Vec<usize> = seen.poses.iter().map(|r| r.origin).collect();
        let confirmed = !kept.is_empty()
            && without
                .poses
                .first()
                .is_none_or(|best| kept.contains(&best.origin));
        if confirmed {
            self.by_visibility = seen.by_visibility;
            return Ok(seen);
        }
        // Nothing either way confirms nothing: the run goes on (and explains) without one.
        self.unconfirmed = self.viewpoint.take();
        self.context = blind;
        self.by_visibility = without.by_visibility;
        Ok(without)
    }

    /// Pass 0's poses without `refine`: scored on the clouds as they are (no ICP, nothing
    /// rejected, duplicates kept), in the correspondence stage's order (most inliers first).
    fn scored(&mut self, poses: &[RigidTransform]) -> Result<Refined> {
        let keep_all = RefineParams {
            icp: false,
            ..self.rules.keeping_all()
        };
        let mut scored = self.refine(poses, &keep_all)?;
        scored.poses.sort_by_key(|r| r.origin);
        Ok(scored)
    }

    /// Correspondences between the model and the scan points `rows` (mutual, sampled with
    /// `seed`), or how many survived when fewer than 3 (too few for a pose).
    fn matched(
        &mut self,
        rows: &[usize],
        seed: u64,
        heap: bool,
    ) -> Result<std::result::Result<(Correspondences, Vec<f64>), usize>> {
        let mut config = self.options.matching;
        let ranked;
        let window = self.options.mutual_window;
        let relaxed = match (heap, window) {
            (true, Some(MutualWindow::Auto)) => {
                config.n_samples = None;
                Some(self.window_mutual(rows, self.options.scene.heap_window)?)
            }
            (true, _) => Some(self.rank_mutual(rows)?),
            (false, Some(MutualWindow::Diagonals(side))) => Some(self.window_mutual(rows, side)?),
            (false, _) => None,
        };
        let rows = match relaxed {
            Some(kept) => {
                // The pairs the relaxed check keeps are the mutual ones: no further check.
                ranked = kept;
                config.mutual = false;
                if ranked.is_empty() {
                    return Ok(Err(0));
                }
                &ranked[..]
            }
            None => rows,
        };
        let dim = self.target.descriptors.dim();
        let flat: Vec<f64> = rows
            .iter()
            .flat_map(|&r| self.target.descriptors.row(r).iter().copied())
            .collect();
        let subset = Features::new(flat, dim)?;
        let k = self.nearest.k;
        let nearest = NearestSources {
            k,
            source: rows
                .iter()
                .flat_map(|&r| self.nearest.source[r * k..(r + 1) * k].iter().copied())
                .collect(),
            dist2: rows
                .iter()
                .flat_map(|&r| self.nearest.dist2[r * k..(r + 1) * k].iter().copied())
                .collect(),
        };
        let m = match_features_given(&self.source.descriptors, &subset, &nearest, &config, seed)?;
        let src: Vec<[f64; 3]> = m.source.iter().map(|&i| self.source.points[i]).collect();
        let used: Vec<usize> = m.target.iter().map(|&j| rows[j]).collect();
        let tgt: Vec<[f64; 3]> = used.iter().map(|&j| self.target.points[j]).collect();
        if src.len() < 3 {
            return Ok(Err(src.len()));
        }
        let mut corr = Correspondences::new(&src, &tgt)?;
        if self.options.pair_normals || self.embedder.is_some_and(|e| e.takes_normals()) {
            let ns: Vec<[f64; 3]> = m.source.iter().map(|&i| self.source.normals[i]).collect();
            let nt: Vec<[f64; 3]> = used.iter().map(|&j| self.target.normals[j]).collect();
            corr = corr.with_normals(&ns, &nt, DEFAULT_NORMAL_TOLERANCE)?;
        }
        Ok(Ok((corr, m.distance)))
    }

    /// The learned embedding of a pass's correspondences (with the descriptor similarity of
    /// their `distances` when the embedder takes it); None without an embedder.
    fn features(&self, corr: &Correspondences, distances: &[f64]) -> Result<Option<Features>> {
        let Some(embedder) = self.embedder else {
            return Ok(None);
        };
        if embedder.takes_similarity() {
            let with = corr.clone().with_similarity(&similarity(distances))?;
            return embedder.embed(&with).map(Some);
        }
        embedder.embed(corr).map(Some)
    }

    /// Whether a pass after `accepted` copies matches as in a heap: the scan is said to be one,
    /// or that many copies show one; never where only the mutual check could be relaxed.
    fn is_heap(&self, accepted: usize) -> bool {
        let o = self.options;
        let relaxed = match o.mutual_window {
            None => o.heap_rank.is_some_and(|r| r > 1),
            Some(MutualWindow::Auto) => true,
            // Every pass is windowed already.
            Some(MutualWindow::Diagonals(_)) => false,
        };
        let relaxable = o.matching.mutual && o.matching.k == 1 && o.heap != Some(false) && relaxed;
        relaxable && (o.heap == Some(true) || accepted >= o.scene.heap_min_copies)
    }

    /// The scan rows of `rows` whose nearest model row counts them among its `heap_rank`
    /// nearest rows of `rows` (looked for among its nearest 64 of the whole scan, or
    /// `heap_rank` if more), ascending.
    fn rank_mutual(&mut self, rows: &[usize]) -> Result<Vec<usize>> {
        let rank = self.options.heap_rank.unwrap_or(1);
        let near = self.targets_of_sources(rank)?;
        let mut taking_part = vec![false; self.target.points.len()];
        for &r in rows {
            taking_part[r] = true;
        }
        let mut kept = Vec::new();
        for s in 0..self.source.points.len() {
            let list = &near.source[s * near.k..(s + 1) * near.k];
            for &t in list.iter().filter(|&&t| taking_part[t]).take(rank) {
                if self.nearest.source[t * self.nearest.k] == s {
                    kept.push(t);
                }
            }
        }
        self.targets_of_sources = Some(near);
        kept.sort_unstable();
        kept.dedup();
        Ok(kept)
    }

    /// Each model row's `k` (at least [`WINDOW_CANDIDATES`]) nearest scan rows of the whole
    /// scan, nearest first: found once per call (its `k` is fixed for a call), to be put back
    /// in `targets_of_sources` after use.
    fn targets_of_sources(&mut self, k: usize) -> Result<NearestSources> {
        let k = k.max(WINDOW_CANDIDATES).min(self.target.points.len());
        match self.targets_of_sources.take() {
            Some(near) if near.k == k => Ok(near),
            _ => nearest_sources(&self.target.descriptors, &self.source.descriptors, k),
        }
    }

    /// The scan rows of `rows` in a pair the windowed mutual check keeps, in cubes of `side`
    /// model diagonals ([`MutualWindow`]), ascending.
    fn window_mutual(&mut self, rows: &[usize], side: f64) -> Result<Vec<usize>> {
        let near = self.targets_of_sources(WINDOW_CANDIDATES)?;
        let kept = super::window::windowed_mutual(
            &self.target.points,
            rows,
            &near,
            &self.nearest,
            side * self.model_diagonal,
        );
        self.targets_of_sources = Some(near);
        Ok(kept)
    }

    /// Poses voted by point pairs among the scan points `rows`, most voted first (the
    /// references start at `round`, so that each round votes from other points).
    fn voted(&mut self, rows: &[usize], round: usize) -> Result<Vec<RigidTransform>> {
        let voter = match self.voter.take() {
            Some(voter) => voter,
            None => {
                let diameter = super::voxel::diagonal(&self.source.points);
                let params = PpfParams {
                    max_poses: self.options.scene.heap_voted_poses.max(1),
                    ..PpfParams::for_diameter(diameter)
                };
                PpfModel::new(&self.source.points, &self.source.normals, params)?
            }
        };
        let poses = voter.poses(&self.target.points, &self.target.normals, rows, round);
        self.voter = Some(voter);
        Ok(poses?.into_iter().map(|p| handed(p.transform)).collect())
    }

    /// Face poses over the scan rows where `free` is true (all when `None`); none unless
    /// asked for.
    fn face_poses(&self, free: Option<&[bool]>) -> Result<Vec<RigidTransform>> {
        match &self.faces {
            Some(proposer) => Ok(proposer
                .poses(free, &self.context, self.rules.icp_radius_coarse)?
                .into_iter()
                .map(handed)
                .collect()),
            None => Ok(Vec::new()),
        }
    }

    /// The rows of `voted` worth refining: those already bringing `voted_min_relative_fitness`
    /// times the median accepted copy's share of the model within ICP's first radius.
    fn within_reach(&self, voted: &[RigidTransform], accepted: &Accepted) -> Result<Vec<usize>> {
        if voted.is_empty() || accepted.is_empty() {
            return Ok((0..voted.len()).collect());
        }
        let n = self.source.points.len();
        let step = n.div_ceil(self.options.scene.screen_points);
        let model: Vec<[f64; 3]> = self.source.points.iter().step_by(step).copied().collect();
        let near = self
            .context
            .near_shares(voted, &model, self.rules.icp_radius_coarse)?;
        let fitness: Vec<f64> = accepted.rows.iter().map(|r| r.fitness).collect();
        let floor = self.vote_floor(fitness);
        Ok((0..voted.len()).filter(|&i| near[i] >= floor).collect())
    }

    /// The share of the model a voted pose must explain.
    fn vote_floor(&self, mut fitness: Vec<f64>) -> f64 {
        self.options.scene.voted_min_relative_fitness * median(&mut fitness)
    }

    fn refine(&mut self, poses: &[RigidTransform], params: &RefineParams) -> Result<Refined> {
        let refined = self.context.refine(poses, params)?;
        self.by_visibility = refined.by_visibility;
        Ok(refined)
    }

    /// Keeps `refined`'s sliding poses, tagged with `pass` and their instance in it.
    fn keep_sliding(&mut self, refined: &Refined, pass: usize, instance: impl Fn(usize) -> usize) {
        for r in &refined.sliding {
            self.sliding.rows.push(r.clone());
            self.sliding.tags.push((pass, instance(r.origin)));
        }
    }

    /// The sliding poses of every pass, surest first, without those sharing more than
    /// `max_shared` of the scan points they explain with the copies `found` or a surer one.
    fn ambiguous(&self, found: &[Candidate]) -> Result<Vec<Candidate>> {
        let mut sliding = Accepted {
            rows: self.sliding.rows.clone(),
            tags: self.sliding.tags.clone(),
        };
        if sliding.is_empty() {
            return Ok(Vec::new());
        }
        sliding.sort();
        let radius = self.rules.fit_radius;
        let found: Vec<RigidTransform> = found.iter().map(|c| handed(c.pose)).collect();
        let index = self.context.index();
        let mut taken: Vec<bool> =
            unexplained(&self.target.points, &self.source.points, &found, radius)?
                .into_iter()
                .map(|free| !free)
                .collect();
        let keep = not_duplicates(
            index,
            &self.source.points,
            &sliding.poses(),
            radius,
            self.rules.max_shared,
            &mut taken,
        )?;
        Ok(candidates(sliding.take(&keep)))
    }

    /// Scan points no pose of `accepted` explains (within `peel_radius_voxels`).
    fn unexplained(&self, accepted: &Accepted) -> Result<Vec<bool>> {
        let radius = self.options.scene.peel_radius_voxels * self.voxel;
        unexplained(
            &self.target.points,
            &self.source.points,
            &accepted.poses(),
            radius,
        )
    }

    /// Peeling rounds until one adds no copy (in a heap, `heap_empty_rounds` in a row), or
    /// `max_peel_rounds`.
    fn peel(&mut self, mut accepted: Accepted, config: &Config) -> Result<Accepted> {
        let mut free = self.unexplained(&accepted)?;
        let mut empty = 0;
        for round in 1..=self.options.scene.max_peel_rounds {
            let rows: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
            if rows.len() < 3 {
                break;
            }
            let heap = self.is_heap(accepted.len());
            let seed = self.options.seed.wrapping_add(round as u64);
            let voted = if heap && self.options.heap == Some(true) {
                self.voted(&rows, round)?
            } else {
                Vec::new()
            };
            let Ok((corr, distances)) = self.matched(&rows, seed, heap)? else {
                break;
            };
            let features = self.features(&corr, &distances)?;
            let registration = register(&corr, features.as_ref(), config, seed)?;
            let clustered = registration.instances.len();
            let reach = self.within_reach(&voted, &accepted)?;
            let faces = self.face_poses(Some(&free))?;
            let mut candidates = poses_of(&registration);
            candidates.extend(reach.iter().map(|&i| voted[i]));
            candidates.extend(faces.iter().copied());
            let (reached, n_voted) = (clustered + reach.len(), voted.len());
            let every = RefineParams {
                max_shared: 1.0,
                ..self.rules.clone()
            };
            let mut new = self.refine(&candidates, &every)?;
            // A voted pose's origin names its row of `voted`, past the clusters', and a face
            // pose's its row of `faces`, past every voted one.
            let instance = |origin: usize| match origin {
                o if o >= reached => clustered + n_voted + (o - reached),
                o if o >= clustered => clustered + reach[o - clustered],
                o => o,
            };
            for pose in &mut new.poses {
                pose.origin = instance(pose.origin);
            }
            self.keep_sliding(&new, round, instance);
            let votes = clustered..clustered + n_voted;
            let new = self.without_weak_votes(Accepted::from_pass(new, round), votes, &accepted);
            let mut duplicates = Vec::new();
            if !new.is_empty() && self.by_visibility {
                let mut taken: Vec<bool> = free.iter().map(|f| !f).collect();
                let keep = not_duplicates(
                    self.context.index(),
                    &self.source.points,
                    &new.poses(),
                    1.5 * self.voxel,
                    self.rules.max_shared,
                    &mut taken,
                )?;
                let kept = new.take(&keep);
                duplicates = (0..new.len())
                    .filter(|i| !keep.contains(i))
                    .map(|i| new.rows[i].pose)
                    .collect();
                let explained = self.unexplained(&kept)?;
                for (f, e) in free.iter_mut().zip(explained) {
                    *f &= e;
                }
                accepted = accepted.merged(kept);
            } else if !new.is_empty() {
                let pool = accepted.merged_unsorted(new);
                let judged = self.refine(
                    &pool.poses(),
                    &RefineParams {
                        icp: false,
                        ..self.rules.clone()
                    },
                )?;
                accepted = pool.reverified(judged);
                free = self.unexplained(&accepted)?;
            }
            let added = accepted.tags.iter().filter(|t| t.0 == round).count();
            self.passes.push(Pass {
                matches: corr.len(),
                correspondences: Some(corr),
                registration,
                scan_points: rows,
                added,
                voted,
                faces,
                duplicates,
            });
            empty = if added > 0 { 0 } else { empty + 1 };
            let patience = if heap {
                self.options.scene.heap_empty_rounds
            } else {
                1
            };
            if empty >= patience {
                break;
            }
        }
        Ok(accepted)
    }

    /// `new` without the voted poses (instance in `votes`) that explain less of the model than
    /// `voted_min_relative_fitness` times the median copy (those accepted before this round
    /// and this round's others; with none, the best voted). Face poses are not votes: their
    /// patch is evidence of the face, as a cluster of matches is.
    fn without_weak_votes(
        &self,
        new: Accepted,
        votes: std::ops::Range<usize>,
        accepted: &Accepted,
    ) -> Accepted {
        let voted: Vec<bool> = new.tags.iter().map(|t| votes.contains(&t.1)).collect();
        if !voted.iter().any(|&v| v) {
            return new;
        }
        let mut peers: Vec<f64> = accepted.rows.iter().map(|r| r.fitness).collect();
        peers.extend(
            new.rows
                .iter()
                .zip(&voted)
                .filter(|(_, &v)| !v)
                .map(|(r, _)| r.fitness),
        );
        if peers.is_empty() {
            let best = new
                .rows
                .iter()
                .zip(&voted)
                .filter(|(_, &v)| v)
                .map(|(r, _)| r.fitness)
                .fold(f64::NEG_INFINITY, f64::max);
            peers.push(best);
        }
        let floor = self.vote_floor(peers);
        let keep: Vec<usize> = (0..new.len())
            .filter(|&i| !voted[i] || new.rows[i].fitness >= floor)
            .collect();
        new.take(&keep)
    }

    /// The accepted poses with the turned alternatives the scan supports better
    /// ([`resolve_flips`](super::resolve_flips)), surest first.
    fn flipped(&self, accepted: Accepted, symmetry: Option<&Symmetry>) -> Result<Accepted> {
        let turns = self.duplicate_turns(&accepted);
        let poses = Refined {
            poses: accepted.rows.clone(),
            by_visibility: self.by_visibility,
            rejected: Vec::new(),
            sliding: Vec::new(),
        };
        let params = RefineParams::for_voxel(self.voxel);
        let none = Symmetry::none();
        let (out, order) = resolve_flips_with_symmetry(
            &self.context,
            &params,
            &poses,
            &turns,
            &self.options.scene,
            symmetry.unwrap_or(&none),
        )?;
        Ok(Accepted {
            rows: out.poses,
            tags: order.iter().map(|&i| accepted.tags[i]).collect(),
        })
    }

    /// Each duplicate the passes dropped ([`Pass::duplicates`]) as a rotation of the model
    /// relative to the accepted pose whose copy it lies on (the nearest by the posed model's
    /// centroid): `R_home^T R_duplicate`, the duplicate's rotation in the home pose's frame.
    fn duplicate_turns(&self, accepted: &Accepted) -> Vec<Matrix3<f64>> {
        let centre = mean_point(&self.source.points);
        let placed = |pose: &RigidTransform| pose.apply(centre);
        let homes: Vec<[f64; 3]> = accepted.rows.iter().map(|r| placed(&r.pose)).collect();
        let mut turns = Vec::new();
        for duplicate in self.passes.iter().flat_map(|p| &p.duplicates) {
            let at = placed(duplicate);
            let home = (0..homes.len())
                .min_by(|&a, &b| distance(homes[a], at).total_cmp(&distance(homes[b], at)));
            if let Some(home) = home {
                turns.push(accepted.rows[home].pose.rotation.transpose() * duplicate.rotation);
            }
        }
        turns
    }

    /// The accepted poses, final: with the sensor's judgement, those fitting loosely against
    /// the scene's median dropped and the rest ranked by tightness and stability.
    fn ranked(&self, accepted: Accepted) -> Result<Vec<Candidate>> {
        let mut accepted = accepted;
        if self.by_visibility {
            let sc = &self.options.scene;
            let rmse: Vec<f64> = accepted.rows.iter().map(|r| r.visible_rmse).collect();
            let loose = loose_poses(&rmse, sc.max_relative_visible_rmse, sc.min_poses_to_compare);
            let keep: Vec<usize> = (0..loose.len()).filter(|&i| !loose[i]).collect();
            accepted = accepted.take(&keep);
            let stability = pose_stability(
                &self.source.points,
                &self.source.normals,
                self.context.index(),
                &accepted.poses(),
                1.5 * self.voxel,
            )?;
            let rmse: Vec<f64> = accepted.rows.iter().map(|r| r.visible_rmse).collect();
            let tight = fit_tightness(&rmse, sc.min_poses_to_compare);
            let stable = stability_factor(&stability, sc.min_poses_to_compare);
            for (i, row) in accepted.rows.iter_mut().enumerate() {
                row.confidence *= tight[i] * stable[i];
            }
            accepted.sort();
        }
        Ok(candidates(accepted))
    }
}

/// The copies as [`register_point_clouds`] returns them, in `accepted`'s order.
fn candidates(accepted: Accepted) -> Vec<Candidate> {
    accepted
        .rows
        .into_iter()
        .zip(accepted.tags)
        .map(|(r, (pass_index, instance))| Candidate {
            pose: r.pose,
            pass_index,
            instance,
            confidence: r.confidence,
            fitness: r.fitness,
            inlier_rmse: r.inlier_rmse,
            visible_fitness: r.visible_fitness,
            contradiction: r.contradiction,
            seen: r.seen,
            visible_rmse: r.visible_rmse,
            slid_fitness: r.slid_fitness,
        })
        .collect()
}

/// A bad `mutual_window` as a typed error: a side that is not a positive number, or a window
/// where the check it relaxes is not the plain mutual one.
fn check_window(options: &SceneOptions) -> Result<()> {
    if let Some(MutualWindow::Diagonals(side)) = options.mutual_window {
        check_positive("mutual_window", side)?;
        if !options.matching.mutual || options.matching.k != 1 {
            return Err(Error::InvalidParameter {
                name: "mutual_window",
                value: format!("{side}"),
                reason: "needs mutual matching with k = 1: it makes the mutual check local",
            });
        }
    }
    Ok(())
}

/// The verified poses so far, surest first, each with its (pass, instance of that pass).
struct Accepted {
    rows: Vec<RefinedPose>,
    tags: Vec<(usize, usize)>,
}

impl Accepted {
    fn from_pass(refined: Refined, pass: usize) -> Self {
        let tags = refined.poses.iter().map(|r| (pass, r.origin)).collect();
        Self {
            rows: refined.poses,
            tags,
        }
    }

    fn len(&self) -> usize {
        self.rows.len()
    }

    fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The poses, as stages take them ([`handed`]).
    fn poses(&self) -> Vec<RigidTransform> {
        self.rows.iter().map(|r| handed(r.pose)).collect()
    }

    fn take(&self, rows: &[usize]) -> Self {
        Self {
            rows: rows.iter().map(|&i| self.rows[i].clone()).collect(),
            tags: rows.iter().map(|&i| self.tags[i]).collect(),
        }
    }

    /// `self` then `other`, in that order.
    fn merged_unsorted(mut self, other: Self) -> Self {
        self.rows.extend(other.rows);
        self.tags.extend(other.tags);
        self
    }

    /// Both lists as one, surest first (`self` first among equals).
    fn merged(self, other: Self) -> Self {
        let mut both = self.merged_unsorted(other);
        both.sort();
        both
    }

    /// Stable sort by decreasing confidence.
    fn sort(&mut self) {
        let mut order: Vec<usize> = (0..self.rows.len()).collect();
        order.sort_by(|&a, &b| self.rows[b].confidence.total_cmp(&self.rows[a].confidence));
        *self = self.take(&order);
    }

    /// The pool's poses as verification judged them together (`judged.origin` indexes the
    /// pool).
    fn reverified(self, judged: Refined) -> Self {
        let tags = judged.poses.iter().map(|r| self.tags[r.origin]).collect();
        Self {
            rows: judged.poses,
            tags,
        }
    }
}

/// The ranked and windowed mutual checks look at this many of a model point's nearest scan
/// points (the ranked one at `heap_rank` if more): a heap shows a few dozen copies, so a
/// model point's true match on each lies among its few dozen nearest; more cost time and
/// found no more copies on the validation bins (128: recall of half-visible copies 0.362 vs
/// 0.356).
const WINDOW_CANDIDATES: usize = 64;

/// The Euclidean distance between two points.
fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The poses of a registration's instances, in order, as stages take poses.
fn poses_of(registration: &Registration) -> Vec<RigidTransform> {
    registration
        .instances
        .iter()
        .map(|i| handed(i.pose))
        .collect()
}

/// A pose as a stage takes it: its rotation block replaced by the nearest rotation, as for a
/// pose given as a 4 x 4 matrix. Why every pose a stage receives goes through this: the
/// Python pipeline hands its poses to the core as matrices, and ICP on flat faces turns a
/// difference in the last bit into another settled pose; the same step here keeps the two
/// paths' poses identical.
fn handed(pose: RigidTransform) -> RigidTransform {
    RigidTransform {
        rotation: nearest_rotation(&pose.rotation).unwrap_or(pose.rotation),
        ..pose
    }
}

/// The downsampled scan without its strays (fewer than `stray_neighbours` others within 2
/// voxels) when they are more than `max_stray_share` of it; an error when every point is one.
fn without_strays(points: Vec<[f64; 3]>, voxel: f64, scene: &SceneRules) -> Result<Vec<[f64; 3]>> {
    let stray = isolated_points(&points, 2.0 * voxel, scene.stray_neighbours)?;
    let n = stray.iter().filter(|&&s| s).count();
    if n == points.len() {
        return Err(Error::TooFewPoints {
            what: "scan points with a surface around them (pass a denser scan or a larger voxel)",
            got: 0,
            min: 1,
        });
    }
    if n as f64 / points.len() as f64 > scene.max_stray_share {
        return Ok(points
            .into_iter()
            .zip(stray)
            .filter_map(|(p, s)| (!s).then_some(p))
            .collect());
    }
    Ok(points)
}
