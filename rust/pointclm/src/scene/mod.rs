//! Registration of a model in a scan, as the stages after the correspondence stage see it:
//! the scene-wide parameters ([`SceneRules`]), the peeling of what accepted copies explain
//! ([`peeling`]) and the final ranking of the copies against one another ([`ranking`]).
//!
//! The stages run in this order for each call: the scan's sensor and viewpoint, description
//! (normals and FPFH, [`crate::pointcloud`]), matching ([`crate::matching`]), proposals
//! ([`crate::register`], and point pair voting in a heap, [`crate::pointcloud::PpfModel`]),
//! verification ([`crate::pointcloud::RefineContext`]), peeling, flips, ranking. Every stage
//! works against one index of the scan, the one its [`crate::pointcloud::RefineContext`] holds.

pub mod peeling;
pub mod ranking;
pub mod register;
pub mod rules;
pub mod voxel;

pub use register::{
    cloud_config, register_point_clouds, Candidate, Pass, SceneOptions, SceneRegistration,
};
pub use rules::SceneRules;

#[cfg(test)]
#[path = "../tests/scene.rs"]
mod tests;
