//! Planar patches of a cloud with normals: region growing over the neighbour graph, each patch
//! a plane, a rectangle in it and its points.
//!
//! Why: a flat face looks the same everywhere to a local descriptor, so faces are matched as
//! wholes instead (their size and outline), by [`crate::scene::faces`].

use std::collections::HashSet;

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::rectangle::min_area_rectangle;
use super::search::{Neighbourhoods, PointIndex};
use super::{check_index, check_normals, check_points, check_positive};
use crate::error::{Error, Result};

/// How far a point may lie from its patch's plane, and how far its normal may turn from the
/// plane's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlaneTolerances {
    /// Distance from the plane, in the cloud's units.
    pub distance: f64,
    /// Angle between the point's normal and the plane's, in radians.
    pub angle: f64,
}

/// A plane's points deviate from it by the cloud's noise only: three standard deviations
/// hold all but a few in a thousand.
const NOISE_SIGMAS: f64 = 3.0;

/// Floors of the calibrated tolerances, which a noiseless cloud (a mesh's samples) gets: the
/// centroid of a voxel that a face's edge cuts lies up to about a quarter voxel off the face,
/// and a normal fitted over 2 voxels near an edge turns by several degrees while its point
/// still lies on the face. Chosen on the box models (validation): 0.05 voxel and 2 degrees
/// left 0.79-0.92 of a box in faces, these 0.89-0.98, while the bunny and the dragon stay
/// at 0.00-0.03.
const MIN_DISTANCE_VOXELS: f64 = 0.25;
const MIN_ANGLE_RAD: f64 = 10.0 * std::f64::consts::PI / 180.0;

impl PlaneTolerances {
    /// The tolerances of a cloud downsampled at `voxel` whose points scatter about their
    /// surface by `noise` (a standard deviation, as [`crate::scene::voxel::noise_level`]
    /// measures it), with normals fitted over `normal_radius`: [`NOISE_SIGMAS`] times the
    /// noise from the plane, and the same multiple of the tilt noise gives a normal fitted
    /// to a disc of that radius (about `2 noise / (radius sqrt(k))` per axis for `k` points,
    /// `k` the disc's area in voxels), each at least its floor.
    pub fn calibrated(voxel: f64, noise: f64, normal_radius: f64) -> Result<Self> {
        check_positive("voxel", voxel)?;
        check_positive("normal_radius", normal_radius)?;
        if !(noise.is_finite() && noise >= 0.0) {
            return Err(Error::InvalidParameter {
                name: "noise",
                value: noise.to_string(),
                reason: "must be a finite number, zero or more",
            });
        }
        let k = (std::f64::consts::PI * (normal_radius / voxel).powi(2)).max(3.0);
        // Two tilt components: their norm's spread is about sqrt(2) times each one's.
        let tilt = std::f64::consts::SQRT_2 * 2.0 * noise / (normal_radius * k.sqrt());
        Ok(Self {
            distance: (NOISE_SIGMAS * noise).max(MIN_DISTANCE_VOXELS * voxel),
            angle: (NOISE_SIGMAS * tilt).atan().max(MIN_ANGLE_RAD),
        })
    }
}

/// How many hops of the neighbour graph beyond the normals' agreement a patch of a closed
/// surface reaches on its plane ([`PlaneSegmenter::ring`]): a normal within the normals'
/// radius of an edge is bent, and where it is bent past the angle tolerance is up to that
/// radius (one hop) from the edge, a little more on a grid of samples; the second hop
/// reaches the edge all the same. One hop on an open surface (a scan), where a second would
/// cross a narrow gap (between boxes packed side by side) onto a neighbour's face.
const CLOSED_RING_HOPS: usize = 2;

/// One planar patch.
#[derive(Debug, Clone, PartialEq)]
pub struct Patch {
    /// Unit normal of the fitted plane, on the side the points' normals face (towards the
    /// sensor on a scan, outward on a model).
    pub normal: [f64; 3],
    /// The points' mean.
    pub centroid: [f64; 3],
    /// The centre of the minimum-area rectangle holding the points and the patch's rim (the
    /// points on its edges that a neighbouring patch took), in the plane.
    pub centre: [f64; 3],
    /// The rectangle's axes, long side first; `(axes[0], axes[1], normal)` is right-handed.
    pub axes: [[f64; 3]; 2],
    /// The rectangle's side lengths, along `axes` (long side first).
    pub extents: [f64; 2],
    /// The rows of the patch's points, ascending.
    pub rows: Vec<usize>,
}

impl Patch {
    /// The rectangle's area.
    pub fn area(&self) -> f64 {
        self.extents[0] * self.extents[1]
    }
}

/// Region growing of planar patches over one cloud: the neighbour graph and the order of the
/// seeds are built once, and patches found over any subset of the points.
pub struct PlaneSegmenter {
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    hoods: Neighbourhoods,
    /// Rows, flattest first (seeds are tried in this order).
    order: Vec<usize>,
    tolerances: PlaneTolerances,
    min_points: usize,
    /// Whether the cloud samples a closed surface ([`Self::closed`]).
    closed: bool,
}

impl PlaneSegmenter {
    /// The graph joins points within `radius` (at most 30 neighbours each); patches of fewer
    /// than `min_points` points are dropped (their points stay free for other patches).
    /// Errors: empty or non-finite points, normals not one per point, an index of another
    /// cloud, a radius or tolerance that is not positive, `min_points` below 3.
    pub fn new(
        points: &[[f64; 3]],
        normals: &[[f64; 3]],
        index: &PointIndex,
        radius: f64,
        tolerances: PlaneTolerances,
        min_points: usize,
    ) -> Result<Self> {
        check_points(points, "points for planes", 1)?;
        check_normals(
            normals,
            points.len(),
            "normals for planes",
            "normals for planes (one per point)",
        )?;
        check_index(index, points)?;
        check_positive("plane distance tolerance", tolerances.distance)?;
        check_positive("plane angle tolerance", tolerances.angle)?;
        if min_points < 3 {
            return Err(Error::InvalidParameter {
                name: "min_points",
                value: min_points.to_string(),
                reason: "a plane needs at least 3 points",
            });
        }
        let hoods = index.neighbourhoods(points, radius, 30)?;
        // Flatness: how far the neighbours' normals turn from the point's. Seeds on flat
        // ground first, so that each patch starts from a plane its centre agrees with.
        let turn: Vec<f64> = (0..points.len())
            .into_par_iter()
            .map(|i| {
                let (near, _) = hoods.of(i);
                let n = normals[i];
                let s: f64 = near
                    .iter()
                    .map(|&j| 1.0 - dot(n, normals[j as usize]))
                    .sum();
                s / near.len().max(1) as f64
            })
            .collect();
        let mut order: Vec<usize> = (0..points.len()).collect();
        order.sort_by(|&a, &b| turn[a].total_cmp(&turn[b]).then(a.cmp(&b)));
        Ok(Self {
            points: points.to_vec(),
            normals: normals.to_vec(),
            hoods,
            order,
            tolerances,
            min_points,
            closed: false,
        })
    }

    /// The segmenter of a cloud that samples a closed surface all round (a model's mesh),
    /// where every face ends at an edge shared with another face: its patches' rings reach
    /// [`CLOSED_RING_HOPS`] deep and its rectangles hold their rims ([`Self::ring`]), so that
    /// each face measures its full extent, as the same face seen alone on a scan does.
    pub fn closed(mut self) -> Self {
        self.closed = true;
        self
    }

    /// The patches among the rows where `free` is true (every row when `None`), largest
    /// first. Deterministic: the growth is serial in the seeds' fixed order, the rectangles
    /// are fitted in parallel.
    pub fn patches(&self, free: Option<&[bool]>) -> Result<Vec<Patch>> {
        let n = self.points.len();
        if let Some(f) = free {
            super::check_len(f.len(), n, "free flags (one per point)")?;
        }
        let allowed = |i: usize| free.is_none_or(|f| f[i]);
        let mut taken = vec![false; n];
        let mut groups: Vec<(Vec<usize>, Vec<usize>)> = Vec::new();
        let cos = self.tolerances.angle.cos();
        for &seed in &self.order {
            if taken[seed] || !allowed(seed) {
                continue;
            }
            let (rows, rim) = self.grow(seed, cos, &allowed, &mut taken);
            if rows.len() < self.min_points {
                for &r in &rows {
                    taken[r] = false;
                }
                // Tried as a seed once: it may still join a later patch.
                continue;
            }
            groups.push((rows, rim));
        }
        let mut patches: Vec<Patch> = groups
            .into_par_iter()
            .filter_map(|(mut rows, rim)| {
                rows.sort_unstable();
                fit_patch(&self.points, &self.normals, rows, &rim)
            })
            .collect();
        patches.sort_by(|a, b| {
            b.rows
                .len()
                .cmp(&a.rows.len())
                .then(a.rows[0].cmp(&b.rows[0]))
        });
        Ok(patches)
    }

    /// The patch grown from `seed`: neighbours whose normal agrees with the plane's and that
    /// lie on it join (the plane refitted each time the patch doubles), then one ring
    /// ([`Self::ring`]). Its rows and its rim.
    fn grow(
        &self,
        seed: usize,
        cos: f64,
        allowed: &impl Fn(usize) -> bool,
        taken: &mut [bool],
    ) -> (Vec<usize>, Vec<usize>) {
        let mut plane = Plane {
            point: self.points[seed],
            normal: self.normals[seed],
        };
        let mut moments = Moments::default();
        let mut rows = vec![seed];
        taken[seed] = true;
        moments.add(self.points[seed]);
        let mut next_fit = 8;
        let mut head = 0;
        let tol = self.tolerances.distance;
        while head < rows.len() {
            let i = rows[head];
            head += 1;
            for &j in self.hoods.of(i).0 {
                let j = j as usize;
                if taken[j] || !allowed(j) {
                    continue;
                }
                if dot(self.normals[j], plane.normal) < cos || plane.distance(self.points[j]) > tol
                {
                    continue;
                }
                taken[j] = true;
                rows.push(j);
                moments.add(self.points[j]);
            }
            if rows.len() >= next_fit {
                if let Some(fitted) = moments.plane(plane.normal) {
                    plane = fitted;
                }
                next_fit *= 2;
            }
        }
        let rim = self.ring(&mut rows, plane, allowed, taken);
        (rows, rim)
    }

    /// The rings of neighbours of `rows` on `plane` whatever their normal, as normals fitted
    /// across an edge are bent while the points there still lie on the face: the free ones
    /// join `rows`. One hop deep; on a closed surface ([`Self::closed`]) [`CLOSED_RING_HOPS`]
    /// deep, and those another patch took already are returned (the rim). Why the rim: the
    /// points along an edge lie on both faces, and a face measured without those its
    /// neighbour took comes out up to a voxel short on that side, where the same face seen
    /// alone (a box's top from above) keeps them; with them, each face measures the same
    /// whichever grew first.
    fn ring(
        &self,
        rows: &mut Vec<usize>,
        plane: Plane,
        allowed: &impl Fn(usize) -> bool,
        taken: &mut [bool],
    ) -> Vec<usize> {
        let tol = self.tolerances.distance;
        // The patch's own rows, told apart from the points other patches took (a rim).
        let mut own: HashSet<usize> = match self.closed {
            true => rows.iter().copied().collect(),
            false => HashSet::new(),
        };
        let mut frontier = rows.clone();
        let mut rim = Vec::new();
        let hops = if self.closed { CLOSED_RING_HOPS } else { 1 };
        for _ in 0..hops {
            let mut next = Vec::new();
            for &i in &frontier {
                for &j in self.hoods.of(i).0 {
                    let j = j as usize;
                    if !allowed(j) || plane.distance(self.points[j]) > tol {
                        continue;
                    }
                    if !taken[j] {
                        taken[j] = true;
                        rows.push(j);
                    } else if self.closed && !own.contains(&j) {
                        rim.push(j);
                    } else {
                        continue;
                    }
                    if self.closed {
                        own.insert(j);
                    }
                    next.push(j);
                }
            }
            frontier = next;
        }
        rim.sort_unstable();
        rim
    }
}

/// A plane through `point` with unit `normal`.
#[derive(Debug, Clone, Copy)]
struct Plane {
    point: [f64; 3],
    normal: [f64; 3],
}

impl Plane {
    fn distance(&self, p: [f64; 3]) -> f64 {
        dot(sub(p, self.point), self.normal).abs()
    }
}

/// Running sums for a plane fit, about the first point added (for rounding).
#[derive(Debug, Default)]
struct Moments {
    origin: Option<[f64; 3]>,
    n: f64,
    sum: Vector3<f64>,
    outer: Matrix3<f64>,
}

impl Moments {
    fn add(&mut self, p: [f64; 3]) {
        let o = *self.origin.get_or_insert(p);
        let d = Vector3::from(sub(p, o));
        self.n += 1.0;
        self.sum += d;
        self.outer += d * d.transpose();
    }

    /// The least-squares plane, its normal on the side of `side`; `None` below 3 points.
    fn plane(&self, side: [f64; 3]) -> Option<Plane> {
        let o = self.origin?;
        if self.n < 3.0 {
            return None;
        }
        let mean = self.sum / self.n;
        let cov = self.outer / self.n - mean * mean.transpose();
        let normal = lowest_axis(&cov)?;
        let normal = if dot(normal, side) < 0.0 {
            normal.map(|v| -v)
        } else {
            normal
        };
        Some(Plane {
            point: [o[0] + mean[0], o[1] + mean[1], o[2] + mean[2]],
            normal,
        })
    }
}

/// The unit eigenvectors of the smallest and the largest eigenvalue of a symmetric 3 x 3
/// matrix, or `None` when not finite.
fn eigen_axes(cov: &Matrix3<f64>) -> Option<([f64; 3], [f64; 3])> {
    let eig = SymmetricEigen::new(*cov);
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]));
    let low = eig.eigenvectors.column(idx[0]).normalize();
    let high = eig.eigenvectors.column(idx[2]).normalize();
    let ok = low.iter().chain(high.iter()).all(|v| v.is_finite());
    ok.then(|| ([low[0], low[1], low[2]], [high[0], high[1], high[2]]))
}

fn lowest_axis(cov: &Matrix3<f64>) -> Option<[f64; 3]> {
    eigen_axes(cov).map(|(low, _)| low)
}

/// The patch of `rows`: the least-squares plane (signed by the points' normals), and the
/// minimum-area rectangle of the points and the `rim` ([`PlaneSegmenter::ring`]) projected
/// on it.
fn fit_patch(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    rows: Vec<usize>,
    rim: &[usize],
) -> Option<Patch> {
    let mut moments = Moments::default();
    let mut side = [0.0; 3];
    for &r in &rows {
        moments.add(points[r]);
        side = add(side, normals[r]);
    }
    let plane = moments.plane(side)?;
    let normal = plane.normal;
    let centroid = plane.point;
    // Any in-plane basis (the major axis here): the rectangle's own axes come from the hull.
    let cov = {
        let mut m = Matrix3::zeros();
        for &r in &rows {
            let d = Vector3::from(sub(points[r], centroid));
            m += d * d.transpose();
        }
        m
    };
    let (_, major) = eigen_axes(&cov)?;
    let u = normalize(sub(major, scale(normal, dot(major, normal))))?;
    let v = cross(normal, u);
    let flat: Vec<[f64; 2]> = (rows.iter().chain(rim))
        .map(|&r| {
            let d = sub(points[r], centroid);
            [dot(d, u), dot(d, v)]
        })
        .collect();
    let (angle, lo, hi) = min_area_rectangle(&flat)?;
    let (c, s) = (angle.cos(), angle.sin());
    let a1 = add(scale(u, c), scale(v, s));
    let a2 = add(scale(u, -s), scale(v, c));
    let mid = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
    let centre = add(centroid, add(scale(a1, mid[0]), scale(a2, mid[1])));
    let (e1, e2) = (hi[0] - lo[0], hi[1] - lo[1]);
    let (axes, extents) = if e1 >= e2 {
        ([a1, a2], [e1, e2])
    } else {
        // The long side first, and still right-handed with the normal.
        ([a2, scale(a1, -1.0)], [e2, e1])
    };
    Some(Patch {
        normal,
        centroid,
        centre,
        axes,
        extents,
        rows,
    })
}

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

pub(crate) fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f64; 3]) -> Option<[f64; 3]> {
    let n = dot(a, a).sqrt();
    (n > 1e-12).then(|| scale(a, 1.0 / n))
}

#[cfg(test)]
#[path = "../tests/planes.rs"]
pub(crate) mod tests;
