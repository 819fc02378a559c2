//! The whole preprocessing of one cloud: downsample, index, normals, FPFH.

use std::time::Instant;

use super::fpfh::{fpfh, FpfhVariant, FPFH_DIM};
use super::normals::{estimate_normals, Orientation};
use super::search::PointIndex;
use super::voxel::voxel_downsample;
use super::{check_normals, check_points, check_positive};
use crate::correspondences::Features;
use crate::error::{Error, Result};

/// Radii and neighbour counts for [`describe`]. [`DescribeParams::for_voxel`] gives the usual
/// choice (Open3D's registration tutorials, and the scale at which FPFH is tuned): normals over
/// 2 voxels, descriptors over 5.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DescribeParams {
    /// Downsample to this voxel size first; `None` keeps the points as given.
    pub voxel_size: Option<f64>,
    /// Neighbourhood of the PCA normals.
    pub normal_radius: f64,
    pub normal_max_nn: usize,
    /// Neighbourhood of the FPFH descriptors.
    pub feature_radius: f64,
    pub feature_max_nn: usize,
    /// Current Open3D's FPFH or PCL's.
    pub variant: FpfhVariant,
    /// Sign rule for estimated normals (unused when normals are given).
    pub orientation: Orientation,
}

impl DescribeParams {
    /// Normals over `2 * voxel_size` (30 neighbours at most), FPFH over `5 * voxel_size`
    /// (100 at most), normals towards the origin (a scan's sensor).
    pub fn for_voxel(voxel_size: f64) -> Self {
        Self {
            voxel_size: Some(voxel_size),
            normal_radius: 2.0 * voxel_size,
            normal_max_nn: 30,
            feature_radius: 5.0 * voxel_size,
            feature_max_nn: 100,
            variant: FpfhVariant::Open3d,
            orientation: Orientation::Towards([0.0; 3]),
        }
    }
}

/// Seconds spent in each stage of [`describe`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DescribeTimings {
    /// Downsampling (or copying the points as given).
    pub downsample: f64,
    /// The k-d tree and the normals (the tree alone when normals are given).
    pub normals: f64,
    pub fpfh: f64,
}

/// A described cloud: the (downsampled) points, their normals and FPFH descriptors.
#[derive(Debug, Clone)]
pub struct Described {
    pub points: Vec<[f64; 3]>,
    pub normals: Vec<[f64; 3]>,
    pub descriptors: Features,
    pub timings: DescribeTimings,
}

/// Downsamples (if asked), builds one k-d tree, estimates normals (unless given; given normals
/// require no downsampling, since averaging points would leave them unaligned) and computes
/// FPFH over the same tree.
///
/// A neighbour count above the cloud's size is lowered to it (a point cannot have more
/// neighbours; the neighbourhoods are the same), so that a huge count cannot size buffers.
pub fn describe(
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    params: &DescribeParams,
) -> Result<Described> {
    let t0 = Instant::now();
    check_points(points, "points to describe", 1)?;
    let points = downsampled(points, normals.is_some(), params.voxel_size)?;
    let t1 = Instant::now();
    let index = PointIndex::new(&points)?;
    let normals = match normals {
        Some(n) => given_normals(n, points.len())?,
        None => estimate_normals(
            &points,
            &index,
            params.normal_radius,
            at_most(params.normal_max_nn, points.len(), 3),
            params.orientation,
        )?,
    };
    let t2 = Instant::now();
    let desc = fpfh(
        &points,
        &normals,
        &index,
        params.feature_radius,
        at_most(params.feature_max_nn, points.len(), 2),
        params.variant,
    )?;
    let flat: Vec<f64> = desc.iter().flat_map(|d| d.iter().copied()).collect();
    let descriptors = Features::new(flat, FPFH_DIM)?;
    let t3 = Instant::now();
    Ok(Described {
        points,
        normals,
        descriptors,
        timings: DescribeTimings {
            downsample: (t1 - t0).as_secs_f64(),
            normals: (t2 - t1).as_secs_f64(),
            fpfh: (t3 - t2).as_secs_f64(),
        },
    })
}

/// The points downsampled to `voxel_size`, or as given; refuses downsampling with normals.
fn downsampled(
    points: &[[f64; 3]],
    with_normals: bool,
    voxel_size: Option<f64>,
) -> Result<Vec<[f64; 3]>> {
    let Some(v) = voxel_size else {
        return Ok(points.to_vec());
    };
    check_positive("voxel_size", v)?;
    if with_normals {
        return Err(Error::InvalidParameter {
            name: "voxel_size",
            value: v.to_string(),
            reason: "given normals cannot follow downsampling; pass one or the other",
        });
    }
    voxel_downsample(points, v)
}

fn given_normals(normals: &[[f64; 3]], n_points: usize) -> Result<Vec<[f64; 3]>> {
    check_normals(normals, n_points, "normals", "normals (one per point)")?;
    Ok(normals.to_vec())
}

/// `max_nn` lowered to the cloud's size, but not below `floor` (the smallest count the stage
/// takes), so that a small cloud is not refused for its size.
fn at_most(max_nn: usize, n_points: usize, floor: usize) -> usize {
    max_nn.min(n_points.max(floor))
}

#[cfg(test)]
#[path = "../tests/describe.rs"]
mod tests;
