//! The one-call entry points: correspondences -> consistency -> pruning -> clustering ->
//! poses, for one scene or many in parallel.

use std::time::Instant;

use rayon::prelude::*;

use crate::cancel;
use crate::clustering::cluster_kept;
use crate::config::Config;
use crate::correspondences::{Correspondences, Features};
use crate::error::{Error, Result};
use crate::instances::{finalize, Instance};
use crate::magnitude;
#[cfg(feature = "network")]
use crate::network::Network;
use crate::pruning::{density_counts, select_kept};
use crate::ransac::{ransac, RansacFit};
use crate::seeds::{stream, STAGE_RANSAC};
use crate::validation::NullModel;

/// Wall-clock seconds spent in each stage (for reporting; not part of the result's identity).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimings {
    /// The learned embedding's forward pass (0 without a network).
    pub embedding: f64,
    /// Spatial consistency and density pruning.
    pub pruning: f64,
    /// Affinity, eigendecomposition and label assignment.
    pub clustering: f64,
    /// RANSAC, refit, merging and labelling.
    pub poses: f64,
}

/// The result of registering one scene; [`Registration::default`] is the empty one (no
/// instances, nothing kept), as a scene pass without correspondences reports it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Registration {
    /// Registered instances, most inliers first.
    pub instances: Vec<Instance>,
    /// Per correspondence: `-1` for an outlier, `k` for `instances[k]`.
    pub labels: Vec<i64>,
    /// Correspondences that survived pruning (ascending indices).
    pub kept: Vec<usize>,
    /// Clusters chosen by the eigengap (before dropping small ones and merging).
    pub n_clusters: usize,
    /// Time per stage.
    pub timings: StageTimings,
}

/// A scene for [`register_batch`].
#[derive(Debug, Clone)]
pub struct Scene {
    pub correspondences: Correspondences,
    pub features: Option<Features>,
}

/// Finds every instance of the source in the target from putative correspondences.
///
/// `features` (one row per correspondence, e.g. the learned embedding) switch pruning and
/// clustering from `S = beta` to `S = S^F * beta`. Parallel parts run on the current rayon
/// pool; the result depends only on the inputs and `seed`, never on the thread count.
///
/// Points and config lengths of extreme magnitude (beyond about `2^±240`, e.g. 1e300 or
/// 1e-300, where squared distances overflow or underflow) are scaled internally by an exact
/// power of two and the poses scaled back; when no common scale can hold both the largest
/// magnitude and the smallest length, the result is [`Error::MagnitudeRange`]. A cancelled
/// [`CancelToken`](crate::cancel::CancelToken) stops the call between stages with
/// [`Error::Cancelled`].
pub fn register(
    c: &Correspondences,
    features: Option<&Features>,
    config: &Config,
    seed: u64,
) -> Result<Registration> {
    config.validate()?;
    cancel::check()?;
    if let Some(f) = features {
        f.check_rows(c.len())?;
    }
    let e = magnitude::scale_exponent(c, config)?;
    if e == 0 {
        return register_in_window(c, features, config, seed);
    }
    let scaled = magnitude::scaled_correspondences(c, e)?;
    let mut r = register_in_window(
        &scaled,
        features,
        &magnitude::scaled_config(config, e),
        seed,
    )?;
    for inst in &mut r.instances {
        inst.pose.translation = inst.pose.translation.map(|t| magnitude::times_pow2(t, e));
        inst.inlier_rmse = magnitude::times_pow2(inst.inlier_rmse, e);
    }
    Ok(r)
}

/// [`register`] on input whose magnitudes f64 squared distances can hold.
fn register_in_window(
    c: &Correspondences,
    features: Option<&Features>,
    config: &Config,
    seed: u64,
) -> Result<Registration> {
    let t0 = Instant::now();
    let counts = density_counts(c, features, config)?;
    let kept = select_kept(&counts, config);
    cancel::check()?;
    let t1 = Instant::now();
    // One index of the target ends serves every validation, in each round and at the end.
    let null = config
        .max_nfa
        .map(|_| NullModel::new(c, config.inlier_threshold));
    let proposals = propose(c, features, &kept, config, null.as_ref(), seed)?;
    let t2 = t1 + proposals.clustering;
    cancel::check()?;
    let fits = proposals.fits;
    let n_clusters = proposals.n_clusters;
    let (instances, labels) = finalize(c, &fits, config, null.as_ref());
    let t3 = Instant::now();
    Ok(Registration {
        instances,
        labels,
        kept,
        n_clusters,
        timings: StageTimings {
            embedding: 0.0,
            pruning: (t1 - t0).as_secs_f64(),
            clustering: (t2 - t1).as_secs_f64(),
            poses: (t3 - t2).as_secs_f64(),
        },
    })
}

/// Candidate poses from the kept set, and the clustering's share of the time spent.
struct Proposals {
    fits: Vec<RansacFit>,
    n_clusters: usize,
    clustering: std::time::Duration,
}

/// Clusters the kept set and fits a pose per cluster, in rounds: after each round the
/// correspondences explained by a validated pose leave the set and the rest is clustered
/// again. Why: with many similar copies the eigengap settles on too few clusters, and a
/// cluster that merged two copies yields one pose; a second look at what no validated pose
/// explains finds the copies the first one merged or missed. Without validation
/// (`max_nfa = None`) there is no way to tell found copies from junk, so one round runs (the
/// paper's method).
fn propose(
    c: &Correspondences,
    features: Option<&Features>,
    kept: &[usize],
    config: &Config,
    null: Option<&NullModel>,
    seed: u64,
) -> Result<Proposals> {
    let null = null.zip(config.max_nfa).map(|(m, v)| (m, v.log10()));
    let rounds = if null.is_some() { config.max_rounds } else { 1 };
    let thr_sq = config.inlier_threshold * config.inlier_threshold;
    let mut pool = kept.to_vec();
    let mut fits: Vec<RansacFit> = Vec::new();
    let mut first_count = 0;
    let mut clustering = std::time::Duration::ZERO;
    for round in 0..rounds {
        cancel::check()?;
        let t = Instant::now();
        let (groups, n_clusters) = cluster_kept(c, features, &pool, config, seed ^ round as u64)?;
        clustering += t.elapsed();
        if round == 0 {
            first_count = n_clusters;
        }
        let round_fits = fit_groups(c, &groups, config, seed, fits.len() as u64);
        // The last round's validation would only feed a round that does not run (`finalize`
        // validates the final poses).
        let Some(null) = null.filter(|_| round + 1 < rounds) else {
            fits.extend(round_fits);
            break;
        };
        let n_tests = fits.len() + round_fits.len();
        let explained = explained_by_valid(c, &pool, &round_fits, null, n_tests, thr_sq);
        fits.extend(round_fits);
        let before = pool.len();
        pool.retain(|&i| !explained[i]);
        if pool.len() == before || pool.len() < config.min_cluster_size {
            break;
        }
    }
    Ok(Proposals {
        fits,
        n_clusters: first_count,
        clustering,
    })
}

/// One RANSAC fit per group (none for a group without a non-degenerate triplet); group `k`
/// draws from RANSAC stream `offset + k`, so every group of every round has its own stream.
fn fit_groups(
    c: &Correspondences,
    groups: &[Vec<usize>],
    config: &Config,
    seed: u64,
    offset: u64,
) -> Vec<RansacFit> {
    groups
        .par_iter()
        .enumerate()
        .filter_map(|(k, g)| {
            let mut rng = stream(seed, STAGE_RANSAC, offset + k as u64);
            ransac(
                c,
                g,
                config.ransac_iterations,
                config.ransac_confidence,
                config.inlier_threshold,
                config.refine,
                &mut rng,
            )
        })
        .collect()
}

/// Per correspondence, whether a fit of this round that `null` validates (`log10 NFA` at
/// most the bound, among `n_tests` poses) holds it among its inliers; only rows of `pool`
/// are looked at.
fn explained_by_valid(
    c: &Correspondences,
    pool: &[usize],
    round_fits: &[RansacFit],
    (null, bound): (&NullModel, f64),
    n_tests: usize,
    thr_sq: f64,
) -> Vec<bool> {
    let valid: Vec<bool> = round_fits
        .par_iter()
        .map(|f| null.log10_nfa(c, &f.pose, n_tests) <= bound)
        .collect();
    let mut explained = vec![false; c.len()];
    for (f, _) in round_fits.iter().zip(&valid).filter(|(_, &v)| v) {
        for &i in pool {
            if f.pose.residual_sq(c.source(i), c.target(i)) < thr_sq {
                explained[i] = true;
            }
        }
    }
    explained
}

/// Registers many scenes on a private pool of `num_threads` threads (0 = rayon's default,
/// one per core), every scene with the same `seed`, so each result equals the one
/// [`register`] gives for that scene alone. One bad scene yields its own `Err` and does not
/// stop the others.
pub fn register_batch(
    scenes: &[Scene],
    config: &Config,
    seed: u64,
    num_threads: usize,
) -> Result<Vec<Result<Registration>>> {
    config.validate()?;
    on_pool(scenes, num_threads, |s| {
        register(&s.correspondences, s.features.as_ref(), config, seed)
    })
}

/// `f` on every item, in order, on a private pool of `num_threads` threads.
fn on_pool<T: Sync>(
    items: &[T],
    num_threads: usize,
    f: impl Fn(&T) -> Result<Registration> + Sync + Send,
) -> Result<Vec<Result<Registration>>> {
    let pool = thread_pool(num_threads)?;
    // the caller's cancel token follows each scene onto the pool's threads
    let token = cancel::current();
    let results = pool.install(|| {
        items
            .par_iter()
            .map(|item| cancel::within(token.clone(), || f(item)))
            .collect()
    });
    cancel::check()?;
    Ok(results)
}

/// [`register`] with the features computed by a trained embedding network (PointCLM proper):
/// correspondences -> embedding -> pruning and clustering on `S = S^F * beta` -> poses.
///
/// The forward pass runs on the current rayon pool; see [`Network::embed`]. Pass
/// `network.recommended_config()` (or a config derived from it) for the thresholds chosen
/// with that network.
#[cfg(feature = "network")]
pub fn register_with_network(
    c: &Correspondences,
    network: &Network,
    config: &Config,
    seed: u64,
) -> Result<Registration> {
    config.validate()?;
    register_embedded(c, config, seed, || network.embed(c))
}

/// Embeds with `embed` (timed as the embedding stage), then registers with those features.
#[cfg(feature = "network")]
fn register_embedded(
    c: &Correspondences,
    config: &Config,
    seed: u64,
    embed: impl FnOnce() -> Result<Features>,
) -> Result<Registration> {
    let t0 = Instant::now();
    let features = embed()?;
    cancel::check()?;
    let embedding = t0.elapsed().as_secs_f64();
    let mut r = register(c, Some(&features), config, seed)?;
    r.timings.embedding = embedding;
    Ok(r)
}

/// [`register_with_network`] for many scenes on a private pool of `num_threads` threads (0 =
/// one per core). Scenes are spread over the threads and each forward pass runs on the thread
/// of its scene, so the results equal those of [`register_with_network`] scene by scene,
/// whatever `num_threads`. One bad scene yields its own `Err` and does not stop the others.
#[cfg(feature = "network")]
pub fn register_batch_with_network(
    scenes: &[Correspondences],
    network: &Network,
    config: &Config,
    seed: u64,
    num_threads: usize,
) -> Result<Vec<Result<Registration>>> {
    config.validate()?;
    on_pool(scenes, num_threads, |c| {
        register_embedded(c, config, seed, || network.embed_sequential(c))
    })
}

/// A private rayon pool (a library must not configure the global one).
pub fn thread_pool(num_threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(num_threads)
        .build()
        .map_err(|e| Error::ThreadPool {
            threads: num_threads,
            reason: e.to_string(),
        })
}

#[cfg(test)]
#[path = "tests/pipeline.rs"]
mod tests;

#[cfg(test)]
#[path = "tests/hardening.rs"]
mod hardening;

#[cfg(test)]
#[path = "tests/fuzz.rs"]
mod fuzz;
