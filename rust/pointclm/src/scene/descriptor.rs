//! Which local descriptor the clouds are matched by.
//!
//! The clouds are always described with FPFH first: the scan's normals take their sign from
//! FPFH when no sensor is known ([`describe_scan`](super::describe_scan)). A learned descriptor
//! then replaces the descriptors over the same points and oriented normals, or joins them,
//! so that every later stage (matching, peeling, heaps) runs unchanged on whichever was chosen.

use std::sync::Arc;

use crate::correspondences::Features;
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
    /// FPFH and a learned descriptor side by side, each of unit length, so that each counts
    /// alike in a match's distance: a match must look alike to both. The learned one finds
    /// more true matches than FPFH, FPFH rejects some of its look-alikes.
    FpfhAndLearned(Arc<LearnedDescriptor>),
    /// Decided by the model's shape: FPFH alone for a mostly planar model (at least
    /// `SceneRules::min_planar_share` of it in large flat faces, the rule that switches face
    /// proposals on), FPFH and the learned one beside it for any other. Why: on a flat face
    /// every neighbourhood looks alike to any local descriptor, and the learned one only adds
    /// look-alikes there (a box's copies with 3 true matches 0.12 -> 0.08), while on curved
    /// parts it finds most of the true matches FPFH misses (BENCHMARKS.md, learned descriptor).
    Auto(Arc<LearnedDescriptor>),
}

impl PartialEq for Descriptor {
    /// The same network object, not equal weights: options compare by what they run.
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Self::Fpfh, Self::Fpfh) => true,
            (Self::Learned(a), Self::Learned(b)) => Arc::ptr_eq(a, b),
            (Self::FpfhAndLearned(a), Self::FpfhAndLearned(b)) => Arc::ptr_eq(a, b),
            (Self::Auto(a), Self::Auto(b)) => Arc::ptr_eq(a, b),
            _ => false,
        }
    }
}

impl Descriptor {
    /// What this descriptor is for a model with `planar_share` of its points in large flat
    /// faces ([`Self::Auto`] decided at `min_planar_share`; the others as they are).
    pub fn for_model(&self, planar_share: f64, min_planar_share: f64) -> Self {
        match self {
            Self::Auto(_) if planar_share >= min_planar_share => Self::Fpfh,
            Self::Auto(net) => Self::FpfhAndLearned(Arc::clone(net)),
            other => other.clone(),
        }
    }

    /// Whether the model's planar share is needed to decide ([`Self::Auto`]).
    pub fn by_shape(&self) -> bool {
        matches!(self, Self::Auto(_))
    }

    /// Its name as `register_point_clouds(descriptor=...)` takes it.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Fpfh => "fpfh",
            Self::Learned(_) => "learned",
            Self::FpfhAndLearned(_) => "fpfh+learned",
            Self::Auto(_) => "auto",
        }
    }

    /// `cloud` with this descriptor (FPFH: as it is), described at `voxel`; [`Self::Auto`]
    /// must be decided first ([`Self::for_model`]).
    pub fn apply(&self, mut cloud: Described, voxel: f64) -> Result<Described> {
        let (net, join) = match self {
            Self::Fpfh => return Ok(cloud),
            Self::Learned(net) => (net, false),
            Self::FpfhAndLearned(net) | Self::Auto(net) => (net, true),
        };
        let t0 = std::time::Instant::now();
        let index = PointIndex::new(&cloud.points)?;
        let learned = net.describe(&cloud.points, &cloud.normals, &index, voxel)?;
        cloud.descriptors = if join {
            joined(&cloud.descriptors, &learned)?
        } else {
            learned
        };
        cloud.timings.fpfh += t0.elapsed().as_secs_f64();
        Ok(cloud)
    }
}

/// Each row of `a` scaled to unit length (a zero row stays zero), then the row of `b` (unit
/// length already).
fn joined(a: &Features, b: &Features) -> Result<Features> {
    let mut data = Vec::with_capacity(a.len() * (a.dim() + b.dim()));
    for i in 0..a.len() {
        let row = a.row(i);
        let norm = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        let scale = if norm > 0.0 { 1.0 / norm } else { 0.0 };
        data.extend(row.iter().map(|v| v * scale));
        data.extend_from_slice(b.row(i));
    }
    Features::new(data, a.dim() + b.dim())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joined_rows_hold_unit_fpfh_then_the_learned_row() {
        let fpfh = Features::new(vec![3.0, 4.0, 0.0, 0.0, 0.0, 0.0], 3).unwrap();
        let learned = Features::new(vec![1.0, 0.0, 0.0, 1.0], 2).unwrap();
        let j = joined(&fpfh, &learned).unwrap();
        assert_eq!(j.dim(), 5);
        let expected = [0.6, 0.8, 0.0, 1.0, 0.0];
        assert!(j
            .row(0)
            .iter()
            .zip(expected)
            .all(|(a, b)| (a - b).abs() < 1e-12));
        // A point without FPFH neighbours keeps a zero FPFH part, not NaN.
        assert_eq!(j.row(1), &[0.0, 0.0, 0.0, 0.0, 1.0]);
    }
}
