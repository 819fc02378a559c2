//! Turned alternatives of verified poses: a part close to a symmetry is often posed turned,
//! and the few discrete hypotheses (half turns about the model's principal axes, quarter turns
//! about those that leave most of it in place, and the scene's own alternatives) are refined
//! and scored like the pose, the one the scan supports best kept ([`resolve_flips`]).
//!
//! Why: ICP settles a pose of a near-symmetric part (a bathtub end for end, a box with a block
//! on one corner a quarter turn about its vertical axis) on the copy, and it passes
//! verification, yet its rotation is wrong. The turned poses are few, so each is tried.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::peeling::explained_scan_points;
use super::{mean_point, SceneRules};
use crate::config::Declared;
use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::pointcloud::{
    check_points, check_positive, nearest_rotation, PointIndex, RefineContext, RefineParams,
    Refined, RefinedPose,
};
use crate::symmetry::Symmetry;

/// A component of a principal axis farther than this from zero can set the axis' sign. Why
/// not the largest component: an axis at 45 degrees between two coordinate axes (common in
/// models drawn aligned to them) has two equal largest components, and rounding would pick
/// either; a component that should be zero is a few ulps off it, far below this.
pub const AXIS_SIGN_TOLERANCE: f64 = 1e-6;

/// `(F, 4, 4)` half turns of the model about its principal axes through its centroid that
/// verification can tell from the model itself: at least `min_change` of the turned model
/// lies farther than the fitness radius (1.5 voxels) from it; `F <= 3`, by ascending variance
/// of the axis.
pub fn flip_turns(model: &[[f64; 3]], voxel: f64, min_change: f64) -> Result<Vec<RigidTransform>> {
    check_share("min_change", min_change)?;
    Ok(Shape::new(model, fit_radius(voxel)?)?.half_turns(min_change))
}

/// Quarter turns of the model, either way about its principal axes through its centroid
/// (ascending variance, `+90` then `-90` degrees about each axis, whose sign is canonical:
/// its first component off zero, [`AXIS_SIGN_TOLERANCE`], positive), that move at least
/// `min_change` and at most `max_change` of it farther than the fitness radius from it
/// (near-symmetries); at most 6.
pub fn quarter_turns(
    model: &[[f64; 3]],
    voxel: f64,
    min_change: f64,
    max_change: f64,
) -> Result<Vec<RigidTransform>> {
    check_share("min_change", min_change)?;
    check_share("max_change", max_change)?;
    Ok(Shape::new(model, fit_radius(voxel)?)?.quarter_turns(min_change, max_change))
}

/// Verified `poses` (of the context's model in its scan, as [`RefineContext::refine`] returns
/// them) with each replaced by a turned alternative the scan supports better, surest first,
/// and for each the row of `poses.poses` it came from.
///
/// The hypotheses: each pose times a half turn about a principal axis of the model
/// ([`flip_turns`]), a quarter turn either way about those that leave most of the model in
/// place ([`quarter_turns`]), and the scene's own alternatives `rotations` (3 x 3 turns of the
/// model about its centroid, e.g. the duplicates peeling dropped relative to the copy they lie
/// on; grouped within `scene_turn_deg`, the `max_scene_turns` largest groups tried). Each is
/// refined by ICP and scored with `params` keeping everything (`params`' lengths must be the
/// context's). A turned pose that explains at least as much of the whole model (`fitness`)
/// replaces the pose when
///
/// * it is a half turn and surer (`confidence`), or
/// * it would itself pass verification (`params.min_visible_fitness`,
///   `params.max_contradiction`, when judged by the sensor) and explains far more of the
///   points that tell the two apart: the model points each puts where the other has no
///   surface (`flip_evidence_ratio`, `flip_evidence_sigmas`).
///
/// A pose that stays is one of several hypotheses when some of its turns pass the same
/// conditions and the points that tell them apart decide neither way: its confidence is
/// divided by one plus their number. A turned pose that lands on another pose's copy (it
/// shares more than `params.max_shared` of the scan points it explains with the other poses,
/// and more than the pose did) is put back. Turns mapping the model onto itself are not tried
/// (`min_flip_change`; `min_flip_change_by_fitness` when the poses were not judged by the
/// sensor). The refinement runs in parallel on the current rayon pool; the result does not
/// depend on the number of threads. The returned poses keep `poses`' origins and rejections.
///
/// Errors: `rules` or `params` out of range, lengths other than the context's, a rotation that
/// is not one up to rounding ([`crate::pointcloud::MAX_ROTATION_DEVIATION`]).
pub fn resolve_flips(
    context: &RefineContext,
    params: &RefineParams,
    poses: &Refined,
    rotations: &[Matrix3<f64>],
    rules: &SceneRules,
) -> Result<(Refined, Vec<usize>)> {
    resolve_flips_with_symmetry(context, params, poses, rotations, rules, &Symmetry::none())
}

/// [`resolve_flips`] for a model with declared symmetries: a turn within `scene_turn_deg` of
/// a symmetry, or of a symmetry composed with a turn already tried, is not a distinct
/// alternative and is not tried (the pose and that turn place the same part).
pub fn resolve_flips_with_symmetry(
    context: &RefineContext,
    params: &RefineParams,
    poses: &Refined,
    rotations: &[Matrix3<f64>],
    rules: &SceneRules,
    symmetry: &Symmetry,
) -> Result<(Refined, Vec<usize>)> {
    check_rules(rules)?;
    let rotations = checked_rotations(rotations)?;
    check_positive("fit_radius", params.fit_radius)?;
    let shape = Shape::new(context.source(), params.fit_radius)?;
    let (turns, half) = shape.turns(poses.by_visibility, &rotations, rules);
    let (turns, half) = distinct_turns(turns, half, symmetry, rules.scene_turn_deg);
    let n = poses.poses.len();
    if n == 0 || turns.is_empty() {
        return Ok((poses.clone(), (0..n).collect()));
    }
    let candidates: Vec<RigidTransform> = poses
        .poses
        .iter()
        .flat_map(|p| turns.iter().map(move |turn| composed(&p.pose, turn)))
        .collect();
    let alt = context.refine(&candidates, &keep_all(params))?;
    let evidence = Evidence {
        shape: &shape,
        context,
        rules,
    };
    let chosen = Choice {
        poses: &poses.poses,
        by_visibility: poses.by_visibility,
        alt: &alt.poses,
        turns: turns.len(),
        half,
        params,
    };
    let (mut rows, turned) = chosen.with_better_turns(&evidence);
    undo_turns_onto_other_copies(
        &poses.poses,
        &mut rows,
        &turned,
        &evidence,
        params.max_shared,
    );
    let mut order: Vec<usize> = (0..n).collect();
    // Stable: ties keep the input's order.
    order.sort_by(|&a, &b| rows[b].confidence.total_cmp(&rows[a].confidence));
    let resolved = Refined {
        poses: order.iter().map(|&i| rows[i].clone()).collect(),
        by_visibility: poses.by_visibility,
        rejected: poses.rejected.clone(),
        sliding: poses.sliding.clone(),
    };
    Ok((resolved, order))
}

/// `turns` (the first `half` of them half turns) without those within `near` degrees of a
/// symmetry, or of one composed with a turn kept before them, and the half turns left.
fn distinct_turns(
    turns: Vec<RigidTransform>,
    half: usize,
    symmetry: &Symmetry,
    near: f64,
) -> (Vec<RigidTransform>, usize) {
    if symmetry.is_trivial() {
        return (turns, half);
    }
    let mut kept: Vec<RigidTransform> = Vec::with_capacity(turns.len());
    let mut kept_half = 0;
    for (i, turn) in turns.into_iter().enumerate() {
        let same =
            |k: &Matrix3<f64>| symmetry.angle_to_deg(&(k.transpose() * turn.rotation)) < near;
        if same(&Matrix3::identity()) || kept.iter().any(|k| same(&k.rotation)) {
            continue;
        }
        kept_half += usize::from(i < half);
        kept.push(turn);
    }
    (kept, kept_half)
}

/// `params` scoring only, with ICP ([`RefineParams::keeping_all`]).
fn keep_all(params: &RefineParams) -> RefineParams {
    RefineParams {
        icp: true,
        ..params.keeping_all()
    }
}

/// `pose` after `turn` (`T_pose @ T_turn`), its rotation made exactly orthonormal as the
/// verification's input poses are.
fn composed(pose: &RigidTransform, turn: &RigidTransform) -> RigidTransform {
    let rotation = pose.rotation * turn.rotation;
    RigidTransform {
        rotation: nearest_rotation(&rotation).unwrap_or(rotation),
        translation: pose.rotation * turn.translation + pose.translation,
    }
}

/// The fitness radius (1.5 voxels) at `voxel`.
fn fit_radius(voxel: f64) -> Result<f64> {
    check_positive("voxel_size", voxel)?;
    Ok(RefineParams::for_voxel(voxel).fit_radius)
}

fn check_share(name: &'static str, value: f64) -> Result<()> {
    if (0.0..=1.0).contains(&value) {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name,
            value: value.to_string(),
            reason: "must lie in [0, 1]",
        })
    }
}

fn check_rules(rules: &SceneRules) -> Result<()> {
    match Declared::out_of_range(rules) {
        None => Ok(()),
        Some((field, value)) => Err(Error::InvalidParameter {
            name: field.name,
            value: value.to_string(),
            reason: "outside its declared range (see SceneRules::FIELDS)",
        }),
    }
}

/// Each of `rotations` made exactly orthonormal; an error for one that is not finite or not a
/// rotation up to rounding.
fn checked_rotations(rotations: &[Matrix3<f64>]) -> Result<Vec<Matrix3<f64>>> {
    rotations
        .iter()
        .enumerate()
        .map(|(row, m)| {
            if !m.iter().all(|v| v.is_finite()) {
                return Err(Error::NonFinite {
                    what: "rotations",
                    row,
                });
            }
            nearest_rotation(m).map_err(|deviation| Error::InvalidParameter {
                name: "rotations",
                value: format!("row {row} with ||R^T R - I|| = {deviation:.2e}"),
                reason: "must be a rotation up to rounding, with a positive determinant",
            })
        })
        .collect()
}

/// The angle between two rotations in degrees, `acos((tr(a^T b) - 1) / 2)`.
fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let mut trace = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            trace += a[(i, j)] * b[(i, j)];
        }
    }
    ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// A model's points, centroid, principal axes and index, to turn it and measure how much a
/// turn moves.
struct Shape<'a> {
    src: &'a [[f64; 3]],
    radius: f64,
    centre: Vector3<f64>,
    /// Ascending variance, each with its first component off zero positive.
    axes: [Vector3<f64>; 3],
    index: PointIndex,
}

impl<'a> Shape<'a> {
    fn new(src: &'a [[f64; 3]], radius: f64) -> Result<Self> {
        check_points(src, "model points", 1)?;
        check_positive("radius", radius)?;
        let centre = Vector3::from(mean_point(src));
        Ok(Self {
            src,
            radius,
            centre,
            axes: principal_axes(src, &centre),
            index: PointIndex::with_cells(src, radius)?,
        })
    }

    fn turns(
        &self,
        by_visibility: bool,
        rotations: &[Matrix3<f64>],
        rules: &SceneRules,
    ) -> (Vec<RigidTransform>, usize) {
        // Judged by the share of the model alone, a small change is not told from noise.
        let min_change = if by_visibility {
            rules.min_flip_change
        } else {
            rules.min_flip_change_by_fitness
        };
        let mut turns = self.half_turns(min_change);
        let half = turns.len();
        turns.extend(self.quarter_turns(min_change, rules.max_quarter_turn_change));
        let scene = self.scene_turns(rotations, &turns, min_change, rules);
        turns.extend(scene);
        (turns, half)
    }

    fn half_turns(&self, min_change: f64) -> Vec<RigidTransform> {
        let rotations: Vec<Matrix3<f64>> = self
            .axes
            .iter()
            .map(|a| 2.0 * a * a.transpose() - Matrix3::identity())
            .collect();
        self.kept(&rotations, min_change, 1.0)
    }

    fn quarter_turns(&self, min_change: f64, max_change: f64) -> Vec<RigidTransform> {
        let mut rotations = Vec::with_capacity(6);
        for a in &self.axes {
            let cross = a.cross_matrix();
            for way in [1.0, -1.0] {
                rotations.push(Matrix3::identity() + way * cross + cross * cross);
            }
        }
        self.kept(&rotations, min_change, max_change)
    }

    /// The turns from `rotations`: grouped within `scene_turn_deg` (each joins the first group
    /// whose first rotation is that near), those within it of the identity or of a turn
    /// already `tried` left out, the `max_scene_turns` largest groups' first rotations kept
    /// (ties: the first found), each moving at least `min_change` of the model.
    fn scene_turns(
        &self,
        rotations: &[Matrix3<f64>],
        tried: &[RigidTransform],
        min_change: f64,
        rules: &SceneRules,
    ) -> Vec<RigidTransform> {
        let near = rules.scene_turn_deg;
        let known: Vec<Matrix3<f64>> = std::iter::once(Matrix3::identity())
            .chain(tried.iter().map(|t| t.rotation))
            .collect();
        let mut groups: Vec<(Matrix3<f64>, usize)> = Vec::new();
        for rot in rotations {
            if known.iter().any(|k| angle_deg(k, rot) < near) {
                continue;
            }
            match groups
                .iter_mut()
                .find(|(first, _)| angle_deg(first, rot) < near)
            {
                Some((_, size)) => *size += 1,
                None => groups.push((*rot, 1)),
            }
        }
        groups.sort_by_key(|g| std::cmp::Reverse(g.1)); // stable: ties keep the order found
        let firsts: Vec<Matrix3<f64>> = groups
            .iter()
            .take(rules.max_scene_turns)
            .map(|g| g.0)
            .collect();
        self.kept(&firsts, min_change, 1.0)
    }

    /// The rigid motions rotating by `rotations` about the centroid that move from
    /// `min_change` to `max_change` of the model farther than the radius from it.
    fn kept(
        &self,
        rotations: &[Matrix3<f64>],
        min_change: f64,
        max_change: f64,
    ) -> Vec<RigidTransform> {
        let n = self.src.len() as f64;
        rotations
            .iter()
            .map(|rot| RigidTransform {
                rotation: *rot,
                translation: self.centre - rot * self.centre,
            })
            .filter(|turn| {
                let moved = self
                    .src
                    .par_iter()
                    .filter(|&&p| self.index.nearest(&turn.apply(p)).1.sqrt() > self.radius)
                    .count();
                let share = moved as f64 / n;
                min_change <= share && share <= max_change
            })
            .collect()
    }

    /// Whether a model point lies strictly within the radius of `point`.
    fn near(&self, point: &[f64; 3]) -> bool {
        self.index.any_within(point, self.radius)
    }
}

/// The eigenvectors of the points' covariance about `centre`, by ascending eigenvalue (ties:
/// the solver's order), each signed so that its first component off zero is positive.
fn principal_axes(src: &[[f64; 3]], centre: &Vector3<f64>) -> [Vector3<f64>; 3] {
    let mut cov = Matrix3::zeros();
    for p in src {
        let d = Vector3::from(*p) - centre;
        cov += d * d.transpose();
    }
    cov /= (src.len().max(2) - 1) as f64;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    order.map(|k| canonical_sign(eig.eigenvectors.column(k).into_owned()))
}

/// `axis` or its opposite, whichever has its first component off zero
/// ([`AXIS_SIGN_TOLERANCE`]) positive.
fn canonical_sign(axis: Vector3<f64>) -> Vector3<f64> {
    match axis.iter().find(|v| v.abs() > AXIS_SIGN_TOLERANCE) {
        Some(&v) if v < 0.0 => -axis,
        _ => axis,
    }
}

/// Which of two poses of one copy the points that tell them apart support, counted on the
/// context's scan index.
struct Evidence<'a> {
    shape: &'a Shape<'a>,
    context: &'a RefineContext,
    rules: &'a SceneRules,
}

impl Evidence<'_> {
    /// The scan points the model explains at `pose` (ascending).
    fn explained(&self, pose: &RigidTransform) -> Vec<usize> {
        let (index, src) = (self.context.index(), self.context.source());
        explained_scan_points(index, src, pose, self.shape.radius)
    }

    /// How many of the points that tell `first` from `second` the scan explains for each:
    /// the model points `first` puts where `second` has no surface, and the other way round.
    fn hits(&self, first: &RigidTransform, second: &RigidTransform) -> (usize, usize) {
        // second = first * rel, in the model's frame.
        let rot = first.rotation.transpose() * second.rotation;
        let shift = first.rotation.transpose() * (second.translation - first.translation);
        let shape = self.shape;
        let scan = self.context.index();
        let count = |pose: &RigidTransform, off: &(dyn Fn(Vector3<f64>) -> Vector3<f64> + Sync)| {
            shape
                .src
                .par_iter()
                .filter(|&&p| {
                    !shape.near(&off(Vector3::from(p)).into())
                        && scan.any_within(&pose.apply(p), shape.radius)
                })
                .count()
        };
        // The first pose's own points lie off the model as the second poses it (rel^-1 p off
        // the model); the second's, rel p off the model.
        let own = count(first, &|p| rot.transpose() * (p - shift));
        let other = count(second, &|p| rot * p + shift);
        (own, other)
    }

    /// Whether `more` explained points that tell two poses apart decide against `fewer`.
    fn decisive(&self, more: usize, fewer: usize) -> bool {
        let (more, fewer) = (more as f64, fewer as f64);
        more > self.rules.flip_evidence_ratio * fewer
            && more - fewer > self.rules.flip_evidence_sigmas * (more + fewer).sqrt()
    }
}

/// What [`resolve_flips`] chooses among: the poses, their refined turns (`turns` per pose,
/// pose-major, the first `half` half turns; by `origin`, a candidate missing cannot win) and
/// the verification's rules.
struct Choice<'a> {
    poses: &'a [RefinedPose],
    by_visibility: bool,
    alt: &'a [RefinedPose],
    turns: usize,
    half: usize,
    params: &'a RefineParams,
}

impl Choice<'_> {
    /// The poses, each taken from its best alternative by [`resolve_flips`]' rule (the surest
    /// half turn that is surer, else the turn the points that tell it from the pose favour
    /// most decisively), and the rows replaced. A pose no turn replaces has its confidence
    /// divided by one plus the number of its eligible turns those points do not rule out.
    fn with_better_turns(&self, evidence: &Evidence) -> (Vec<RefinedPose>, Vec<usize>) {
        let mut rows = self.poses.to_vec();
        let mut turned = Vec::new();
        if self.alt.is_empty() {
            return (rows, turned);
        }
        let mut row_of = vec![None; self.poses.len() * self.turns];
        for (r, a) in self.alt.iter().enumerate() {
            if let Some(slot) = row_of.get_mut(a.origin) {
                *slot = Some(r);
            }
        }
        let p = self.params;
        for (i, pose) in self.poses.iter().enumerate() {
            let alts: Vec<Option<&RefinedPose>> = (0..self.turns)
                .map(|t| row_of[i * self.turns + t].map(|r| &self.alt[r]))
                .collect();
            // The alternative must explain as much of the model and pass verification itself.
            let as_much = |a: &RefinedPose| a.fitness >= pose.fitness;
            let eligible = |a: &RefinedPose| {
                as_much(a)
                    && (!self.by_visibility
                        || (a.visible_fitness >= p.min_visible_fitness
                            && a.contradiction <= p.max_contradiction))
            };
            let mut best: Option<(usize, f64)> = None;
            for (t, a) in alts.iter().enumerate().take(self.half) {
                if let Some(a) = a.filter(|a| a.confidence > pose.confidence && as_much(a)) {
                    if best.is_none_or(|(_, c)| a.confidence > c) {
                        best = Some((t, a.confidence));
                    }
                }
            }
            let t = match best {
                Some((t, _)) => t,
                None => {
                    let hits: Vec<(usize, (usize, usize))> = alts
                        .iter()
                        .enumerate()
                        .filter_map(|(t, a)| a.filter(|a| eligible(a)).map(|a| (t, a)))
                        .map(|(t, a)| (t, evidence.hits(&pose.pose, &a.pose)))
                        .collect();
                    let mut most: Option<(usize, usize)> = None;
                    for &(t, (own, other)) in &hits {
                        // Decisive: `other` exceeds `own` (the ratio is at least 1).
                        if evidence.decisive(other, own) {
                            let margin = other - own;
                            if most.is_none_or(|(_, m)| margin > m) {
                                most = Some((t, margin));
                            }
                        }
                    }
                    match most {
                        Some((t, _)) => t,
                        None => {
                            // The pose is one of as many hypotheses as the turns it cannot rule
                            // out.
                            let undecided = hits
                                .iter()
                                .filter(|(_, (own, other))| !evidence.decisive(*own, *other))
                                .count();
                            rows[i].confidence /= (1 + undecided) as f64;
                            continue;
                        }
                    }
                }
            };
            if let Some(a) = alts[t] {
                rows[i] = RefinedPose {
                    origin: pose.origin,
                    ..a.clone()
                };
                turned.push(i);
            }
        }
        (rows, turned)
    }
}

/// Puts back, in `rows`, each `turned` row whose turn carried it onto another pose's copy: its
/// turned pose shares more than `max_shared` of the scan points it explains with the other
/// poses, and more than the pose did. Such a turn is ICP settling on a neighbour, not an
/// alternative for this copy.
fn undo_turns_onto_other_copies(
    poses: &[RefinedPose],
    rows: &mut [RefinedPose],
    turned: &[usize],
    evidence: &Evidence,
    max_shared: f64,
) {
    if turned.is_empty() {
        return;
    }
    let mut explained: Vec<Vec<usize>> = rows
        .par_iter()
        .map(|r| evidence.explained(&r.pose))
        .collect();
    let mut count = vec![0i64; evidence.context.index().len()];
    for points in &explained {
        for &p in points {
            count[p] += 1;
        }
    }
    for &i in turned {
        for &p in &explained[i] {
            count[p] -= 1; // the other poses' points alone
        }
        let before = evidence.explained(&poses[i].pose);
        let shared = |points: &[usize]| {
            if points.is_empty() {
                1.0
            } else {
                points.iter().filter(|&&p| count[p] > 0).count() as f64 / points.len() as f64
            }
        };
        let (now, then) = (shared(&explained[i]), shared(&before));
        if now > max_shared && now > then {
            rows[i] = poses[i].clone();
            explained[i] = before;
        }
        for &p in &explained[i] {
            count[p] += 1;
        }
    }
}

#[cfg(test)]
#[path = "../tests/flips.rs"]
mod tests;
