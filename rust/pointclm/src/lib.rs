//! # pointclm
//!
//! Multi-instance point cloud registration after PointCLM (ECCV 2022): given putative
//! correspondences between one object (source) and a scene holding several copies of it
//! (target), find the pose `T_target_source` of every copy.
//!
//! The data flows one way: correspondences -> spatial consistency ([`consistency`]) ->
//! density pruning ([`pruning`]) -> spectral clustering ([`clustering`], [`spectral`]) ->
//! per-cluster RANSAC ([`ransac`]) -> instances ([`instances`]), each kept only if its inlier
//! count is statistically significant ([`validation`]). [`register`] runs it all;
//! each stage is public for staged use. With the learned embedding ([`network`], cargo
//! feature `network`, on by default), [`register_with_network`] puts the network's forward
//! pass between consistency and pruning: its unit-norm features turn `S = beta` into
//! `S = S^F * beta`.
//!
//! ```
//! use pointclm::{register, Config, Correspondences};
//!
//! // Three correspondences of a pure translation by (1, 0, 0), repeated 4 times over.
//! let src: Vec<[f64; 3]> = (0..12).map(|i| [(i % 4) as f64 * 0.1, (i / 4) as f64 * 0.1, ((i * 7) % 5) as f64 * 0.05]).collect();
//! let dst: Vec<[f64; 3]> = src.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
//! let corr = Correspondences::new(&src, &dst)?;
//! let config = Config { min_cluster_size: 5, tau_n: 4, ..Config::default() };
//! let result = register(&corr, None, &config, 0)?;
//! assert_eq!(result.instances.len(), 1);
//! let t = result.instances[0].pose.to_matrix();
//! assert!((t[0][3] - 1.0).abs() < 1e-9);
//! # Ok::<(), pointclm::Error>(())
//! ```
//!
//! Starting from point clouds instead, [`scene::register_point_clouds`] runs the whole path
//! (voxel, FPFH, matching, the correspondence stage, ICP and verification, peeling, ranking)
//! and returns every copy's pose; its stages are public in [`scene`], [`pointcloud`] (FPFH,
//! ICP, verification, point pair voting) and [`matching`].
//!
//! No Python, and no I/O beyond reading weight files in [`network`]: other crates can depend
//! on this one directly.

pub mod cancel;
pub mod clustering;
pub mod config;
pub mod consistency;
pub mod correspondences;
mod cpu;
pub mod discretize;
pub mod error;
mod grid;
pub mod instances;
pub mod kabsch;
pub mod kmeans;
pub mod lowest_eigen;
mod magnitude;
pub mod matching;
#[cfg(feature = "network")]
pub mod network;
pub mod pipeline;
pub mod pointcloud;
pub mod pruning;
pub mod ransac;
pub mod scene;
mod seeds;
pub mod spectral;
pub mod symmetry;
#[cfg(test)]
#[path = "tests/support.rs"]
mod testing;
pub mod validation;

// The crate README's examples run with the doctests without becoming the crate's
// rendered docs, whose relative links to examples/ and benches/ would not resolve there.
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;

pub use config::{Assignment, Config, Pruning};
pub use correspondences::{Correspondences, Features, MIN_CORRESPONDENCES};
pub use error::{Error, Result};
pub use instances::Instance;
pub use kabsch::RigidTransform;
pub use matching::{
    match_features, match_features_given, nearest_sources, Matches, MatchingConfig, NearestSources,
};
#[cfg(feature = "network")]
pub use network::{Architecture, Inputs, Network, Normalization};
pub use pipeline::{register, register_batch, Registration, Scene, StageTimings};
#[cfg(feature = "network")]
pub use pipeline::{register_batch_with_network, register_with_network};
