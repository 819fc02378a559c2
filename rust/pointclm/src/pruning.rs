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
mod tests {
    use super::*;
    use crate::consistency::spatial_consistency;
    use crate::testing::random_scene;

    fn features_for(n: usize, seed: u64) -> Features {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut data = Vec::with_capacity(n * 8);
        for _ in 0..n {
            let v: Vec<f64> = (0..8).map(|_| rng.random::<f64>() - 0.3).collect();
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            data.extend(v.iter().map(|x| x / norm));
        }
        Features::new(data, 8).unwrap()
    }

    #[test]
    fn blocked_and_dense_counts_agree_exactly() {
        // 301 rows: not a multiple of the block size
        let scene = random_scene(301, 3, 0.2, 5);
        let n = scene.corr.len();
        let feats = features_for(n, 1);
        for pruning in [Pruning::Paper, Pruning::AuthorsCode, Pruning::Disabled] {
            let config = Config {
                pruning,
                ..Config::default()
            };
            let beta = spatial_consistency(&scene.corr, config.sigma_d).unwrap();
            for f in [None, Some(&feats)] {
                let blocked = density_counts(&scene.corr, f, &config).unwrap();
                let dense = density_counts_dense(&beta, n, f, &config);
                assert_eq!(blocked, dense, "{pruning:?} features={}", f.is_some());
            }
        }
    }

    #[test]
    fn inliers_survive_and_outliers_go() {
        let scene = random_scene(1000, 4, 0.04, 9);
        let config = Config::default();
        let counts = density_counts(&scene.corr, None, &config).unwrap();
        let kept = select_kept(&counts, &config);
        let kept_inliers = kept.iter().filter(|&&i| scene.labels[i] >= 0).count();
        let inliers = scene.labels.iter().filter(|&&l| l >= 0).count();
        assert!(kept_inliers as f64 >= 0.9 * inliers as f64);
        assert!(
            kept.len() - kept_inliers <= 20,
            "{} outliers kept",
            kept.len() - kept_inliers
        );
    }

    #[test]
    fn cap_keeps_the_densest() {
        let counts = vec![50, 12, 40, 11, 30];
        let config = Config {
            max_kept: 10.max(Config::default().min_cluster_size),
            ..Config::default()
        };
        assert_eq!(select_kept(&counts, &config), vec![0, 1, 2, 3, 4]);
        let config = Config {
            max_kept: 10,
            min_cluster_size: 3,
            ..Config::default()
        };
        let many: Vec<u32> = (0..20).map(|i| 11 + i).collect();
        let kept = select_kept(&many, &config);
        assert_eq!(kept, (10..20).collect::<Vec<_>>());
    }
}
