//! [`register_point_clouds`]: a model and a scan in, the pose of every copy out, as named
//! stages over one description of each cloud and one index of the scan: voxel, description,
//! matching, proposals (the correspondence stage), verification, peeling, ranking.
//!
//! This is the training-free path with a known sensor position or none: the Python package's
//! `register_point_clouds` with `heap=False` and `flips=False` runs the same stages with the
//! same arithmetic, and adds the learned embedding, point pair voting in heaps, turned
//! alternatives and the estimation of an unknown viewpoint.

use crate::config::Config;
use crate::correspondences::{Correspondences, Features};
use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::matching::{match_features_given, nearest_sources, MatchingConfig, NearestSources};
use crate::pipeline::{register, Registration};
use crate::pointcloud::{
    check_points, check_positive, describe, isolated_points, voxel_downsample, DescribeParams,
    Described, FpfhVariant, Orientation, RefineContext, RefineParams, Refined, RefinedPose,
};

use super::peeling::{not_duplicates, unexplained};
use super::ranking::{fit_tightness, loose_poses, pose_stability, stability_factor};
use super::voxel::default_voxel_size;
use super::SceneRules;

/// How [`register_point_clouds`] runs; [`SceneOptions::default`] is the Python package's
/// defaults for this path.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneOptions {
    /// The voxel the clouds are described at; `None`: [`default_voxel_size`].
    pub voxel_size: Option<f64>,
    /// The position of the sensor that took the scan (one view): the scan's normals face it,
    /// and verification judges each pose by what the sensor could see of it. `None`: the
    /// normals face the origin and poses are judged by the share of the model explained.
    pub viewpoint: Option<[f64; 3]>,
    /// Matching of every pass: the `top_k` most similar mutual matches, `n_samples` of them
    /// drawn at random.
    pub matching: MatchingConfig,
    /// The correspondence stage's config, in the clouds' units; `None`: [`cloud_config`].
    pub config: Option<Config>,
    /// Further passes over the scan points no accepted copy explains (peeling).
    pub peel: bool,
    /// Seeds the sampling of matches and the correspondence stage (pass `r` uses `seed + r`).
    pub seed: u64,
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
            peel: true,
            seed: 0,
            scene: SceneRules::default(),
        }
    }
}

/// One copy of the model in the scan, refined and verified.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// `T_target_source` after ICP.
    pub pose: RigidTransform,
    /// The pass of the correspondence stage that proposed it (0: the whole scan).
    pub pass_index: usize,
    /// Its instance in that pass's [`Registration`].
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
}

/// One pass of the correspondence stage.
#[derive(Debug, Clone)]
pub struct Pass {
    /// Rows `(model point | scan point)` of the downsampled clouds.
    pub correspondences: Correspondences,
    /// The correspondence stage's result over them.
    pub registration: Registration,
    /// Indices into [`SceneRegistration::target`]'s points of the scan points matched.
    pub scan_points: Vec<usize>,
    /// Copies this pass added to the accepted ones.
    pub added: usize,
}

/// The result of [`register_point_clouds`].
#[derive(Debug, Clone)]
pub struct SceneRegistration {
    /// The copies found, surest first.
    pub candidates: Vec<Candidate>,
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
}

/// The correspondence stage's config for clouds described at `voxel`, before peeling's
/// cluster level: verification on the clouds judges every proposal far better than a count of
/// correspondences can, so the stage proposes every plausible group (`tau_s` 0.8, `tau_n` 1,
/// clusters of 3, no a-contrario test), with sigma_d at 3 voxels (a right match lands within
/// about a voxel of the true point on each side) and inliers within 2 voxels.
pub fn cloud_config(voxel: f64, cluster_level: Option<f64>) -> Config {
    let base = Config {
        tau_s: 0.8,
        tau_n: 1,
        min_cluster_size: 3,
        max_nfa: None,
        cluster_level,
        ..Config::default()
    };
    let defaults = Config::default();
    let mut scaled = base.scaled(3.0 * voxel / base.sigma_d);
    let per_unit = 2.0 * voxel / defaults.inlier_threshold;
    scaled.inlier_threshold = base.inlier_threshold * per_unit;
    scaled
}

/// Finds every copy of `model` (a complete object) in `scan`; see the module documentation.
/// Parallel on the current rayon pool; the result depends only on the inputs and the seed.
pub fn register_point_clouds(
    model: &[[f64; 3]],
    scan: &[[f64; 3]],
    options: &SceneOptions,
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
        None => default_voxel_size(model, scan, &options.scene),
    };
    check_positive("voxel_size (the model has no extent: give one)", voxel)?;
    let mut run = Run::new(model, scan, voxel, options)?;
    let config = match &options.config {
        Some(c) => c.clone(),
        None => cloud_config(
            voxel,
            options.peel.then_some(options.scene.peel_cluster_level),
        ),
    };
    let everything: Vec<usize> = (0..run.target.points.len()).collect();
    let corr = run
        .matched(&everything, options.seed)?
        .map_err(|got| Error::TooFewCorrespondences { got, min: 3 })?;
    let registration = register(&corr, None, &config, options.seed)?;
    let first = run.refine(&poses_of(&registration), &run.rules.clone())?;
    let mut accepted = Accepted::from_pass(first, 0);
    let added = accepted.len();
    run.passes.push(Pass {
        correspondences: corr,
        registration,
        scan_points: everything,
        added,
    });
    if options.peel && !accepted.is_empty() {
        accepted = run.peel(accepted, &config)?;
    }
    let candidates = run.ranked(accepted)?;
    Ok(SceneRegistration {
        candidates,
        passes: run.passes,
        by_visibility: run.by_visibility,
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
    context: RefineContext,
    rules: RefineParams,
    voxel: f64,
    options: &'o SceneOptions,
    passes: Vec<Pass>,
    by_visibility: bool,
}

impl<'o> Run<'o> {
    /// The clouds described, the scan's nearest model descriptors found once for every pass,
    /// and the refinement context (the one index of the scan every later stage uses).
    fn new(
        model: &[[f64; 3]],
        scan: &[[f64; 3]],
        voxel: f64,
        options: &'o SceneOptions,
    ) -> Result<Self> {
        let n = model.len() as f64;
        let mut sum = [0.0; 3];
        for p in model {
            for (s, v) in sum.iter_mut().zip(p) {
                *s += v;
            }
        }
        let centre = sum.map(|s| s / n);
        let source = describe(
            model,
            None,
            &DescribeParams {
                orientation: Orientation::AwayFrom(centre),
                ..DescribeParams::for_voxel(voxel)
            },
        )?;
        let points = without_strays(voxel_downsample(scan, voxel)?, voxel, &options.scene)?;
        let target = describe(
            &points,
            None,
            &DescribeParams {
                voxel_size: None,
                normal_radius: 2.0 * voxel,
                normal_max_nn: 30,
                feature_radius: 5.0 * voxel,
                feature_max_nn: 100,
                variant: FpfhVariant::Open3d,
                orientation: Orientation::Towards(options.viewpoint.unwrap_or([0.0; 3])),
            },
        )?;
        let nearest = nearest_sources(&source.descriptors, &target.descriptors, 1)?;
        let rules = RefineParams::for_voxel(voxel);
        let context = RefineContext::new(
            &source.points,
            &target.points,
            Some(&target.normals),
            options.viewpoint,
            &rules,
        )?;
        Ok(Self {
            source,
            target,
            nearest,
            context,
            rules,
            voxel,
            options,
            passes: Vec::new(),
            by_visibility: false,
        })
    }

    /// Correspondences between the model and the scan points `rows` (mutual, sampled with
    /// `seed`), or how many survived when fewer than 3 (too few for a pose).
    fn matched(
        &self,
        rows: &[usize],
        seed: u64,
    ) -> Result<std::result::Result<Correspondences, usize>> {
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
        let m = match_features_given(
            &self.source.descriptors,
            &subset,
            &nearest,
            &self.options.matching,
            seed,
        )?;
        let src: Vec<[f64; 3]> = m.source.iter().map(|&i| self.source.points[i]).collect();
        let used: Vec<usize> = m.target.iter().map(|&j| rows[j]).collect();
        let tgt: Vec<[f64; 3]> = used.iter().map(|&j| self.target.points[j]).collect();
        if src.len() < 3 {
            return Ok(Err(src.len()));
        }
        Ok(Ok(Correspondences::new(&src, &tgt)?))
    }

    fn refine(&mut self, poses: &[RigidTransform], params: &RefineParams) -> Result<Refined> {
        let refined = self.context.refine(poses, params)?;
        self.by_visibility = refined.by_visibility;
        Ok(refined)
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

    /// Peeling rounds until one adds no copy (or `max_peel_rounds`).
    fn peel(&mut self, mut accepted: Accepted, config: &Config) -> Result<Accepted> {
        let mut free = self.unexplained(&accepted)?;
        for round in 1..=self.options.scene.max_peel_rounds {
            let rows: Vec<usize> = (0..free.len()).filter(|&i| free[i]).collect();
            if rows.len() < 3 {
                break;
            }
            let seed = self.options.seed.wrapping_add(round as u64);
            let Ok(corr) = self.matched(&rows, seed)? else {
                break;
            };
            let registration = register(&corr, None, config, seed)?;
            let every = RefineParams {
                max_shared: 1.0,
                ..self.rules.clone()
            };
            let new = self.refine(&poses_of(&registration), &every)?;
            if !new.poses.is_empty() && new.by_visibility {
                let new = Accepted::from_pass(new, round);
                let mut taken: Vec<bool> = free.iter().map(|f| !f).collect();
                let radius = 1.5 * self.voxel;
                let max_shared = self.rules.max_shared;
                let index = self.context.index();
                let keep = not_duplicates(
                    index,
                    &self.source.points,
                    &new.poses(),
                    radius,
                    max_shared,
                    &mut taken,
                )?;
                let kept = new.take(&keep);
                let explained = self.unexplained(&kept)?;
                for (f, e) in free.iter_mut().zip(explained) {
                    *f &= e;
                }
                accepted = accepted.merged(kept);
            } else if !new.poses.is_empty() {
                let new = Accepted::from_pass(new, round);
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
                correspondences: corr,
                registration,
                scan_points: rows,
                added,
            });
            if added == 0 {
                break;
            }
        }
        Ok(accepted)
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
        Ok(accepted
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
            })
            .collect())
    }
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

    fn poses(&self) -> Vec<RigidTransform> {
        self.rows.iter().map(|r| r.pose).collect()
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

/// The poses of a registration's instances, in order.
fn poses_of(registration: &Registration) -> Vec<RigidTransform> {
    registration.instances.iter().map(|i| i.pose).collect()
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
