//! From raw point clouds to local descriptors: voxel downsampling, neighbour search, normals
//! and FPFH. The descriptors feed [`crate::matching`], which turns them into the putative
//! correspondences the rest of the pipeline consumes.
//!
//! Conventions follow Open3D, so that users can move between the two: voxel downsampling
//! averages the points of each voxel, neighbourhoods are "hybrid" (at most `max_nn` nearest
//! within `radius`), and FPFH is Open3D's 33-bin variant (a test checks parity with Open3D's
//! own output on 3DMatch fragments).

pub mod covariance;
pub mod describe;
pub mod fpfh;
pub mod icp;
pub mod normals;
pub mod planes;
pub mod ppf;
mod rectangle;
pub mod refine;
pub mod search;
pub mod sensor;
pub mod terraces;
pub mod visibility;
pub mod voxel;

pub use covariance::{pose_covariances, PoseCovariance};
pub use describe::{describe, DescribeParams, Described};
pub use fpfh::{fpfh, FpfhVariant, FPFH_DIM};
pub use normals::{edge_on_scores, estimate_normals, Orientation};
pub use planes::{Patch, PlaneSegmenter, PlaneTolerances};
pub use ppf::{PpfModel, PpfParams, PpfPose};
pub use refine::{
    looks_like_one_view, nearest_rotation, refine_poses, RefineContext, RefineParams, Refined,
    RefinedPose, Rejection, MAX_ROTATION_DEVIATION,
};
pub use search::{isolated_points, Neighbourhoods, PointIndex};
pub use sensor::{estimate_sensor, estimate_viewpoint, SensorEstimate, VIEWPOINT_SAMPLE};
pub use terraces::{resolving_terraces, scan_normal_radius, terraced_share};
pub use voxel::voxel_downsample;

use crate::error::{Error, Result};

/// Rejects an empty cloud or a non-finite coordinate, naming the input.
pub(crate) fn check_points(points: &[[f64; 3]], what: &'static str, min: usize) -> Result<()> {
    if points.len() < min {
        return Err(Error::TooFewPoints {
            what,
            got: points.len(),
            min,
        });
    }
    if let Some(row) = points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        return Err(Error::NonFinite { what, row });
    }
    Ok(())
}

/// Rejects normals that are not one per point (`one_per` names that rule in the error) or not
/// finite (`what` names them).
pub(crate) fn check_normals(
    normals: &[[f64; 3]],
    n_points: usize,
    what: &'static str,
    one_per: &'static str,
) -> Result<()> {
    if normals.len() != n_points {
        return Err(Error::LengthMismatch {
            what: one_per,
            expected: n_points,
            got: normals.len(),
        });
    }
    check_points(normals, what, 0)
}

/// Rejects a per-point array whose length is not the cloud's (`what` names it and the rule).
pub(crate) fn check_len(got: usize, expected: usize, what: &'static str) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(Error::LengthMismatch {
            what,
            expected,
            got,
        })
    }
}

/// Rejects an index built on another cloud than `points`.
pub(crate) fn check_index(index: &PointIndex, points: &[[f64; 3]]) -> Result<()> {
    if index.len() != points.len() {
        return Err(Error::LengthMismatch {
            what: "indexed points (the index must be built on the same cloud)",
            expected: points.len(),
            got: index.len(),
        });
    }
    Ok(())
}

/// Rejects a radius (or voxel size) that is not a positive finite number.
pub(crate) fn check_positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name,
            value: value.to_string(),
            reason: "must be a positive finite number",
        })
    }
}

/// Rejects a neighbour count below `min`.
pub(crate) fn check_count(name: &'static str, value: usize, min: usize) -> Result<()> {
    if value >= min {
        Ok(())
    } else {
        Err(Error::InvalidParameter {
            name,
            value: value.to_string(),
            reason: "too small",
        })
    }
}
