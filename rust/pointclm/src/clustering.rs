//! From the kept correspondences to groups, one per candidate instance.

use faer::MatRef;

use crate::config::{Assignment, Config};
use crate::correspondences::{Correspondences, Features};
use crate::discretize::discretize;
use crate::error::{Error, Result};
use crate::kmeans::kmeans;
use crate::lowest_eigen::lowest_eigenpairs;
use crate::seeds::{stream, STAGE_CLUSTERING};
use crate::spectral::{
    affinity, eigengap, normalized_laplacian, row_normalized_embedding, symmetric_eigen,
    symmetric_eigen_f32, SINGLE_PRECISION_ROWS,
};

/// Spectral clustering of one affinity matrix.
#[derive(Debug, Clone, PartialEq)]
pub struct SpectralLabels {
    /// One label per row, `0..n_clusters`, numbered by first appearance.
    pub labels: Vec<usize>,
    /// The number of clusters used (the eigengap's choice unless given).
    pub n_clusters: usize,
    /// Eigenvalues of the normalised Laplacian, ascending: all of them below
    /// [`PARTIAL_ROWS`] rows (in f32 arithmetic from [`SINGLE_PRECISION_ROWS`] rows), from
    /// there the lowest ones the partial solver found ([`suffices`]): right to its tolerance
    /// up to the eigengap, only roughly in the dense rest of the spectrum.
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
    let count = n_clusters.map_or(
        Count::Eigengap {
            cap: max_clusters,
            level: None,
        },
        Count::Fixed,
    );
    spectral_clustering_by(a, count, assignment, restarts, seed)
}

/// How [`spectral_clustering_by`] picks the number of clusters.
#[derive(Clone, Copy, Debug)]
pub enum Count {
    /// Exactly this many.
    Fixed(usize),
    /// The eigengap's choice, raised to the number of eigenvalues below `level` when given
    /// ([`Config::cluster_level`](crate::Config::cluster_level)), at most `cap`.
    Eigengap {
        cap: Option<usize>,
        level: Option<f64>,
    },
}

/// [`spectral_clustering`] with the count rule spelled out.
pub fn spectral_clustering_by(
    a: MatRef<'_, f64>,
    count: Count,
    assignment: Assignment,
    restarts: usize,
    seed: u64,
) -> Result<SpectralLabels> {
    let n = a.nrows();
    if let Count::Fixed(k) = count {
        if k == 0 || k > n.max(1) {
            return Err(Error::InvalidConfig {
                field: "n_clusters",
                value: k.to_string(),
                reason: "must lie in 1..=number of rows",
            });
        }
    }
    let l = normalized_laplacian(a)?;
    let lowest = (n >= PARTIAL_ROWS)
        .then(|| {
            lowest_eigenpairs(l.as_ref(), n / 3, seed, |v| {
                suffices(v, n, count).then(|| cluster_count(v, n, count))
            })
        })
        .flatten();
    let (eigenvalues, vectors) = match lowest {
        Some(low) => (low.values, Some(low.vectors)),
        None if n >= SINGLE_PRECISION_ROWS => {
            let (values, vectors) = symmetric_eigen_f32(l.as_ref())?;
            (values, Some(vectors))
        }
        None => symmetric_eigen(l.as_ref(), true)?,
    };
    let m = cluster_count(&eigenvalues, n, count);
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

/// Rows from which clustering computes only the lowest eigenpairs
/// ([`lowest_eigenpairs`]); below, the dense decomposition is as fast (one thread: 0.9 ms
/// dense against 1.1 ms partial at 100 rows, 2.1 against 1.2 ms at 150, 8.8 against 2.6 ms
/// at 300, on block affinities of 2-5 groups; the realistic scenes keep 100-260 rows).
pub const PARTIAL_ROWS: usize = 150;

/// Whether the converged lowest eigenvalues `values` (ascending, a prefix of the `n`-row
/// spectrum) settle the cluster count of `count`.
///
/// A fixed count needs that many. The eigengap rule needs every gap it may pick: all gaps up
/// to its cap, or a prefix whose largest gap lies in its lower half, since past the groups'
/// eigenvalues the spectrum of the rest is dense (gaps far below the one separating the
/// groups). A level needs the prefix to reach it (or the cap).
pub fn suffices(values: &[f64], n: usize, count: Count) -> bool {
    let p = values.len();
    if p >= n {
        return true;
    }
    match count {
        Count::Fixed(k) => p >= k,
        Count::Eigengap { cap, level } => {
            if p < 2 {
                return false;
            }
            let cap = cap.map_or(n - 1, |c| c.clamp(1, n - 1));
            if p > cap {
                return true;
            }
            let reached = level.is_none_or(|l| values[p - 1] >= l);
            reached && eigengap(values, None) <= (p - 1) / 2
        }
    }
}

/// The number of clusters `count` picks from the lowest eigenvalues `values` of an `n`-row
/// Laplacian (all of them, or a prefix that [`suffices`]).
pub fn cluster_count(values: &[f64], n: usize, count: Count) -> usize {
    match count {
        Count::Fixed(k) => k,
        Count::Eigengap { cap, level } => {
            let gap = eigengap(values, cap);
            let below = level.map_or(0, |l| values.iter().filter(|&&v| v < l).count());
            let most = cap.unwrap_or(n).max(1);
            gap.max(below.min(most))
        }
    }
    .clamp(n.min(1), n)
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
    let count = Count::Eigengap {
        cap: Some(cap),
        level: config.cluster_level,
    };
    let sl = spectral_clustering_by(
        a.as_ref(),
        count,
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
