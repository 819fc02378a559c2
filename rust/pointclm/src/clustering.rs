//! From the kept correspondences to groups, one per candidate instance.

use faer::MatRef;

use crate::config::{Assignment, Config};
use crate::correspondences::{Correspondences, Features};
use crate::discretize::discretize;
use crate::error::{Error, Result};
use crate::kmeans::kmeans;
use crate::lowest_eigen::{lowest_eigenpairs, Estimates, BLOCK};
use crate::seeds::{stream, STAGE_CLUSTERING};
use crate::spectral::{
    affinity, check_symmetric, eigengap, laplacian_of_symmetric, row_normalized_embedding,
    symmetric_eigen, symmetric_eigen_f32, SINGLE_PRECISION_ROWS,
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
    /// there the partial solver's Ritz values ([`settled_count`]): right to its tolerance up
    /// to the eigengap, upper bounds of the eigenvalues of their rank after it.
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
    check_symmetric(a)?;
    clustering_of_symmetric(a, count, assignment, restarts, seed)
}

/// [`spectral_clustering_by`] of an affinity known to be square, finite and symmetric (see
/// [`laplacian_of_symmetric`]).
fn clustering_of_symmetric(
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
    let l = laplacian_of_symmetric(a)?;
    let lowest = (n >= PARTIAL_ROWS)
        .then(|| {
            lowest_eigenpairs(l.as_ref(), partial_basis(n), seed, |est| {
                settled_count(est, n, count)
            })
        })
        .flatten();
    let (eigenvalues, vectors, m) = match lowest {
        Some(low) => (low.values, Some(low.vectors), low.needed),
        None => {
            let (values, vectors) = if n >= SINGLE_PRECISION_ROWS {
                let (values, vectors) = symmetric_eigen_f32(l.as_ref())?;
                (values, Some(vectors))
            } else {
                symmetric_eigen(l.as_ref(), true)?
            };
            let m = cluster_count(&values, n, count);
            (values, vectors, m)
        }
    };
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
/// ([`lowest_eigenpairs`]); below, the dense decomposition costs about as much as the few
/// Rayleigh-Ritz projections the partial solver needs.
pub const PARTIAL_ROWS: usize = 64;

/// The partial solver's basis budget at `n` rows: a third of the rows, at least four blocks
/// (two products and a restart's room), at most all rows.
pub fn partial_basis(n: usize) -> usize {
    (n / 3).max(4 * BLOCK).min(n)
}

/// The cluster count of `count`, when the partial spectrum `est` of an `n`-row Laplacian
/// settles it (`None`: more of the spectrum is needed).
///
/// A fixed count needs that many converged eigenvalues. The eigengap rule needs to know which
/// gap up to its cap is the largest, from any of:
/// - all those gaps converged;
/// - bounds: a gap whose lower bound exceeds the upper bound of every other gap up to the cap
///   ([`gap_by_bounds`]), so the dense rest of the spectrum need not converge;
/// - failing those, a converged prefix whose largest gap lies in its lower half, since past
///   the groups' eigenvalues the spectrum of the rest is dense (gaps far below the one
///   separating the groups).
///
/// A level needs the converged prefix to reach it (or the cap).
pub fn settled_count(est: &Estimates<'_>, n: usize, count: Count) -> Option<usize> {
    let values = est.converged_values();
    let p = values.len();
    if p >= n {
        return Some(cluster_count(values, n, count));
    }
    let Count::Eigengap { cap, level } = count else {
        return matches!(count, Count::Fixed(k) if p >= k).then(|| cluster_count(values, n, count));
    };
    let cap = cap.map_or(n - 1, |c| c.clamp(1, n - 1));
    if p > cap {
        return Some(cluster_count(values, n, count));
    }
    if level.is_some_and(|l| values.last().is_none_or(|&v| v < l)) {
        return None;
    }
    if let Some(gap) = gap_by_bounds(est, cap) {
        let below = level.map_or(0, |l| values.iter().filter(|&&v| v < l).count());
        return Some(gap.max(below.min(cap)).clamp(1, n));
    }
    (p >= 2 && eigengap(values, None) <= (p - 1) / 2).then(|| cluster_count(values, n, count))
}

/// The eigengap's choice `k` (1-based: the gap `lambda_{k+1} - lambda_k`, `k <= cap`) when
/// the Ritz bounds prove it the largest: its lower bound (`lambda_{k+1}`'s lower estimate
/// less `lambda_k`'s upper bound) exceeds the upper bound of each gap before it, and the span
/// `lambda_{cap+1} - lambda_{k+1}` that all gaps after it share. Needs the Ritz value of rank
/// `cap + 1` (an upper bound) and residuals through rank `k + 1`.
pub fn gap_by_bounds(est: &Estimates<'_>, cap: usize) -> Option<usize> {
    let top = *est.values.get(cap)?;
    let lower = |i: usize| est.lower(i).unwrap_or(f64::NEG_INFINITY);
    let (k, gap) = (1..=est.converged.min(cap))
        .filter(|&k| est.lower(k).is_some())
        .map(|k| (k, lower(k) - est.values[k - 1]))
        .fold(None, |best: Option<(usize, f64)>, (k, g)| match best {
            Some((_, b)) if b >= g => best,
            _ => Some((k, g)),
        })?;
    let before_smaller = (1..k).all(|j| est.values[j] - lower(j - 1) < gap);
    (before_smaller && top - lower(k) < gap).then_some(k)
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

/// The fewest rows a group needs to be kept: the three of a minimal sample, which fix a pose.
///
/// Why not `config.min_cluster_size`: a group is only the seed of a pose, and the pose is
/// judged by every correspondence it explains (`instances::finalize` rescores it over the
/// whole input and applies the size floor to the instances it returns). On realistic scans a
/// copy's matches often split over several small groups, or pruning keeps only a few of
/// them, so a group below the floor can still fit a pose that explains enough rows. On the
/// validation models (60 realistic scenes of dragon, happy, armadillo, bathtub and bed,
/// correspondences alone): correct poses 43 -> 47, wrong 21 -> 21, MF 22.29 -> 23.28 (with
/// `finalize`'s floor after the refit: wrong 19, MF 23.38, MP 37.78 -> 38.47). Synthetic
/// benchmark MF 98.36 -> 99.80. The cap of one group per 3 kept rows matters: one per
/// `min_cluster_size` rows (as before), with the floor after the refit, found 44 correct
/// poses instead of 47.
pub const MIN_SEED_ROWS: usize = 3;

/// Groups of correspondence indices (into the full input), largest first; groups smaller
/// than [`MIN_SEED_ROWS`] are dropped. Also returns the eigengap's cluster count.
pub fn cluster_kept(
    c: &Correspondences,
    features: Option<&Features>,
    kept: &[usize],
    config: &Config,
    seed: u64,
) -> Result<(Vec<Vec<usize>>, usize)> {
    if kept.len() < MIN_SEED_ROWS {
        return Ok((vec![], 0));
    }
    let a = affinity(c, features, kept, config.affinity_sigma)?;
    // At most n / MIN_SEED_ROWS groups can seed a pose; a larger count would only split
    // isolated rows apart (and cost k-means time), e.g. when pruning is disabled.
    let most = (kept.len() / MIN_SEED_ROWS).max(1);
    let cap = config.max_instances.map_or(most, |m| m.min(most));
    let count = Count::Eigengap {
        cap: Some(cap),
        level: config.cluster_level,
    };
    // `affinity` mirrors one triangle: symmetric and finite by construction.
    let sl = clustering_of_symmetric(
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
    groups.retain(|g| g.len() >= MIN_SEED_ROWS);
    // Largest first; equal sizes keep their (deterministic) label order.
    groups.sort_by_key(|g| std::cmp::Reverse(g.len()));
    Ok((groups, sl.n_clusters))
}

#[cfg(test)]
#[path = "tests/clustering.rs"]
mod tests;
