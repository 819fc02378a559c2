//! Which local descriptor the clouds are matched by.
//!
//! The clouds are always described with FPFH first: the scan's normals take their sign from
//! FPFH when no sensor is known ([`describe_scan`](super::describe_scan)). A learned descriptor
//! then replaces the descriptors over the same points and oriented normals, so that every
//! later stage (matching, peeling, heaps) runs unchanged on whichever was chosen.

use std::sync::Arc;

use crate::error::Result;
use crate::network::LearnedDescriptor;
use crate::pointcloud::{Described, PointIndex};

/// The descriptor matching runs on.
#[derive(Debug, Clone, Default)]
pub enum Descriptor {
    /// Open3D's FPFH over 5 voxels.
    #[default]
    Fpfh,
    /// A learned descriptor ([`LearnedDescriptor`]), over its own radius in voxels.
    Learned(Arc<LearnedDescriptor>),
}

impl PartialEq for Descriptor {
    /// The same network object, not equal weights: options compare by what they run.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Self::Fpfh, Self::Fpfh) => true,
            (Self::Learned(a), Self::Learned(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl Descriptor {
    /// `cloud` with this descriptor (FPFH: as it is), described at `voxel`.
    pub fn apply(&self, mut cloud: Described, voxel: f64) -> Result<Described> {
        if let Self::Learned(net) = self {
            let t0 = std::time::Instant::now();
            let index = PointIndex::new(&cloud.points)?;
            cloud.descriptors = net.describe(&cloud.points, &cloud.normals, &index, voxel)?;
            cloud.timings.fpfh += t0.elapsed().as_secs_f64();
        }
        Ok(cloud)
    }
}
