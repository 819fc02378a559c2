//! Density pruning: inliers of one instance are mutually consistent and form dense rows of
//! `S`, while outliers are consistent with few others. Only per-row counts are needed, so rows
//! are computed block by block in parallel and memory stays O(block x N).

use rayon::prelude::*;

use crate::config::{Config, Pruning};
use crate::consistency::{beta_row, inv_sigma_sq};
use crate::correspondences::{Correspondences, Features};
use crate::error::Result;

/// Rows per parallel task: large enough to amortise scheduling, small enough to balance.
const BLOCK_ROWS: usize = 32;

/// How many `j` (including `i` itself) count as consistent with each `i` under the rule.
/// `Pruning::Disabled` gives all zeros.
pub fn density_counts(
    c: &Correspondences,
    features: Option<&Features>,
    config: &Config,
) -> Result<Vec<u32>> {
    let n = c.len();
    if let Some(f) = features {
        f.check_rows(n)?;
    }
    if config.pruning == Pruning::Disabled {
        return Ok(vec![0; n]);
    }
    let inv = inv_sigma_sq(config.sigma_d)?;
    let mut counts = vec![0u32; n];
    counts
        .par_chunks_mut(BLOCK_ROWS)
        .enumerate()
        .for_each(|(block, out)| {
            let mut row = vec![0.0; n];
            for (k, slot) in out.iter_mut().enumerate() {
                let i = block * BLOCK_ROWS + k;
                beta_row(c, i, inv, &mut row);
                *slot = count_row(i, &row, features, config);
            }
        });
    Ok(counts)
}

/// Same counts from an explicit dense `beta` matrix (row-major `N x N`); the unblocked
/// reference that tests compare [`density_counts`] against.
pub fn density_counts_dense(
    beta: &[f64],
    n: usize,
    features: Option<&Features>,
    config: &Config,
) -> Vec<u32> {
    if config.pruning == Pruning::Disabled {
        return vec![0; n];
    }
    (0..n)
        .map(|i| count_row(i, &beta[i * n..(i + 1) * n], features, config))
        .collect()
}

#[inline]
fn count_row(i: usize, beta: &[f64], features: Option<&Features>, config: &Config) -> u32 {
    match (config.pruning, features) {
        (Pruning::Paper, None) => beta.iter().filter(|&&b| b > config.tau_s).count() as u32,
        (Pruning::Paper, Some(f)) => beta
            .iter()
            .enumerate()
            // beta == 0 makes S == 0 whatever the features: skip the dot product
            .filter(|&(j, &b)| b > 0.0 && b * f.similarity(i, j) > config.tau_s)
            .count() as u32,
        (Pruning::AuthorsCode, None) => {
            beta.iter().filter(|&&b| b > config.beta_threshold).count() as u32
        }
        (Pruning::AuthorsCode, Some(f)) => beta
            .iter()
            .enumerate()
            .filter(|&(j, &b)| {
                b > config.beta_threshold && f.similarity(i, j) > config.feature_threshold
            })
            .count() as u32,
        (Pruning::Disabled, _) => 0,
    }
}

/// Indices (ascending) of the correspondences that survive pruning, at most
/// `config.max_kept`: when more survive, the densest rows win (ties by index), since a high
/// count is the evidence of being an inlier.
pub fn select_kept(counts: &[u32], config: &Config) -> Vec<usize> {
    let min = match config.pruning {
        Pruning::Paper => config.tau_n,
        Pruning::AuthorsCode => config.min_count,
        Pruning::Disabled => {
            let n = counts.len().min(config.max_kept);
            return (0..n).collect();
        }
    };
    let mut kept: Vec<usize> = (0..counts.len())
        .filter(|&i| counts[i] as usize > min)
        .collect();
    if kept.len() > config.max_kept {
        kept.sort_by(|&a, &b| counts[b].cmp(&counts[a]).then(a.cmp(&b)));
        kept.truncate(config.max_kept);
        kept.sort_unstable();
    }
    kept
}

#[cfg(test)]
#[path = "tests/pruning.rs"]
mod tests;
