//! The whole preprocessing of one cloud: downsample, index, normals, FPFH.

use super::fpfh::{fpfh, FpfhVariant, FPFH_DIM};
use super::normals::{estimate_normals, Orientation};
use super::search::PointIndex;
use super::voxel::voxel_downsample;
use super::{check_points, check_positive};
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

/// A described cloud: the (downsampled) points, their normals and FPFH descriptors.
#[derive(Debug, Clone)]
pub struct Described {
    pub points: Vec<[f64; 3]>,
    pub normals: Vec<[f64; 3]>,
    pub descriptors: Features,
}

/// Downsamples (if asked), estimates normals (unless given; given normals require no
/// downsampling, since averaging points would leave them unaligned) and computes FPFH.
pub fn describe(
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    params: &DescribeParams,
) -> Result<Described> {
    check_points(points, "points to describe", 1)?;
    let points = match params.voxel_size {
        Some(v) => {
            check_positive("voxel_size", v)?;
            if normals.is_some() {
                return Err(Error::InvalidParameter {
                    name: "voxel_size",
                    value: v.to_string(),
                    reason: "given normals cannot follow downsampling; pass one or the other",
                });
            }
            voxel_downsample(points, v)?
        }
        None => points.to_vec(),
    };
    let index = PointIndex::new(&points)?;
    let normals = match normals {
        Some(n) => {
            if n.len() != points.len() {
                return Err(Error::LengthMismatch {
                    what: "normals (one per point)",
                    expected: points.len(),
                    got: n.len(),
                });
            }
            n.to_vec()
        }
        None => estimate_normals(
            &points,
            &index,
            params.normal_radius,
            params.normal_max_nn,
            params.orientation,
        )?,
    };
    let desc = fpfh(
        &points,
        &normals,
        &index,
        params.feature_radius,
        params.feature_max_nn,
        params.variant,
    )?;
    let flat: Vec<f64> = desc.iter().flat_map(|d| d.iter().copied()).collect();
    Ok(Described {
        points,
        normals,
        descriptors: Features::new(flat, FPFH_DIM)?,
    })
}
