//! From the kept correspondences to groups, one per candidate instance.

use faer::{Mat, MatRef};

use crate::config::{Assignment, Config};
use crate::correspondences::{Correspondences, Features};
use crate::discretize::discretize;
use crate::error::{Error, Result};
use crate::kmeans::kmeans;
use crate::lanczos::{smallest_eigenpairs, PARTIAL_MIN_ROWS};
use crate::seeds::{stream, STAGE_CLUSTERING};
use crate::spectral::{
    affinity, eigengap, normalized_laplacian, row_normalized_embedding, symmetric_eigen,
};

/// Spectral clustering of one affinity matrix.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralLabels {
    /// One label per row, `0..n_clusters`, numbered by first appearance.
    pub labels: Vec<usize>,
    /// The number of clusters used (the eigengap's choice unless given).
    pub n_clusters: usize,
    /// The smallest eigenvalues of the normalised Laplacian, ascending: all of them below
    /// [`PARTIAL_MIN_ROWS`] rows, otherwise as many as the eigengap search needed.
    pub eigenvalues: Vec<f64>,
}

/// Clusters the rows of a symmetric non-negative affinity. `n_clusters = None` picks the
/// count by the eigengap (at most `max_clusters` when given).
pub fn spectral_clustering(
    a: MatRef<'_, f64>,
    n_clusters: Option<usize>,
    max_clusters: Option<usize>,
    assignment: Assignment,
    restarts: usize,
    seed: u64,
) -> Result<SpectralLabels> {
    let n = a.nrows();
    if let Some(k) = n_clusters.filter(|&k| k == 0 || k > n.max(1)) {
        return Err(Error::InvalidConfig {
            field: "n_clusters",
            value: k.to_string(),
            reason: "must lie in 1..=number of rows",
        });
    }
    let l = normalized_laplacian(a)?;
    let (eigenvalues, vectors) = bottom_spectrum(l.as_ref(), n_clusters, max_clusters, seed)?;
    let m = n_clusters
        .unwrap_or_else(|| eigengap(&eigenvalues, max_clusters))
        .clamp(n.min(1), n);
    let Some(vectors) = vectors else {
        return Ok(SpectralLabels {
            labels: vec![],
            n_clusters: 0,
            eigenvalues,
        });
    };
    let mut rng = stream(seed, STAGE_CLUSTERING, 0);
    let labels = if m <= 1 {
        vec![0; n]
    } else {
        match assignment {
            Assignment::KMeans => {
                let emb = row_normalized_embedding(vectors.as_ref(), m);
                kmeans(&emb, m, m, restarts, &mut rng)
            }
            Assignment::Discretize => discretize(vectors.as_ref(), m, restarts, &mut rng),
        }
    };
    Ok(SpectralLabels {
        labels,
        n_clusters: m,
        eigenvalues,
    })
}

/// First size of the partial spectrum searched for the eigengap.
const FIRST_SPECTRUM: usize = 32;

/// The smallest eigenvalues of `l` (ascending) and their eigenvectors, as many as the count
/// needs: `n_clusters` when given; otherwise enough for the eigengap. Large matrices take the
/// Krylov path ([`smallest_eigenpairs`]) with a spectrum that doubles (from
/// [`FIRST_SPECTRUM`]) until the largest gap lies in its lower half, i.e. until the values
/// past the chosen count have been seen to crowd together; small ones, and any case the
/// Krylov method declines, are decomposed densely (all `n` values).
fn bottom_spectrum(
    l: MatRef<'_, f64>,
    n_clusters: Option<usize>,
    max_clusters: Option<usize>,
    seed: u64,
) -> Result<(Vec<f64>, Option<Mat<f64>>)> {
    let n = l.nrows();
    if n >= PARTIAL_MIN_ROWS {
        if let Some(m) = n_clusters {
            if let Some((vals, vecs)) = smallest_eigenpairs(l, m + 1, seed) {
                return Ok((vals, Some(vecs)));
            }
        } else {
            // the eigengap compares values 1..=cap + 1
            let need = max_clusters.map_or(n, |c| c.clamp(1, n - 1) + 1);
            let mut k = FIRST_SPECTRUM.min(need);
            while let Some((vals, vecs)) = smallest_eigenpairs(l, k, seed) {
                let best = eigengap(&vals, max_clusters.map(|c| c.min(k - 1)));
                if k == need || 2 * best <= k {
                    return Ok((vals, Some(vecs)));
                }
                k = (2 * k).min(need);
            }
        }
    }
    symmetric_eigen(l, true)
}

/// Groups of correspondence indices (into the full input), largest first; groups smaller
/// than `config.min_cluster_size` are dropped. Also returns the eigengap's cluster count.
pub fn cluster_kept(
    c: &Correspondences,
    features: Option<&Features>,
    kept: &[usize],
    config: &Config,
    seed: u64,
) -> Result<(Vec<Vec<usize>>, usize)> {
    if kept.len() < config.min_cluster_size {
        return Ok((vec![], 0));
    }
    let a = affinity(c, features, kept, config.affinity_sigma)?;
    // At most n / min_cluster_size groups can become instances; a larger count would only
    // split isolated rows apart (and cost k-means time), e.g. when pruning is disabled.
    let most = (kept.len() / config.min_cluster_size).max(1);
    let cap = config.max_instances.map_or(most, |m| m.min(most));
    let sl = spectral_clustering(
        a.as_ref(),
        None,
        Some(cap),
        config.assignment,
        config.kmeans_restarts,
        seed,
    )?;
    let mut groups = vec![Vec::new(); sl.n_clusters];
    for (&i, &l) in kept.iter().zip(&sl.labels) {
        groups[l].push(i);
    }
    groups.retain(|g| g.len() >= config.min_cluster_size);
    // Largest first; equal sizes keep their (deterministic) label order.
    groups.sort_by_key(|g| std::cmp::Reverse(g.len()));
    Ok((groups, sl.n_clusters))
}

#[cfg(test)]
#[path = "tests/clustering.rs"]
mod tests;
