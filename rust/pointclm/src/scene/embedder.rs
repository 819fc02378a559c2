//! The learned embedding of a pass's correspondences, as the scene pipeline asks for it: an
//! [`Embedder`] says which cues it takes and embeds the correspondences of every pass.

use crate::correspondences::{Correspondences, Features};
use crate::error::{Error, Result};
use crate::network::Network;
use crate::pointcloud::check_positive;

/// Computes the learned embedding of a pass's correspondences (the features the correspondence
/// stage prunes and clusters with, `S = S^F * beta`). The scene pipeline attaches the cues it
/// takes to the correspondences first: the normals at both ends and the descriptor
/// similarity ([`similarity`]).
pub trait Embedder: Sync {
    /// Whether it reads the unit normals at both ends of each correspondence.
    fn takes_normals(&self) -> bool;
    /// Whether it reads each correspondence's descriptor similarity.
    fn takes_similarity(&self) -> bool;
    /// One row per correspondence, in the clouds' units.
    fn embed(&self, correspondences: &Correspondences) -> Result<Features>;
}

/// Descriptor distances as similarities `m / (d + m)` in (0, 1], `m` their median: scale-free,
/// so a network trained on one descriptor scale reads another's. When more than half the
/// matches are exact the mean scales instead; all-zero distances give 1 everywhere.
pub fn similarity(distances: &[f64]) -> Vec<f64> {
    if distances.is_empty() {
        return Vec::new();
    }
    let mut sorted = distances.to_vec();
    let mut m = super::median(&mut sorted);
    if m <= 0.0 {
        let mean = distances.iter().sum::<f64>() / distances.len() as f64;
        m = if mean == 0.0 { 1.0 } else { mean };
    }
    distances.iter().map(|d| m / (d + m)).collect()
}

/// A trained [`Network`] as the scene pipeline's embedder: each pass's correspondences are
/// centred per side and scaled into the network's training units (`sigma_d` of its
/// architecture over the pipeline's `sigma_d`, [`crate::Config::sigma_d`] in the clouds'
/// units), so that it attends with the length tolerance it was trained with; the normals and
/// similarity it reads are passed on.
pub struct NetworkEmbedder<'a> {
    pub network: &'a Network,
    /// The correspondence stage's `sigma_d`, in the clouds' units.
    pub sigma_d: f64,
}

impl Embedder for NetworkEmbedder<'_> {
    fn takes_normals(&self) -> bool {
        self.network.architecture().inputs.normals
    }

    fn takes_similarity(&self) -> bool {
        self.network.architecture().inputs.similarity
    }

    fn embed(&self, c: &Correspondences) -> Result<Features> {
        check_positive("sigma_d", self.sigma_d)?;
        let arch = self.network.architecture();
        let scale = arch.sigma_d / self.sigma_d;
        let src: Vec<[f64; 3]> = (0..c.len()).map(|i| c.source(i)).collect();
        let tgt: Vec<[f64; 3]> = (0..c.len()).map(|i| c.target(i)).collect();
        let units = |side: &[[f64; 3]]| -> Vec<[f64; 3]> {
            let m = super::mean_point(side);
            side.iter()
                .map(|p| {
                    [
                        (p[0] - m[0]) * scale,
                        (p[1] - m[1]) * scale,
                        (p[2] - m[2]) * scale,
                    ]
                })
                .collect()
        };
        let mut x = Correspondences::new(&units(&src), &units(&tgt))?;
        if arch.inputs.normals {
            let missing = Error::MissingInput {
                input: "normals",
                hint: "the network reads the normals at both ends of each correspondence",
            };
            let pairs: Vec<_> = (0..c.len())
                .map(|i| c.normals(i).ok_or(missing.clone()))
                .collect::<Result<_>>()?;
            let (ns, nt): (Vec<[f64; 3]>, Vec<[f64; 3]>) = pairs.into_iter().unzip();
            x = x.with_normals(&ns, &nt, arch.normal_tolerance)?;
        }
        if let (true, Some(s)) = (arch.inputs.similarity, c.similarity()) {
            x = x.with_similarity(s)?;
        }
        self.network.embed(&x)
    }
}
