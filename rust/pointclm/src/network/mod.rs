//! The learned correspondence embedding (SCNonlocal, from PointDSC) evaluated in Rust, so
//! that `register` with a trained network needs neither Python nor torch.
//!
//! The network reads the weights that `pointclm.model.save_model` writes: a safetensors file
//! of the torch state dict and, beside it with the extension `.json`, the metadata holding
//! `architecture` (`depth`, `width`, `sigma_d`, for a network with inputs beyond the
//! coordinates `inputs` and `normal_tolerance`, and for one with per-scene normalization
//! `normalization`) and optionally `recommended_config`.
//!
//! # Inputs
//!
//! Every network sees the 6 coordinates of each correspondence (source xyz | target xyz)
//! minus their scene mean, and scales its attention logits by the spatial consistency
//! `beta_ij = [1 - d_ij^2 / sigma_d^2]_+`. A network trained with [`Inputs`] beyond them
//! reads, after those 6 input channels and not centred:
//!
//! - `normals`: the unit surface normals at both ends (source normal | target normal, 6
//!   channels, from [`Correspondences::with_normals`]). Its `beta` is also multiplied by the
//!   normal term of spatial consistency (see `with_normals`), with the architecture's
//!   `normal_tolerance` rather than the tolerance the correspondences were given.
//! - `similarity`: the descriptor similarity of each match (1 channel, from
//!   [`Correspondences::with_similarity`]); it does not enter `beta`.
//!
//! [`Network::embed`] fails with [`Error::MissingInput`](crate::Error::MissingInput) when
//! the correspondences lack an input the network needs, and ignores those it does not need.
//!
//! The forward pass computes in `f32`, as torch does, so that it reproduces torch's
//! embeddings to about 1e-6. The attention `softmax_j(beta_ij q_i . k_j / sqrt(width))` is evaluated
//! for a block of rows at a time, recomputing `beta` on the fly, so memory stays
//! O(N x block) and no N x N matrix is ever formed.
//!
//! # Normalization
//!
//! What the BatchNorms normalise with ([`Normalization`], `architecture.normalization`):
//!
//! - `running` (the default, and the shipped networks'): the statistics gathered in
//!   training. Each eval-mode BatchNorm is then an affine map, folded into the convolution
//!   before it at load time.
//! - `scene`: the mean and biased variance of the BatchNorm's own input over the scene's N
//!   rows, as torch's `SceneBatchNorm` does at inference too (for networks trained one scene
//!   per batch, whose running statistics fit no scene). Every BatchNorm then needs all N
//!   rows before any row can go on, so the forward pass splits its sweeps at each of them
//!   (see `scene_norm`); the running statistics in the file are read but unused. A scene of
//!   one correspondence has variance 0 and gets each BatchNorm's bias.
//!
//! ```
//! # fn main() -> pointclm::Result<()> {
//! use pointclm::network::Network;
//! use pointclm::{register_with_network, Correspondences};
//!
//! let weights = concat!(env!("CARGO_MANIFEST_DIR"), "/../../python/pointclm/weights/default.safetensors");
//! let network = Network::from_file(weights)?;
//! let src: Vec<[f64; 3]> = (0..40).map(|i| [(i % 5) as f64 * 0.1, (i / 5) as f64 * 0.05, (i % 3) as f64 * 0.07]).collect();
//! let dst: Vec<[f64; 3]> = src.iter().map(|p| [p[0] + 1.0, p[1], p[2]]).collect();
//! let corr = Correspondences::new(&src, &dst)?;
//! let features = network.embed(&corr)?;
//! assert_eq!((features.len(), features.dim()), (40, network.architecture().width));
//! let result = register_with_network(&corr, &network, &network.recommended_config(), 0)?;
//! assert_eq!(result.labels.len(), 40);
//! # Ok(())
//! # }
//! ```

mod descriptor;
mod forward;
pub(crate) mod layers;
mod scene_norm;
pub(crate) mod sparse_attention;
mod weights;

pub use descriptor::{LearnedDescriptor, PAIR_FEATURES};
pub use forward::MAX_DENSE_ATTENTION_ROWS;

use std::fmt;
use std::path::Path;

use crate::config::Config;
use crate::correspondences::{Correspondences, Features, DEFAULT_NORMAL_TOLERANCE};
use crate::error::Result;

use layers::{Dense, SceneNorm};

/// The shape of an SCNonlocal network, as stored under `architecture` in the weights' JSON.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Architecture {
    /// Number of [pointcn, non-local] blocks.
    pub depth: usize,
    /// Channels of every block (even; the message MLP narrows to `width / 2`).
    pub width: usize,
    /// Length tolerance of the `beta` that scales the attention logits.
    pub sigma_d: f64,
    /// The inputs beyond the 6 coordinates (none for the plain network).
    pub inputs: Inputs,
    /// Cosine tolerance of the normal term of `beta` (used with [`Inputs::normals`] only;
    /// [`DEFAULT_NORMAL_TOLERANCE`] where the metadata gives none).
    pub normal_tolerance: f64,
    /// What the BatchNorms normalise with ([`Normalization::Running`] where the metadata
    /// says nothing).
    pub normalization: Normalization,
}

impl Architecture {
    /// The plain network (coordinates only) of this shape.
    pub fn plain(depth: usize, width: usize, sigma_d: f64) -> Self {
        Self {
            depth,
            width,
            sigma_d,
            inputs: Inputs::default(),
            normal_tolerance: DEFAULT_NORMAL_TOLERANCE,
            normalization: Normalization::Running,
        }
    }

    /// Channels of the network's input: 6 coordinates, then those of [`Inputs`].
    pub fn input_channels(&self) -> usize {
        6 + self.inputs.channels()
    }
}

/// What every BatchNorm of the network normalises with at inference.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Normalization {
    /// The running statistics gathered in training (folded into the convolutions).
    #[default]
    Running,
    /// The mean and biased variance of the BatchNorm's input over the scene's rows.
    Scene,
}

impl Normalization {
    /// The name the weights' metadata writes (`"running"`, `"scene"`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Running => "running",
            Self::Scene => "scene",
        }
    }
}

/// The inputs a network reads beyond the coordinates, in the order of their input channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Inputs {
    /// Unit normals at both ends (6 channels), which also enter the attention's `beta`.
    pub normals: bool,
    /// The descriptor similarity of each match (1 channel).
    pub similarity: bool,
}

impl Inputs {
    /// The input names as the weights' metadata writes them, in channel order.
    pub const NAMES: [&'static str; 2] = ["normals", "similarity"];

    /// The names of the inputs in use, in channel order.
    pub fn names(&self) -> Vec<&'static str> {
        let used = [self.normals, self.similarity];
        Self::NAMES
            .into_iter()
            .zip(used)
            .filter_map(|(name, on)| on.then_some(name))
            .collect()
    }

    /// Input channels beyond the 6 coordinates.
    pub fn channels(&self) -> usize {
        6 * usize::from(self.normals) + usize::from(self.similarity)
    }
}

/// A trained embedding network, ready to evaluate: `Send + Sync`, so one loaded network
/// serves any number of threads.
pub struct Network {
    architecture: Architecture,
    recommended: Config,
    lift: Dense,
    blocks: Vec<Block>,
}

/// One [pointcn, non-local] block. `q`, `k` and `v` share their input, so they are one
/// `width -> 3 width` product.
///
/// With [`Normalization::Scene`] the convolutions before BatchNorms are unfolded and `scene`
/// holds those BatchNorms' affine parameters: pointcn's, then the message MLP's two.
pub(crate) struct Block {
    pointcn: Dense,
    qkv: Dense,
    message: [Dense; 3],
    scene: Option<Box<[SceneNorm; 3]>>,
}

impl Network {
    /// Loads `path` (the `.safetensors` file) and the `.json` beside it.
    ///
    /// Errors: [`Error::WeightsNotFound`](crate::Error::WeightsNotFound) when either file is
    /// missing or unreadable, [`Error::WeightsMalformed`](crate::Error::WeightsMalformed)
    /// for a corrupt file or invalid metadata, [`Error::TensorMissing`](crate::Error::TensorMissing)
    /// and [`Error::TensorShape`](crate::Error::TensorShape) when the tensors do not match
    /// the architecture.
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        weights::read_file(path.as_ref())
    }

    /// From the bytes of a safetensors file and the text of its JSON metadata (`name` is
    /// used in error messages only).
    pub fn from_bytes(safetensors: &[u8], metadata: &str, name: &str) -> Result<Self> {
        weights::from_bytes(safetensors, metadata, name)
    }

    /// Depth, width, `sigma_d`, inputs and normalization of the network.
    pub fn architecture(&self) -> Architecture {
        self.architecture
    }

    /// The defaults with the thresholds stored under `recommended_config` in the metadata
    /// (chosen with this network on its validation data); the plain defaults if there are
    /// none.
    pub fn recommended_config(&self) -> Config {
        self.recommended.clone()
    }

    /// Unit-norm embeddings, one `width`-vector per correspondence.
    ///
    /// Blocks of rows run in parallel on the current rayon pool; the result is bit-identical
    /// whatever the number of threads, since the blocks are fixed and each is computed
    /// sequentially. Errors with [`Error::NonFinite`](crate::Error::NonFinite) when
    /// coordinates are too large for `f32`, and with
    /// [`Error::MissingInput`](crate::Error::MissingInput) when `c` lacks an input of the
    /// [architecture](Architecture::inputs) (normals or similarities).
    pub fn embed(&self, c: &Correspondences) -> Result<Features> {
        forward::embed(self, c, true, forward::BLOCK_ROWS)
    }

    /// [`Network::embed`] on the calling thread only (for callers that already parallelise,
    /// e.g. over scenes).
    pub fn embed_sequential(&self, c: &Correspondences) -> Result<Features> {
        forward::embed(self, c, false, forward::BLOCK_ROWS)
    }
}

impl fmt::Debug for Network {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Network")
            .field("architecture", &self.architecture)
            .field("recommended", &self.recommended)
            .finish_non_exhaustive()
    }
}

#[cfg(test)]
#[path = "../tests/network.rs"]
mod tests;
