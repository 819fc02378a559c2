//! Registration of a model in a scan, as the stages after the correspondence stage see it:
//! the scene-wide parameters ([`SceneRules`]), the peeling of what accepted copies explain
//! ([`peeling`]) and the final ranking of the copies against one another ([`ranking`]).
//!
//! The stages run in this order for each call: the scan's sensor and viewpoint, description
//! (normals and FPFH, [`crate::pointcloud`]), matching ([`crate::matching`]), proposals
//! ([`crate::register`], and point pair voting in a heap, [`crate::pointcloud::PpfModel`]),
//! verification ([`crate::pointcloud::RefineContext`]), peeling, turned alternatives
//! ([`flips`]), ranking. Every stage
//! works against one index of the scan, the one its [`crate::pointcloud::RefineContext`] holds.
//!
//! ```
//! use pointclm::kabsch::RigidTransform;
//! use pointclm::scene::{register_point_clouds, SceneOptions};
//!
//! // A bumpy blob (distinctive for FPFH), and a scan of two copies of it, one moved.
//! let model: Vec<[f64; 3]> = (0..2000)
//!     .map(|i| {
//!         let (th, z) = (i as f64 * 2.399_963, 1.0 - 2.0 * (i as f64 + 0.5) / 2000.0);
//!         let r = (1.0 - z * z).sqrt();
//!         let d = [r * th.cos(), r * th.sin(), z];
//!         let bump = 1.0 + 0.3 * (3.0 * d[0]).sin() * (2.0 * d[1]).cos() + 0.2 * d[2];
//!         d.map(|v| v * bump)
//!     })
//!     .collect();
//! let moved = RigidTransform {
//!     translation: [4.0, 0.0, 0.0].into(),
//!     ..RigidTransform::identity()
//! };
//! let mut scan = model.clone();
//! scan.extend(model.iter().map(|&p| moved.apply(p)));
//! let found = register_point_clouds(&model, &scan, &SceneOptions::default())?;
//! assert_eq!(found.candidates.len(), 2);
//! for copy in &found.candidates {
//!     println!("confidence {:.2} at {:?}", copy.confidence, copy.pose.translation);
//! }
//! # Ok::<(), pointclm::Error>(())
//! ```

pub mod descriptor;
pub mod embedder;
pub mod faces;
pub mod flips;
pub mod joint;
pub mod peeling;
pub mod ranking;
pub mod register;
pub mod rules;
pub mod sensor;
pub mod voxel;
mod window;

pub use descriptor::Descriptor;
pub use embedder::{similarity, Embedder, NetworkEmbedder};
pub use faces::{FaceProposer, Proposals};
pub use flips::{flip_turns, quarter_turns, resolve_flips, resolve_flips_with_symmetry};
pub use joint::{judge_jointly, register_models, JointVerdict, ModelPoses};
pub use register::{
    cloud_base_config, cloud_config, config_for_voxel, register_point_clouds,
    register_point_clouds_with, Candidate, MutualWindow, Pass, SceneOptions, SceneRegistration,
    SceneTimings, INLIER_VOXELS, SIGMA_D_VOXELS,
};
pub use rules::SceneRules;
pub use sensor::{describe_scan, DescribedScan};

/// The mean of `points` (a plain sum then one division, as numpy's `mean(axis=0)` rounds it, so
/// that the Python and Rust pipelines orient and turn about the same centre). `points` must
/// not be empty.
pub(crate) fn mean_point(points: &[[f64; 3]]) -> [f64; 3] {
    let mut sum = [0.0; 3];
    for p in points {
        for (s, v) in sum.iter_mut().zip(p) {
            *s += v;
        }
    }
    let n = points.len() as f64;
    sum.map(|s| s / n)
}

/// The median of `values` (the mean of the middle two for an even count; 0 for none); sorts
/// them.
pub(crate) fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    let mid = values.len() / 2;
    if values.len() % 2 == 1 {
        values[mid]
    } else {
        (values[mid - 1] + values[mid]) / 2.0
    }
}

#[cfg(test)]
#[path = "../tests/scene.rs"]
mod tests;
