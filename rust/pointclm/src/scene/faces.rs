//! Pose proposals from flat faces: each model face laid on each scan patch it could be.
//!
//! Why: on parts made of large flat faces (boxes, cartons) every point of a face has the same
//! local descriptor, so descriptor matches propose almost no right pose, while a face's size
//! and outline are distinctive. A visible patch is the face itself, or flush copies of it
//! joined (boxes packed in a row or grid), or a part of it (occluded, or cut by the edge of
//! what the sensor sees). The face's outward normal goes onto the patch's and its sides along
//! the patch's rectangle; its centre onto each tile when the patch is a whole number of faces
//! each way, else, when the patch fits in the face, each of its corners onto the patch's
//! corner on the same side. Verification judges every proposal; nothing is accepted for being
//! proposed.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::kabsch::RigidTransform;
use crate::pointcloud::planes::{add, cross, dot, scale, sub};
use crate::pointcloud::{
    DescribeParams, Patch, PlaneSegmenter, PlaneTolerances, PointIndex, RefineContext,
};

use super::voxel::noise_level;
use super::{mean_point, SceneRules};

/// Which poses the correspondence stage proposes to verification
/// ([`super::SceneOptions::proposals`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Proposals {
    /// Descriptors alone, or with faces when the model is mostly large flat faces: at least
    /// `SceneRules::min_planar_share` of its downsampled points in planar faces wider than a
    /// disc of the FPFH radius ([`planar_share`]).
    #[default]
    Auto,
    /// The clusters of descriptor matches (and, in a heap, point pair voting) alone.
    Descriptors,
    /// Those, and each model face laid on each scan patch it could be ([`FaceProposer`]).
    Faces,
}

impl Proposals {
    /// The names the Python layer and the command line use.
    pub const NAMES: [&'static str; 3] = ["auto", "descriptors", "faces"];

    /// `Proposals` by name ([`Self::NAMES`]); another name is a typed error.
    pub fn from_name(name: &str) -> Result<Self> {
        match name {
            "auto" => Ok(Self::Auto),
            "descriptors" => Ok(Self::Descriptors),
            "faces" => Ok(Self::Faces),
            _ => Err(Error::InvalidParameter {
                name: "proposals",
                value: name.to_string(),
                reason: "must be \"auto\", \"descriptors\" or \"faces\"",
            }),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Descriptors => "descriptors",
            Self::Faces => "faces",
        }
    }
}

/// Patches of fewer points are not faces: a 4 x 4-voxel square is below the FPFH disc, where
/// descriptors still see the face's edges and match.
pub const MIN_PATCH_POINTS: usize = 16;

/// A measured extent falls short of the face's by up to a voxel on each side (the outermost
/// voxel centroid lies within a voxel of the edge), on the model as on the scan.
const SIZE_TOLERANCE_VOXELS: f64 = 2.0;

/// On average a measured extent falls short by about half a voxel in all (0.2-0.7 voxel on the
/// box models' faces): added to every extent before flush copies are counted, where the
/// shortfall would otherwise add up once per copy.
const EXTENT_BIAS_VOXELS: f64 = 0.5;

/// The share of the model's `points` lying in `faces` whose rectangle is at least
/// `min_area`.
pub fn planar_share(faces: &[Patch], n_points: usize, min_area: f64) -> f64 {
    let inside: usize = faces
        .iter()
        .filter(|f| f.area() >= min_area)
        .map(|f| f.rows.len())
        .sum();
    inside as f64 / n_points.max(1) as f64
}

/// The model's faces, measured once per call, and the scan's segmentation, proposing face
/// poses for each pass.
pub struct FaceProposer {
    faces: Vec<Patch>,
    /// The model's points (downsampled), indexed, for telling placements apart.
    model: PointIndex,
    sample: Vec<[f64; 3]>,
    centroid: [f64; 3],
    segmenter: PlaneSegmenter,
    size_tolerance: f64,
    /// Added to every measured extent ([`EXTENT_BIAS_VOXELS`]).
    bias: f64,
    max_poses: usize,
    radius: f64,
}

/// `patch` with `bias` added to its extents.
fn unbiased(mut patch: Patch, bias: f64) -> Patch {
    patch.extents = patch.extents.map(|e| e + bias);
    patch
}

/// The model's planar segmentation at the tolerances' floors ([`PlaneTolerances::calibrated`]
/// without noise), with the share of its points in faces wider than the FPFH disc; its faces
/// are measured to their edges only when asked ([`ModelPlanes::faces`]), as most models (the
/// curved ones) never need them. Why not the model's measured noise: a model is a clean,
/// complete object whose flat faces are flat to rounding, and what the noise measure reads on
/// it is fine detail (0.2-0.5 voxel on the dragon, the rocker arm and the bracket's thin
/// plates), at which curved or neighbouring faces would join.
pub struct ModelPlanes {
    segmenter: PlaneSegmenter,
    /// The share of the model's points in faces wider than the FPFH disc, measured on faces
    /// grown as a scan's are (one ring, no rim): `SceneRules::min_planar_share` was chosen on
    /// that measure (boxes 0.89-0.99, the fandisk 0.43), which the closed growth's wider
    /// faces would move (the fandisk to 0.51) without any change of the part.
    pub planar_share: f64,
}

impl ModelPlanes {
    /// The model's `points` with their outward `normals`, described at `voxel`.
    pub fn new(points: &[[f64; 3]], normals: &[[f64; 3]], voxel: f64) -> Result<Self> {
        let index = PointIndex::new(points)?;
        let params = DescribeParams::for_voxel(voxel);
        let segmenter = segmenter(
            points,
            normals,
            &index,
            voxel,
            params.normal_radius,
            Some(0.0),
        )?;
        let disc = std::f64::consts::PI * params.feature_radius.powi(2);
        let planar_share = planar_share(&segmenter.patches(None)?, points.len(), disc);
        Ok(Self {
            segmenter,
            planar_share,
        })
    }

    /// The model's planar faces (normals outward, as the model's are oriented), each grown
    /// to the edges it shares with its neighbours (a closed surface).
    pub fn faces(self) -> Result<Vec<Patch>> {
        self.segmenter.closed().patches(None)
    }
}

/// The model's planar faces and their planar share ([`ModelPlanes`]) at once.
pub fn model_faces(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    voxel: f64,
) -> Result<(Vec<Patch>, f64)> {
    let planes = ModelPlanes::new(points, normals, voxel)?;
    let share = planes.planar_share;
    Ok((planes.faces()?, share))
}

/// The segmenter of a cloud described at `voxel`, calibrated on `noise`, else on the cloud's
/// own noise measured at the normals' scale; the graph joins points within the normals'
/// radius.
fn segmenter(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    index: &PointIndex,
    voxel: f64,
    normal_radius: f64,
    noise: Option<f64>,
) -> Result<PlaneSegmenter> {
    let noise = match noise {
        Some(given) => given,
        None if points.len() >= 8 => noise_level(points, index, Some(normal_radius)),
        None => 0.0,
    };
    let tolerances = PlaneTolerances::calibrated(voxel, noise, normal_radius)?;
    PlaneSegmenter::new(
        points,
        normals,
        index,
        normal_radius,
        tolerances,
        MIN_PATCH_POINTS,
    )
}

impl FaceProposer {
    /// The proposer for a model (downsampled points and outward normals, its `faces` from
    /// [`model_faces`]) and a scan (downsampled points, normals facing the sensor, `index`
    /// over them), both at `voxel`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: &[[f64; 3]],
        faces: Vec<Patch>,
        scan: &[[f64; 3]],
        scan_normals: &[[f64; 3]],
        index: &PointIndex,
        voxel: f64,
        rules: &SceneRules,
    ) -> Result<Self> {
        let params = DescribeParams::for_voxel(voxel);
        let segmenter = segmenter(scan, scan_normals, index, voxel, params.normal_radius, None)?;
        let step = model.len().div_ceil(rules.screen_points.max(1)).max(1);
        let bias = EXTENT_BIAS_VOXELS * voxel;
        Ok(Self {
            faces: faces.into_iter().map(|f| unbiased(f, bias)).collect(),
            bias,
            model: PointIndex::new(model)?,
            sample: model.iter().step_by(step).copied().collect(),
            centroid: mean_point(model),
            segmenter,
            size_tolerance: SIZE_TOLERANCE_VOXELS * voxel,
            max_poses: rules.max_face_poses,
            radius: voxel,
        })
    }

    /// The face poses over the scan rows where `free` is true (every row when `None`): every
    /// placement of a model face on a patch, tiles first, then by the share of the model
    /// already within `reach` of the scan (`context`'s index), distinct placements only
    /// ([`distinct_placements`]), at most `max_face_poses`.
    pub fn poses(
        &self,
        free: Option<&[bool]>,
        context: &RefineContext,
        reach: f64,
    ) -> Result<Vec<RigidTransform>> {
        if self.max_poses == 0 || self.faces.is_empty() {
            return Ok(Vec::new());
        }
        let patches: Vec<Patch> = (self.segmenter.patches(free)?.into_iter())
            .map(|p| unbiased(p, self.bias))
            .collect();
        let proposed = face_poses(&self.faces, &patches, self.size_tolerance)?;
        if proposed.is_empty() {
            return Ok(Vec::new());
        }
        let poses: Vec<RigidTransform> = proposed.iter().map(|p| p.pose).collect();
        let shares = context.near_shares(&poses, &self.sample, reach)?;
        // Tiles first: their size agrees with the face's, where a corner only anchors it.
        let mut order: Vec<usize> = (0..poses.len()).collect();
        order.sort_by(|&a, &b| {
            (proposed[b].tiled.cmp(&proposed[a].tiled))
                .then(shares[b].total_cmp(&shares[a]))
                .then(a.cmp(&b))
        });
        let ranked: Vec<RigidTransform> = order.iter().map(|&i| poses[i]).collect();
        let kept = distinct_placements(
            &ranked,
            &self.sample,
            &self.model,
            self.centroid,
            self.radius,
            self.max_poses,
        );
        Ok(kept.into_iter().map(|i| ranked[i]).collect())
    }
}

/// One proposal: a pose of the model, the scan patch and model face it came from, and whether
/// the face is a tile of the patch (the whole patch, or one of flush copies filling it) rather
/// than anchored at one of its corners.
#[derive(Debug, Clone, PartialEq)]
pub struct FacePose {
    pub pose: RigidTransform,
    pub patch: usize,
    pub face: usize,
    pub tiled: bool,
}

/// Every pose laying a model face of `faces` on a scan patch of `patches` (module
/// documentation, [`on_patch`]): the face's long axis along either of the patch's, both
/// signs; sizes agree within `size_tolerance` (a length). In patch order, then face order;
/// deterministic.
pub fn face_poses(
    faces: &[Patch],
    patches: &[Patch],
    size_tolerance: f64,
) -> Result<Vec<FacePose>> {
    if !(size_tolerance.is_finite() && size_tolerance >= 0.0) {
        return Err(Error::InvalidParameter {
            name: "size_tolerance",
            value: size_tolerance.to_string(),
            reason: "must be a finite length, zero or more",
        });
    }
    let per_patch: Vec<Vec<FacePose>> = patches
        .par_iter()
        .enumerate()
        .map(|(p, patch)| {
            let mut out = Vec::new();
            for (f, face) in faces.iter().enumerate() {
                on_patch(face, patch, size_tolerance, |pose, tiling| {
                    out.push((
                        FacePose {
                            pose,
                            patch: p,
                            face: f,
                            tiled: tiling.is_some(),
                        },
                        tiling,
                    ))
                });
            }
            best_tilings(out, size_tolerance)
        })
        .collect();
    Ok(per_patch.into_iter().flatten().collect())
}

/// How a face tiles a patch: how far the patch's sides are from whole numbers of faces
/// (summed), and how many faces fill it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tiling {
    residual: f64,
    tiles: usize,
}

/// The proposals on one patch left after dropping the tilings that tile it worse: where one
/// face fills it, narrower faces side by side may fill it within the tolerance too, but would
/// put a copy's body through what holds it up (hidden from the sensor, so verification could
/// not tell). Kept: the tilings within twice the best residual (or half the tolerance), so
/// that both faces of a pair (measured a little apart) stay, and of those the ones of fewest
/// tiles, as a face that divides another (a box of 0.2 x 0.12 x 0.03, whose 0.2 x 0.03 side
/// four times over is its top) fills the larger face as well as the larger face itself does.
/// Corner placements always stay.
fn best_tilings(out: Vec<(FacePose, Option<Tiling>)>, size_tolerance: f64) -> Vec<FacePose> {
    let fits = || out.iter().filter_map(|o| o.1);
    let best = fits().map(|t| t.residual).fold(f64::INFINITY, f64::min);
    let worst = (2.0 * best).max(size_tolerance / 2.0);
    let fewest = (fits().filter(|t| t.residual <= worst))
        .map(|t| t.tiles)
        .min()
        .unwrap_or(0);
    out.into_iter()
        .filter(|o| o.1.is_none_or(|t| t.residual <= worst && t.tiles == fewest))
        .map(|o| o.0)
        .collect()
}

/// A patch tiled by more copies of a face than this is no packing of them (the bin's floor).
const MAX_TILES: f64 = 64.0;

/// How many faces of side `face` lie side by side along a patch side `patch` long, when the
/// patch is a whole number of them within `tol` per face (flush copies add no gap but each
/// side's measure may be off by the tolerance).
fn tiles(patch: f64, face: f64, tol: f64) -> Option<f64> {
    let n = (patch / face).round();
    (n >= 1.0 && (patch - n * face).abs() <= tol * n.sqrt()).then_some(n)
}

/// Calls `emit(pose, tiling)` for each pose laying `face` on `patch`: every tile when the
/// patch is a whole number of faces each way (the face itself, or flush copies of it;
/// `tiling` how well and by how many), otherwise, when the patch fits in the face (a part of
/// it seen), each corner of the face on the patch's corner on the same side (`tiling` None).
fn on_patch(
    face: &Patch,
    patch: &Patch,
    tol: f64,
    mut emit: impl FnMut(RigidTransform, Option<Tiling>),
) {
    let [m1, m2] = face.extents;
    let [l1, l2] = patch.extents;
    let model = frame(face.axes[0], face.normal);
    let centre = Vector3::from(face.centre);
    let square = m1 - m2 <= tol;
    for swapped in [false, true] {
        // The face's long axis along the patch's long axis, or along its short one.
        let along = if swapped { [m2, m1] } else { [m1, m2] };
        let tiling = match (tiles(l1, along[0], tol), tiles(l2, along[1], tol)) {
            (Some(n1), Some(n2)) if n1 * n2 <= MAX_TILES => Some((n1, n2)),
            _ => None,
        };
        // A near-square face's two pairings are one placement but for the quarter turn,
        // which the tiling of a square face finds either way; its corners need both.
        if swapped && square && tiling.is_some() {
            continue;
        }
        let target_axis = if swapped {
            patch.axes[1]
        } else {
            patch.axes[0]
        };
        for sign in [1.0, -1.0] {
            let scan = frame(scale(target_axis, sign), patch.normal);
            let rotation = scan * model.transpose();
            let place = |at: [f64; 3]| RigidTransform {
                rotation,
                translation: Vector3::from(at) - rotation * centre,
            };
            let corner = |s1: f64, s2: f64| {
                add(
                    patch.centre,
                    add(
                        scale(patch.axes[0], s1 * (l1 - along[0]) / 2.0),
                        scale(patch.axes[1], s2 * (l2 - along[1]) / 2.0),
                    ),
                )
            };
            if let Some((n1, n2)) = tiling {
                let fit = Tiling {
                    residual: (l1 - n1 * along[0]).abs() + (l2 - n2 * along[1]).abs(),
                    tiles: (n1 * n2) as usize,
                };
                // Tile (i, j) from the (-, -) corner, each `l / n` long.
                let (w1, w2) = (l1 / n1, l2 / n2);
                for i in 0..n1 as usize {
                    for j in 0..n2 as usize {
                        let shift = add(
                            scale(patch.axes[0], (i as f64 + 0.5) * w1 - l1 / 2.0),
                            scale(patch.axes[1], (j as f64 + 0.5) * w2 - l2 / 2.0),
                        );
                        emit(place(add(patch.centre, shift)), Some(fit));
                    }
                }
                continue;
            }
            if l1 > along[0] + tol || l2 > along[1] + tol {
                continue;
            }
            for s1 in [1.0, -1.0] {
                for s2 in [1.0, -1.0] {
                    emit(place(corner(s1, s2)), None);
                }
            }
        }
    }
}

/// The rotation whose columns are `axis`, `normal x axis` and `normal` (a right-handed
/// frame of the face or patch).
fn frame(axis: [f64; 3], normal: [f64; 3]) -> Matrix3<f64> {
    let second = cross(normal, axis);
    Matrix3::from_columns(&[
        Vector3::from(axis),
        Vector3::from(second),
        Vector3::from(normal),
    ])
}

/// The rows of `poses` left after dropping each pose that places the model where an earlier
/// kept one does: posed centroids within `radius`, and the `sample` points (model frame) of
/// one within `radius` on average of the model posed by the other (`model` indexes the model
/// points), until `limit` are kept. Why by the posed points: a box's half turns are the same
/// placement, and only the posed shape tells them from distinct poses, whatever the model's
/// symmetries.
pub fn distinct_placements(
    poses: &[RigidTransform],
    sample: &[[f64; 3]],
    model: &PointIndex,
    centroid: [f64; 3],
    radius: f64,
    limit: usize,
) -> Vec<usize> {
    let placed: Vec<[f64; 3]> = poses.iter().map(|p| p.apply(centroid)).collect();
    let mut kept: Vec<usize> = Vec::new();
    'next: for (i, pose) in poses.iter().enumerate() {
        if kept.len() >= limit {
            break;
        }
        for &k in &kept {
            if dist(placed[i], placed[k]) > radius {
                continue;
            }
            // Pose i's sample in pose k's model frame.
            let back = poses[k].rotation.transpose();
            let mean: f64 = sample
                .iter()
                .map(|&p| {
                    let q = back * (Vector3::from(pose.apply(p)) - poses[k].translation);
                    model.nearest(&[q[0], q[1], q[2]]).1.sqrt()
                })
                .sum::<f64>()
                / sample.len().max(1) as f64;
            if mean <= radius {
                continue 'next;
            }
        }
        kept.push(i);
    }
    kept
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

#[cfg(test)]
#[path = "../tests/faces.rs"]
mod tests;
