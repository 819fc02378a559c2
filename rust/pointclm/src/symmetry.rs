//! Proper (rotation) symmetries of a model: declared ones, as BOP's `models_info` gives them,
//! or detected from the model's points; the group they generate; and one canonical pose among
//! the equivalent poses of a symmetric part.
//!
//! A symmetry `S` maps the model onto itself (`S model = model`), so a pose `T` and `T S`
//! place the same points: the registration cannot tell them apart, and neither should the
//! score. [`Symmetry`] holds the discrete group (closed under composition, identity first) and
//! the continuous axes; [`canonical_pose`] picks, among every `T S`, the one whose rotation is
//! nearest the identity, so that equivalent poses give one answer.
//!
//! Translations are in the model's own units (BOP writes millimetres: a model in metres needs
//! its symmetries' translations and axis offsets divided by 1000).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::pointcloud::icp::icp;
use crate::pointcloud::{
    check_points, check_positive, estimate_normals, nearest_rotation, Orientation, PointIndex,
};

/// At most this many discrete symmetries: the largest finite rotation group of a 3-D solid
/// (the icosahedron's) has 60, and a prism's dihedral group with 60 sides 120; more means the
/// declared transforms do not generate a finite group.
pub const MAX_GROUP: usize = 120;

/// Detection accepts a rotation when at least this share of the model's points land within
/// the tolerance of the model. Why not all: a point sampled at random lands farther than 3
/// spacings from its nearest neighbour with probability about 2^-9 on a flat surface, more at
/// edges; a feature that breaks the symmetry (a notch, a label) must cover more than 1 %.
pub const DETECT_MIN_SHARE: f64 = 0.99;

/// The default detection tolerance, in median nearest-neighbour spacings of the model: a
/// rotated point lies between the samples of the surface it lands on, farther than 3 median
/// spacings from all of them with probability about 2^-9 for random samples.
pub const SPACINGS_PER_TOLERANCE: f64 = 3.0;

/// A candidate turn that puts this share of the model within the tolerance of itself is
/// refined before it is judged ([`DETECT_MIN_SHARE`]).
const NEAR_SHARE: f64 = 0.7;

/// Rotations about an axis by `2 pi / n` are tried for `n` up to this.
pub const MAX_FOLD: usize = 12;

/// Detection tests at most this many of the model's points (evenly strided).
const DETECT_POINTS: usize = 4000;

/// Two eigenvalues of the model's covariance closer than this share of the larger count as
/// equal. Generous on purpose: an equal pair only adds rotations to try (every symmetry is
/// still verified on the points), while a pair taken for distinct would miss the turns about
/// the third axis.
const EQUAL_EIGENVALUES: f64 = 0.1;

/// Fractions of a full turn whose rotations all fit when the symmetry about an axis is
/// continuous: each is at least 14 degrees from every multiple of `1 / n`, `n <= MAX_FOLD`,
/// so no n-fold symmetry passes them all.
const CONTINUOUS_TURNS: [f64; 5] = [0.137, 0.291, 0.377, 0.613, 0.853];

/// An axis of continuous symmetry: every rotation about the line through `offset` along
/// `direction` (unit) maps the model onto itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axis {
    pub direction: Vector3<f64>,
    pub offset: Vector3<f64>,
}

impl Axis {
    /// The rotation by `angle` (radians) about the axis, as a rigid motion.
    pub fn turn(&self, angle: f64) -> RigidTransform {
        let rotation = axis_rotation(&self.direction, angle);
        RigidTransform {
            rotation,
            translation: self.offset - rotation * self.offset,
        }
    }
}

/// The proper symmetries of a model: a finite group of rigid motions (identity first) and
/// the axes of continuous symmetry (none; one; or several through one point, every rotation
/// about it). Built by [`Symmetry::new`] (declared) or [`detect_symmetries`].
#[derive(Debug, Clone, PartialEq)]
pub struct Symmetry {
    discrete: Vec<RigidTransform>,
    continuous: Vec<Axis>,
    /// With two or more axes: the point they meet at.
    centre: Option<Vector3<f64>>,
}

impl Default for Symmetry {
    fn default() -> Self {
        Self::none()
    }
}

impl Symmetry {
    /// No symmetry: the identity alone.
    pub fn none() -> Self {
        Self {
            discrete: vec![RigidTransform::identity()],
            continuous: Vec::new(),
            centre: None,
        }
    }

    /// The group `discrete` generates (the identity added, products closed, transforms whose
    /// rotations agree within 0.01 radians kept once), with the
    /// `continuous` axes (directions made unit).
    ///
    /// Errors: a non-finite value, a rotation that is not one up to rounding
    /// ([`crate::pointcloud::MAX_ROTATION_DEVIATION`], a positive determinant: reflections
    /// are not proper symmetries), an axis of zero direction, several axes that do not meet
    /// at one point, transforms generating more than [`MAX_GROUP`], or two with one rotation
    /// whose translations differ by more than 0.01 times one plus the largest translation.
    pub fn new(discrete: &[RigidTransform], continuous: &[Axis]) -> Result<Self> {
        let mut checked = Vec::with_capacity(discrete.len());
        for (row, s) in discrete.iter().enumerate() {
            let finite = s
                .rotation
                .iter()
                .chain(s.translation.iter())
                .all(|v| v.is_finite());
            if !finite {
                return Err(Error::NonFinite {
                    what: "symmetries_discrete",
                    row,
                });
            }
            let rotation =
                nearest_rotation(&s.rotation).map_err(|deviation| Error::InvalidParameter {
                    name: "symmetries_discrete",
                    value: format!("transform {row} with ||R^T R - I|| = {deviation:.2e}"),
                    reason: "its rotation must be a rotation up to rounding, with a positive \
                             determinant (a proper symmetry)",
                })?;
            checked.push(RigidTransform { rotation, ..*s });
        }
        let axes = checked_axes(continuous)?;
        let centre = common_point(&axes)?;
        let scale = checked
            .iter()
            .map(|s| s.translation.norm())
            .fold(0.0, f64::max);
        // 0.01, and products within 0.04 of an element taken for it: a detected group,
        // declared again, is closed to a degree or so at a coarse voxel; two symmetries of a
        // finite group of at most MAX_GROUP are 3 degrees (0.052) apart at least.
        let discrete = closed(&checked, 1e-2, Some(1e-2 * (1.0 + scale)), 4.0, Some)?;
        Ok(Self {
            discrete,
            continuous: axes,
            centre,
        })
    }

    /// [`Symmetry::new`] from homogeneous 4 x 4 matrices (row-major, `[R t; 0 0 0 1]`).
    pub fn from_matrices(discrete: &[[[f64; 4]; 4]], continuous: &[Axis]) -> Result<Self> {
        let mut transforms = Vec::with_capacity(discrete.len());
        for (row, m) in discrete.iter().enumerate() {
            if !m.iter().flatten().all(|v| v.is_finite()) {
                return Err(Error::NonFinite {
                    what: "symmetries_discrete",
                    row,
                });
            }
            if m[3] != [0.0, 0.0, 0.0, 1.0] {
                return Err(Error::InvalidParameter {
                    name: "symmetries_discrete",
                    value: format!("transform {row} with last row {:?}", m[3]),
                    reason: "a rigid transform's last row is 0 0 0 1",
                });
            }
            transforms.push(RigidTransform {
                rotation: Matrix3::from_fn(|r, c| m[r][c]),
                translation: Vector3::new(m[0][3], m[1][3], m[2][3]),
            });
        }
        Self::new(&transforms, continuous)
    }

    /// The discrete group, identity first.
    pub fn discrete(&self) -> &[RigidTransform] {
        &self.discrete
    }

    /// The axes of continuous symmetry.
    pub fn continuous(&self) -> &[Axis] {
        &self.continuous
    }

    /// Whether the identity is the only symmetry.
    pub fn is_trivial(&self) -> bool {
        self.discrete.len() == 1 && self.continuous.is_empty()
    }

    /// The number of symmetries, or `None` when they are infinitely many (continuous).
    pub fn order(&self) -> Option<usize> {
        self.continuous.is_empty().then_some(self.discrete.len())
    }

    /// The symmetry `S` maximising `tr(rotation R_S)` (the one bringing `rotation R_S` nearest
    /// the identity) and that trace; ties go to the first discrete element.
    fn best(&self, rotation: &Matrix3<f64>) -> (RigidTransform, f64) {
        if let Some(centre) = self.centre {
            // Every rotation about the centre: R_S = rotation^T, trace 3.
            let r = rotation.transpose();
            let s = RigidTransform {
                rotation: r,
                translation: centre - r * centre,
            };
            return (s, 3.0);
        }
        let mut best = (RigidTransform::identity(), f64::NEG_INFINITY);
        for d in &self.discrete {
            let candidate = match self.continuous.first() {
                None => (*d, (rotation * d.rotation).trace()),
                Some(axis) => {
                    // tr(R C(theta) R_D) = tr((R_D R) C(theta)), maximised in closed form.
                    let (angle, trace) = best_turn(&(d.rotation * rotation), &axis.direction);
                    (compose(&axis.turn(angle), d), trace)
                }
            };
            if candidate.1 > best.1 + 1e-12 {
                best = candidate;
            }
        }
        best
    }

    /// The smallest angle, in degrees, between `rotation` and the rotation of a symmetry.
    pub fn angle_to_deg(&self, rotation: &Matrix3<f64>) -> f64 {
        let (_, trace) = self.best(&rotation.transpose());
        ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// [`canonical_pose`] of `pose`.
    pub fn canonical(&self, pose: &RigidTransform) -> RigidTransform {
        canonical_pose(pose, self)
    }

    /// The largest distance a symmetry moves the model's centroid, or an axis lies from it:
    /// a symmetry in other units than the model's (BOP's millimetres for a model in metres)
    /// moves it far.
    pub fn centroid_shift(&self, model: &[[f64; 3]]) -> Result<f64> {
        check_points(model, "model points", 1)?;
        let c = mean(model);
        let moved = self
            .discrete
            .iter()
            .map(|s| (s.rotation * c + s.translation - c).norm());
        let off_axis = self.continuous.iter().map(|a| {
            let d = c - a.offset;
            (d - a.direction * a.direction.dot(&d)).norm()
        });
        Ok(moved.chain(off_axis).fold(0.0, f64::max))
    }
}

/// The symmetries [`crate::scene::SceneOptions::symmetry`] takes: declared, or detected on
/// the model as described (downsampled) at the run's voxel.
#[derive(Debug, Clone, PartialEq)]
pub enum ModelSymmetry {
    /// The caller's, in the model's units.
    Declared(Symmetry),
    /// [`detect_symmetries`] on the described model at its [`default_tolerance`] (about 3
    /// voxels: finer differences the registration cannot tell either).
    Detect,
}

/// A declared symmetry moving the model's centroid (or an axis lying from it) by more than
/// this share of the model's bounding diagonal is taken for one in other units.
pub const MAX_CENTROID_SHIFT: f64 = 0.1;

impl ModelSymmetry {
    /// The symmetry for `model` (the caller's points) described as `described`. Errors: a
    /// declared symmetry that moves the model's centroid by more than [`MAX_CENTROID_SHIFT`]
    /// of its bounding diagonal (other units, or another frame), and detection's.
    pub fn resolve(&self, model: &[[f64; 3]], described: &[[f64; 3]]) -> Result<Symmetry> {
        match self {
            Self::Detect => detect_symmetries(described, default_tolerance(described)?),
            Self::Declared(s) => {
                let shift = s.centroid_shift(model)?;
                let diagonal = bounding_diagonal(model);
                if shift > MAX_CENTROID_SHIFT * diagonal {
                    return Err(Error::InvalidParameter {
                        name: "symmetry",
                        value: format!(
                            "a symmetry moving the model's centroid by {shift:.4e} (the model's \
                             bounding diagonal is {diagonal:.4e})"
                        ),
                        reason: "a symmetry maps the model onto itself: give its translations \
                                 and axis offsets in the model's units and frame (BOP writes \
                                 millimetres)",
                    });
                }
                Ok(s.clone())
            }
        }
    }
}

fn bounding_diagonal(points: &[[f64; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}

/// Among the poses equivalent to `pose` (`pose S` for every symmetry `S`), the one whose
/// rotation is nearest the identity (largest trace; with a continuous axis the angle about it
/// in closed form; ties to the first discrete element). Equivalent poses give the same pose
/// up to rounding, except on the measure-zero set where two symmetries tie.
pub fn canonical_pose(pose: &RigidTransform, symmetry: &Symmetry) -> RigidTransform {
    let (s, _) = symmetry.best(&pose.rotation);
    compose(pose, &s)
}

/// The median distance from a model point to its nearest other point (over at most
/// 4000 of them, evenly strided), times [`SPACINGS_PER_TOLERANCE`]: [`detect_symmetries`]'
/// default tolerance.
pub fn default_tolerance(model: &[[f64; 3]]) -> Result<f64> {
    check_points(model, "model points", 3)?;
    let index = PointIndex::new(model)?;
    let mut spacing: Vec<f64> = strided(model, DETECT_POINTS)
        .par_iter()
        .map(|p| index.nearest_k(p, 2).get(1).map_or(0.0, |n| n.1.sqrt()))
        .collect();
    let median = crate::scene::median(&mut spacing);
    let tolerance = SPACINGS_PER_TOLERANCE * median;
    if tolerance.is_nan() || tolerance <= 0.0 {
        return Err(Error::InvalidParameter {
            name: "model points",
            value: format!("median spacing {median}"),
            reason: "half the points or more are duplicates: give a tolerance",
        });
    }
    Ok(tolerance)
}

/// The proper symmetries of `model` to `tolerance` (in the model's units; see
/// [`default_tolerance`]): the rotations that put at least [`DETECT_MIN_SHARE`] of its points
/// within `tolerance` of the model.
///
/// A symmetry keeps the covariance of the points, so its axis is a principal axis and, unless
/// it is a half turn, the other two variances are equal. Tried: half turns about each
/// principal axis of distinct variance; about an axis whose perpendicular variances are equal,
/// turns by `2 pi / n` (`n <= MAX_FOLD`) and a few turns that only a continuous symmetry
/// passes, and half turns about the perpendicular axes (every angle, at steps that move no
/// point more than half the tolerance); when all three are equal (a cube, a sphere), turns
/// about the directions to the nearest and farthest points too, and a few turns that only a
/// sphere passes. Each accepted turn is refined by a few ICP steps of the model onto itself and
/// checked again; the accepted turns generate the group.
///
/// Errors: fewer than 3 points, a non-finite one, a non-positive tolerance, or more than
/// [`MAX_GROUP`] symmetries at this tolerance (give a smaller one).
pub fn detect_symmetries(model: &[[f64; 3]], tolerance: f64) -> Result<Symmetry> {
    check_points(model, "model points", 3)?;
    check_positive("tolerance", tolerance)?;
    let shape = SelfFit::new(model, tolerance)?;
    let c = shape.centre;
    let (values, axes) = principal(model, &c);
    let equal = |a: f64, b: f64| (b - a).abs() <= EQUAL_EIGENVALUES * a.abs().max(b.abs());
    let (e01, e12) = (equal(values[0], values[1]), equal(values[1], values[2]));
    let mut found = Vec::new();
    let mut continuous = Vec::new();
    if e01 && e12 {
        if shape.about_every_axis() {
            let axes = [Vector3::x(), Vector3::y(), Vector3::z()].map(|direction| Axis {
                direction,
                offset: c,
            });
            return Symmetry::new(&[], &axes);
        }
        let mut candidates = axes.to_vec();
        candidates.extend(shape.extreme_directions());
        for a in &candidates {
            found.extend(shape.folds(a));
        }
    } else if e01 || e12 {
        let unique = if e01 { axes[2] } else { axes[0] };
        if shape.continuous_about(&unique) {
            let direction = shape.refined_axis(&unique);
            continuous.push(Axis {
                direction,
                offset: c,
            });
            found.extend(shape.flips_across(&direction, true));
        } else {
            found.extend(shape.folds(&unique));
            found.extend(shape.flips_across(&unique, false));
        }
    } else {
        for a in &axes {
            found.extend(shape.accepted(&[half_turn(a)]));
        }
    }
    // Turns closer than one that moves the farthest point by the tolerance cannot be told
    // apart; each product is refined onto the model, so that rounding does not add up.
    let apart = tolerance / shape.radius.max(tolerance);
    let settle = |s: RigidTransform| {
        let s = shape.refined(&s);
        shape.fits(&s).then_some(s)
    };
    let discrete =
        closed(&found, apart, None, 1.0, settle).map_err(|_| Error::InvalidParameter {
            name: "tolerance",
            value: tolerance.to_string(),
            reason: "the rotations that fit at this tolerance are not a finite group: give a \
                     smaller one",
        })?;
    Ok(Symmetry {
        discrete,
        continuous,
        centre: None,
    })
}

/// The model, its index and centroid, to try rotations of it onto itself.
struct SelfFit<'a> {
    points: &'a [[f64; 3]],
    /// Unit normals of `points` (within the tolerance), for point-to-plane ICP.
    normals: Vec<[f64; 3]>,
    index: PointIndex,
    tested: Vec<[f64; 3]>,
    centre: Vector3<f64>,
    /// The largest distance of a tested point from the centroid.
    radius: f64,
    tolerance: f64,
}

impl<'a> SelfFit<'a> {
    fn new(model: &'a [[f64; 3]], tolerance: f64) -> Result<Self> {
        let centre = mean(model);
        let tested = strided(model, DETECT_POINTS);
        let radius = tested
            .iter()
            .map(|p| (Vector3::from(*p) - centre).norm())
            .fold(0.0, f64::max);
        let index = PointIndex::new(model)?;
        let normals = estimate_normals(
            model,
            &index,
            tolerance,
            30,
            Orientation::AwayFrom(centre.into()),
        )?;
        Ok(Self {
            points: model,
            normals,
            index,
            tested,
            centre,
            radius,
            tolerance,
        })
    }

    /// The rigid motion rotating by `rotation` about the centroid.
    fn about_centre(&self, rotation: Matrix3<f64>) -> RigidTransform {
        RigidTransform {
            rotation,
            translation: self.centre - rotation * self.centre,
        }
    }

    /// The share of tested points `s` puts within the tolerance of the model.
    fn share(&self, s: &RigidTransform) -> f64 {
        let t2 = self.tolerance * self.tolerance;
        let near = self
            .tested
            .par_iter()
            .filter(|p| self.index.nearest(&s.apply(**p)).1 <= t2)
            .count();
        near as f64 / self.tested.len() as f64
    }

    fn fits(&self, s: &RigidTransform) -> bool {
        self.share(s) >= DETECT_MIN_SHARE
    }

    /// `s` after ICP of the model onto itself (pairs within the tolerance, then half of it).
    fn refined(&self, s: &RigidTransform) -> RigidTransform {
        // Point-to-plane: on the flat faces of a box point-to-point pairs barely pull along
        // the face, and its turns stayed degrees off.
        let radii = [self.tolerance, 0.5 * self.tolerance];
        icp(
            &self.tested,
            self.points,
            &self.normals,
            &self.index,
            *s,
            &radii,
            30,
            None,
        )
    }

    /// The rotations about the centroid by `rotations` that fit once refined. Why refine
    /// before the check: principal axes of sampled points are off by a degree or so, which
    /// moves the far points of a turn about them out of the tolerance; a turn that fits
    /// [`NEAR_SHARE`] of the points is refined first, and must then fit.
    fn accepted(&self, rotations: &[Matrix3<f64>]) -> Vec<RigidTransform> {
        rotations
            .iter()
            .map(|r| self.about_centre(*r))
            .filter(|s| self.share(s) >= NEAR_SHARE)
            .map(|s| self.refined(&s))
            .filter(|s| self.fits(s))
            .collect()
    }

    /// The turns by `2 pi / n` about `axis` through the centroid that fit, `2 <= n <= MAX_FOLD`.
    fn folds(&self, axis: &Vector3<f64>) -> Vec<RigidTransform> {
        let rotations: Vec<Matrix3<f64>> = (2..=MAX_FOLD)
            .map(|n| axis_rotation(axis, std::f64::consts::TAU / n as f64))
            .collect();
        self.accepted(&rotations)
    }

    /// Whether every rotation about `axis` through the centroid fits ([`CONTINUOUS_TURNS`]).
    fn continuous_about(&self, axis: &Vector3<f64>) -> bool {
        CONTINUOUS_TURNS
            .iter()
            .all(|f| self.fits(&self.about_centre(axis_rotation(axis, f * std::f64::consts::TAU))))
    }

    /// Whether every rotation about the centroid fits (a sphere): turns about axes off every
    /// principal direction by the continuous fractions.
    fn about_every_axis(&self) -> bool {
        let axes = [
            Vector3::new(1.0, 2.0, 3.0),
            Vector3::new(-3.0, 1.0, 2.0),
            Vector3::new(2.0, -3.0, 1.0),
        ];
        axes.iter().zip(CONTINUOUS_TURNS).all(|(a, f)| {
            let r = axis_rotation(&a.normalize(), f * std::f64::consts::TAU);
            self.fits(&self.about_centre(r))
        })
    }

    /// `axis` of continuous symmetry made more exact: the axis of a quarter turn about it
    /// after ICP (which may slide about the axis, not tilt it).
    fn refined_axis(&self, axis: &Vector3<f64>) -> Vector3<f64> {
        let turned =
            self.refined(&self.about_centre(axis_rotation(axis, 0.25 * std::f64::consts::TAU)));
        let r = turned.rotation;
        let w = Vector3::new(
            r[(2, 1)] - r[(1, 2)],
            r[(0, 2)] - r[(2, 0)],
            r[(1, 0)] - r[(0, 1)],
        );
        if w.norm() < 1e-9 || w.normalize().dot(axis).abs() < 0.99 {
            return *axis;
        }
        let w = w.normalize();
        if w.dot(axis) < 0.0 {
            -w
        } else {
            w
        }
    }

    /// Half turns about the axes perpendicular to `axis` through the centroid that fit: the
    /// angle about `axis` stepped so that no point moves more than half the tolerance, each
    /// run of fitting steps giving its best (least mean distance) step; only the first with
    /// `one` (a continuous axis makes them all equivalent).
    fn flips_across(&self, axis: &Vector3<f64>, one: bool) -> Vec<RigidTransform> {
        let start = perpendicular(axis);
        let other = axis.cross(&start);
        let step = (0.5 * self.tolerance / self.radius.max(self.tolerance)).min(0.1);
        let n = (std::f64::consts::PI / step).ceil() as usize;
        let flips: Vec<RigidTransform> = (0..n)
            .map(|k| {
                let phi = std::f64::consts::PI * k as f64 / n as f64;
                self.about_centre(half_turn(&(start * phi.cos() + other * phi.sin())))
            })
            .collect();
        let scored: Vec<(bool, f64)> = flips.iter().map(|s| self.scored(s)).collect();
        // Runs of fitting steps; a run through the last step continues at the first (phi = pi
        // is phi = 0).
        let first_miss = scored.iter().position(|s| !s.0);
        let Some(first_miss) = first_miss else {
            return self.accepted(&[flips[0].rotation]);
        };
        let mut runs: Vec<Vec<usize>> = Vec::new();
        let mut current: Vec<usize> = Vec::new();
        for k in (0..n).map(|i| (first_miss + i) % n) {
            if scored[k].0 {
                current.push(k);
            } else if !current.is_empty() {
                runs.push(std::mem::take(&mut current));
            }
        }
        if !current.is_empty() {
            runs.push(current);
        }
        runs.sort_by_key(|run| run.iter().copied().min());
        let take = if one { 1 } else { runs.len() };
        let best: Vec<Matrix3<f64>> = runs
            .iter()
            .take(take)
            .filter_map(|run| {
                run.iter()
                    .min_by(|&&a, &&b| scored[a].1.total_cmp(&scored[b].1))
                    .map(|&k| flips[k].rotation)
            })
            .collect();
        self.accepted(&best)
    }

    /// Whether `s` fits, and the mean distance of the tested points it moves to the model.
    fn scored(&self, s: &RigidTransform) -> (bool, f64) {
        let t2 = self.tolerance * self.tolerance;
        let (near, sum) = self
            .tested
            .par_iter()
            .map(|p| {
                let d2 = self.index.nearest(&s.apply(*p)).1;
                (usize::from(d2 <= t2), d2.sqrt())
            })
            .reduce(|| (0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        let n = self.tested.len() as f64;
        (near as f64 / n >= DETECT_MIN_SHARE, sum / n)
    }

    /// Directions from the centroid to the farthest and to the nearest tested points (2 % of
    /// them each), grouped within 15 degrees up to sign, at most 8 of each: a cube's corners
    /// and face centres, where a model with three equal variances has its axes.
    fn extreme_directions(&self) -> Vec<Vector3<f64>> {
        let mut by_distance: Vec<(f64, Vector3<f64>)> = self
            .tested
            .iter()
            .map(|p| Vector3::from(*p) - self.centre)
            .filter(|d| d.norm() > 0.0)
            .map(|d| (d.norm(), d.normalize()))
            .collect();
        by_distance.sort_by(|a, b| a.0.total_cmp(&b.0));
        let k = (by_distance.len() / 50).max(1);
        let mut out = Vec::new();
        for end in [&by_distance[..k], &by_distance[by_distance.len() - k..]] {
            let mut groups: Vec<Vector3<f64>> = Vec::new();
            for (_, d) in end {
                if groups.len() < 8
                    && groups
                        .iter()
                        .all(|g| g.dot(d).abs() < 15f64.to_radians().cos())
                {
                    groups.push(*d);
                }
            }
            out.extend(groups);
        }
        out
    }
}

/// The rigid motion `a` after `b`: `a b`.
fn compose(a: &RigidTransform, b: &RigidTransform) -> RigidTransform {
    RigidTransform {
        rotation: a.rotation * b.rotation,
        translation: a.rotation * b.translation + a.translation,
    }
}

/// The angle `theta` maximising `tr(m C(theta))`, `C(theta)` the rotation about the unit
/// `axis`, and that maximum.
fn best_turn(m: &Matrix3<f64>, axis: &Vector3<f64>) -> (f64, f64) {
    // C = cos I + sin [a]x + (1 - cos) a a^T, so tr(m C) = a^T m a + A cos + B sin.
    let along = axis.dot(&(m * axis));
    let a = m.trace() - along;
    let b = (m * axis.cross_matrix()).trace();
    let angle = b.atan2(a);
    (angle, along + a.hypot(b))
}

/// Rodrigues' rotation by `angle` about the unit `axis`.
fn axis_rotation(axis: &Vector3<f64>, angle: f64) -> Matrix3<f64> {
    let k = axis.cross_matrix();
    Matrix3::identity() + angle.sin() * k + (1.0 - angle.cos()) * k * k
}

/// The half turn about the unit `axis`.
fn half_turn(axis: &Vector3<f64>) -> Matrix3<f64> {
    2.0 * axis * axis.transpose() - Matrix3::identity()
}

/// A unit vector perpendicular to the unit `axis`: the coordinate axis least along it,
/// projected (deterministic, so detection's choices do not depend on the solver).
fn perpendicular(axis: &Vector3<f64>) -> Vector3<f64> {
    let basis = [Vector3::x(), Vector3::y(), Vector3::z()];
    let least = basis
        .iter()
        .min_by(|a, b| a.dot(axis).abs().total_cmp(&b.dot(axis).abs()))
        .copied()
        .unwrap_or_else(Vector3::x);
    (least - axis * axis.dot(&least)).normalize()
}

/// Every `len / max`-th point (rounded up), at most about `max` of them.
fn strided(points: &[[f64; 3]], max: usize) -> Vec<[f64; 3]> {
    let step = points.len().div_ceil(max).max(1);
    points.iter().step_by(step).copied().collect()
}

fn mean(points: &[[f64; 3]]) -> Vector3<f64> {
    Vector3::from(crate::scene::mean_point(points))
}

/// The covariance's eigenvalues, ascending, and their unit eigenvectors.
fn principal(points: &[[f64; 3]], centre: &Vector3<f64>) -> ([f64; 3], [Vector3<f64>; 3]) {
    let mut cov = Matrix3::zeros();
    for p in points {
        let d = Vector3::from(*p) - centre;
        cov += d * d.transpose();
    }
    cov /= points.len() as f64;
    let eig = SymmetricEigen::new(cov);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    (
        order.map(|k| eig.eigenvalues[k]),
        order.map(|k| eig.eigenvectors.column(k).into_owned()),
    )
}

/// The group `generators` generate with the identity, identity first then in the order
/// found. Elements are told apart by their rotations (within `rotation_tol` radians; a
/// product within `cover` times it of an element is that element, since rounding in
/// generators that already are a group adds up in their products): a bounded model has no
/// translation symmetry, so two symmetries with one rotation are one. Two whose translations
/// differ by more than `translation_tol` are an error (a screw motion or a translation is no
/// symmetry); without one, the first is kept. Any other product passes through `settle` (None:
/// dropped).
fn closed(
    generators: &[RigidTransform],
    rotation_tol: f64,
    translation_tol: Option<f64>,
    cover: f64,
    settle: impl Fn(RigidTransform) -> Option<RigidTransform>,
) -> Result<Vec<RigidTransform>> {
    let turned = |a: &RigidTransform, b: &RigidTransform, k: f64| {
        let trace = (a.rotation.transpose() * b.rotation).trace();
        ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos() <= k * rotation_tol
    };
    let find = |group: &[RigidTransform], s: &RigidTransform, k: f64| -> Result<bool> {
        match group.iter().find(|g| turned(g, s, k)) {
            None => Ok(false),
            Some(g) => match translation_tol {
                Some(tol) if (g.translation - s.translation).norm() > tol => {
                    Err(Error::InvalidParameter {
                        name: "symmetries_discrete",
                        value: format!(
                            "two transforms with one rotation, translations {:?} and {:?}",
                            g.translation.as_slice(),
                            s.translation.as_slice()
                        ),
                        reason: "they differ by a translation, which no bounded model has as a \
                                 symmetry (a turn's translation must keep a point fixed)",
                    })
                }
                _ => Ok(true),
            },
        }
    };
    let mut group = vec![RigidTransform::identity()];
    let push = |group: &mut Vec<RigidTransform>, s: RigidTransform| -> Result<bool> {
        if find(group, &s, 1.0)? {
            return Ok(false);
        }
        if group.len() >= MAX_GROUP {
            return Err(Error::InvalidParameter {
                name: "symmetries_discrete",
                value: format!("more than {MAX_GROUP} transforms"),
                reason: "the transforms must generate a finite group (check the rotations)",
            });
        }
        group.push(s);
        Ok(true)
    };
    for g in generators {
        push(&mut group, *g)?;
    }
    let generators = group[1..].to_vec();
    let mut grew = true;
    while grew {
        grew = false;
        let snapshot = group.clone();
        for a in &snapshot {
            for b in &generators {
                let product = compose(a, b);
                if find(&group, &product, cover)? {
                    continue;
                }
                if let Some(product) = settle(product) {
                    grew |= push(&mut group, product)?;
                }
            }
        }
    }
    Ok(group)
}

/// The axes with unit directions; an error for a non-finite value or a zero direction.
fn checked_axes(axes: &[Axis]) -> Result<Vec<Axis>> {
    axes.iter()
        .enumerate()
        .map(|(row, a)| {
            if !a
                .direction
                .iter()
                .chain(a.offset.iter())
                .all(|v| v.is_finite())
            {
                return Err(Error::NonFinite {
                    what: "symmetries_continuous",
                    row,
                });
            }
            let norm = a.direction.norm();
            if norm.is_nan() || norm <= 1e-12 {
                return Err(Error::InvalidParameter {
                    name: "symmetries_continuous",
                    value: format!("axis {row} of direction {:?}", a.direction.as_slice()),
                    reason: "an axis needs a non-zero direction",
                });
            }
            Ok(Axis {
                direction: a.direction / norm,
                offset: a.offset,
            })
        })
        .collect()
}

/// With two or more axes, the point they all pass through (every rotation about it is then a
/// symmetry); an error when they are parallel or do not meet.
fn common_point(axes: &[Axis]) -> Result<Option<Vector3<f64>>> {
    if axes.len() < 2 {
        return Ok(None);
    }
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for axis in axes {
        let p = Matrix3::identity() - axis.direction * axis.direction.transpose();
        a += p;
        b += p * axis.offset;
    }
    let scale = 1.0 + axes.iter().map(|x| x.offset.norm()).fold(0.0, f64::max);
    let meet = a
        .try_inverse()
        .filter(|_| a.determinant() > 1e-9)
        .map(|inv| inv * b)
        .filter(|x| {
            axes.iter().all(|axis| {
                let d = x - axis.offset;
                (d - axis.direction * axis.direction.dot(&d)).norm() <= 1e-4 * scale
            })
        });
    match meet {
        Some(x) => Ok(Some(x)),
        None => Err(Error::InvalidParameter {
            name: "symmetries_continuous",
            value: format!("{} axes", axes.len()),
            reason: "several axes of continuous symmetry must meet at one point (every rotation \
                     about it is then a symmetry)",
        }),
    }
}

#[cfg(test)]
#[path = "tests/symmetry.rs"]
mod tests;
