//! Descriptor matching: from per-point descriptors of the source (the model) and the target
//! (the scene) to putative correspondences, as the paper's appendix builds them for Scan2CAD.
//!
//! Every target point is matched to its most similar source descriptor; the descriptor
//! distance is its saliency score. The `top_k` most salient matches are kept (optionally only
//! mutual nearest neighbours), then `n_samples` of them are drawn at random, so that the
//! pipeline sees a bounded number of correspondences whatever the cloud sizes.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use rand::seq::index::sample;
use rayon::prelude::*;

use crate::correspondences::Features;
use crate::error::{Error, Result};
use crate::seeds::{stream, STAGE_MATCHING};

/// How many matches to keep and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchingConfig {
    /// Keep the `top_k` matches with the smallest descriptor distance (paper: 10,000).
    pub top_k: usize,
    /// Keep only mutual nearest neighbours (the source descriptor's nearest target
    /// descriptor is the target point that chose it).
    pub mutual: bool,
    /// Then draw this many of them uniformly at random (paper: 1000); `None` keeps all.
    pub n_samples: Option<usize>,
}

impl Default for MatchingConfig {
    fn default() -> Self {
        Self {
            top_k: 10_000,
            mutual: false,
            n_samples: Some(1000),
        }
    }
}

/// Matched pairs, most salient (smallest descriptor distance) first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Matches {
    /// Row of the source descriptor (source point index).
    pub source: Vec<usize>,
    /// Row of the target descriptor (target point index).
    pub target: Vec<usize>,
    /// Euclidean distance between the two descriptors.
    pub distance: Vec<f64>,
}

impl Matches {
    /// Number of matches.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    /// True when nothing matched.
    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }
}

/// Matches every target descriptor to its nearest source descriptor, then keeps and samples
/// as `config` says. Parallel over target rows on the current rayon pool; the result depends
/// only on the inputs and `seed`.
pub fn match_features(
    source: &Features,
    target: &Features,
    config: &MatchingConfig,
    seed: u64,
) -> Result<Matches> {
    if source.is_empty() || target.is_empty() {
        return Err(Error::TooFewPoints {
            what: if source.is_empty() {
                "source descriptors"
            } else {
                "target descriptors"
            },
            got: 0,
            min: 1,
        });
    }
    if source.dim() != target.dim() {
        return Err(Error::LengthMismatch {
            what: "target descriptor length (must equal the source's)",
            expected: source.dim(),
            got: target.dim(),
        });
    }
    if config.top_k == 0 {
        return Err(Error::InvalidParameter {
            name: "top_k",
            value: "0".into(),
            reason: "must keep at least one match",
        });
    }
    if config.n_samples == Some(0) {
        return Err(Error::InvalidParameter {
            name: "n_samples",
            value: "0".into(),
            reason: "must sample at least one match (or None for all)",
        });
    }

    let (src_of_tgt, dist2) = nearest_rows(target, source);
    let mut order: Vec<usize> = (0..target.len()).collect();
    if config.mutual {
        let (tgt_of_src, _) = nearest_rows(source, target);
        order.retain(|&t| tgt_of_src[src_of_tgt[t]] == t);
    }
    // Ties broken by target index, so the order is total and reproducible.
    order.sort_unstable_by(|&a, &b| dist2[a].total_cmp(&dist2[b]).then(a.cmp(&b)));
    order.truncate(config.top_k);
    if let Some(n) = config.n_samples {
        if n < order.len() {
            let mut rng = stream(seed, STAGE_MATCHING, 0);
            let mut picked = sample(&mut rng, order.len(), n).into_vec();
            picked.sort_unstable();
            order = picked.into_iter().map(|k| order[k]).collect();
        }
    }
    Ok(Matches {
        source: order.iter().map(|&t| src_of_tgt[t]).collect(),
        target: order.clone(),
        distance: order.iter().map(|&t| dist2[t].max(0.0).sqrt()).collect(),
    })
}

/// Rows of queries handled per matrix product: large enough for an efficient product, small
/// enough that a block of distances (`BLOCK x base rows`) stays in cache-sized memory.
const BLOCK: usize = 128;

/// For every query row, the nearest base row and the squared distance to it (exact brute
/// force: `|q|^2 + |b|^2 - 2 q.b` by blocked matrix products, then the winner's distance
/// recomputed directly so that no cancellation error is reported).
fn nearest_rows(queries: &Features, base: &Features) -> (Vec<usize>, Vec<f64>) {
    let dim = base.dim();
    let base_mat = Mat::<f64>::from_fn(base.len(), dim, |i, j| base.row(i)[j]);
    let base_norm: Vec<f64> = (0..base.len())
        .map(|i| base.row(i).iter().map(|v| v * v).sum())
        .collect();
    let n = queries.len();
    let blocks: Vec<(Vec<usize>, Vec<f64>)> = (0..n.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let lo = b * BLOCK;
            let hi = (lo + BLOCK).min(n);
            let q = Mat::<f64>::from_fn(dim, hi - lo, |j, i| queries.row(lo + i)[j]);
            // Column i of g holds q_i . b_j for every base row j, contiguous in j.
            let mut g = Mat::<f64>::zeros(base.len(), hi - lo);
            matmul(
                g.as_mut(),
                Accum::Replace,
                base_mat.as_ref(),
                q.as_ref(),
                1.0,
                Par::Seq,
            );
            let mut best = Vec::with_capacity(hi - lo);
            let mut best_d2 = Vec::with_capacity(hi - lo);
            for i in 0..hi - lo {
                let col = g.col_as_slice(i);
                let mut arg = 0;
                let mut min = f64::INFINITY;
                for (j, (&bn, &dot)) in base_norm.iter().zip(col).enumerate() {
                    let v = bn - 2.0 * dot;
                    if v < min {
                        min = v;
                        arg = j;
                    }
                }
                let exact: f64 = queries
                    .row(lo + i)
                    .iter()
                    .zip(base.row(arg))
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum();
                best.push(arg);
                best_d2.push(exact);
            }
            (best, best_d2)
        })
        .collect();
    let mut idx = Vec::with_capacity(n);
    let mut d2 = Vec::with_capacity(n);
    for (a, b) in blocks {
        idx.extend(a);
        d2.extend(b);
    }
    (idx, d2)
}

#[cfg(test)]
#[path = "tests/matching.rs"]
mod tests;
