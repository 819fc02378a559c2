//! Every threshold of the method, named, with the paper's synthetic-scale defaults.

use crate::error::{Error, Result};

/// How density pruning decides that a correspondence lies in a dense (inlier) region.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pruning {
    /// The paper's form: `S = S^F * beta` (or `S = beta` without features), binarised at
    /// `tau_s`; keep row `i` if its row sum (itself included) exceeds `tau_n`.
    Paper,
    /// The authors' code: count `j` with `beta_ij > beta_threshold` and, with features,
    /// `S^F_ij > feature_threshold`; keep `i` if the count (itself included) exceeds `min_count`.
    AuthorsCode,
    /// No pruning: every correspondence goes to clustering (paper Table 3 ablation).
    Disabled,
}

/// How rows of the spectral embedding are turned into cluster labels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Assignment {
    /// k-means++ with restarts on the row-normalised embedding (Ng, Jordan and Weiss).
    KMeans,
    /// Yu and Shi's discretisation, as scikit-learn's `assign_labels="discretize"`
    /// that the authors' code uses.
    Discretize,
}

/// Parameters of the whole pipeline.
///
/// Lengths (`sigma_d`, `affinity_sigma`, `inlier_threshold`) are in the units of the points.
/// The defaults are the paper's synthetic settings, where shapes fit in a unit sphere and the
/// noise is about 0.01; [`Config::scaled`] multiplies every length for data at another scale.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Length tolerance of spatial consistency `beta_ij = [1 - d_ij^2 / sigma_d^2]_+`.
    pub sigma_d: f64,
    /// Pruning rule; see [`Pruning`].
    pub pruning: Pruning,
    /// Paper rule: binarisation threshold on `S`.
    pub tau_s: f64,
    /// Paper rule: a row must have more than this many entries above `tau_s`.
    pub tau_n: usize,
    /// Authors'-code rule: threshold on `beta`.
    pub beta_threshold: f64,
    /// Authors'-code rule: threshold on the feature similarity `S^F` (ignored without features).
    pub feature_threshold: f64,
    /// Authors'-code rule: a row must count more than this many consistent correspondences.
    pub min_count: usize,
    /// Upper bound on the kept set handed to the dense eigensolver: when pruning keeps more,
    /// the densest `max_kept` rows are clustered (memory and time grow as its square and cube).
    pub max_kept: usize,
    /// Length scale of the clustering affinity `[1 - d_ij^2 / affinity_sigma^2]_+`.
    pub affinity_sigma: f64,
    /// Optional cap on the number of clusters the eigengap may choose.
    pub max_instances: Option<usize>,
    /// When set, the cluster count is the larger of the eigengap's and the number of
    /// normalised-Laplacian eigenvalues below this level (in (0, 2)). Why: with dozens of
    /// similar copies the spectrum rises smoothly and its largest gap comes early, while
    /// every copy still contributes an eigenvalue well below 1 (a group with more affinity
    /// inside than across has a small Rayleigh quotient). `None`: the eigengap alone (the
    /// paper's rule).
    pub cluster_level: Option<f64>,
    /// Clustering rounds: after each, the correspondences explained by validated instances
    /// leave the kept set and the rest is clustered again, which finds copies the eigengap
    /// merged or missed (bins of dozens of parts). Needs `max_nfa` (without validation one
    /// round runs, as in the paper).
    pub max_rounds: usize,
    /// Label assignment on the spectral embedding.
    pub assignment: Assignment,
    /// Restarts of k-means (best inertia wins) or of the discretisation.
    pub kmeans_restarts: usize,
    /// Clusters, and final instances, with fewer members are dropped.
    pub min_cluster_size: usize,
    /// At most this many RANSAC hypotheses (3-point Kabsch) per cluster.
    pub ransac_iterations: usize,
    /// RANSAC stops once an all-inlier sample would have been drawn with this probability
    /// at the best inlier share found so far (1 runs all `ransac_iterations`).
    pub ransac_confidence: f64,
    /// A-contrario validation: an instance is kept only if its number of false alarms (how
    /// many poses as well supported would arise from unrelated matches) is at most this
    /// ([`crate::validation`]). `None` keeps every instance.
    pub max_nfa: Option<f64>,
    /// A correspondence is an inlier of a pose if `||R x + t - y||` is below this.
    pub inlier_threshold: f64,
    /// Refit each pose by least squares on its inliers (the authors' code does not).
    pub refine: bool,
    /// Merge instances whose poses place the object at the same spot (the authors' code
    /// returns such duplicates).
    pub merge_duplicates: bool,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            sigma_d: 0.05,
            pruning: Pruning::Paper,
            tau_s: 0.85,
            tau_n: 10,
            beta_threshold: 0.9,
            feature_threshold: 0.8,
            min_count: 9,
            max_kept: 2000,
            affinity_sigma: 0.1,
            max_instances: None,
            cluster_level: None,
            max_rounds: 1,
            assignment: Assignment::KMeans,
            kmeans_restarts: 10,
            min_cluster_size: 10,
            ransac_iterations: 1000,
            ransac_confidence: 1.0,
            max_nfa: Some(1e-3),
            inlier_threshold: 0.1,
            refine: true,
            merge_duplicates: true,
        }
    }
}

fn invalid(field: &'static str, value: impl ToString, reason: &'static str) -> Error {
    Error::InvalidConfig {
        field,
        value: value.to_string(),
        reason,
    }
}

fn positive_length(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, v, "must be a finite length > 0"))
    }
}

/// Upper bounds of the count fields, enforced by [`Config::validate`]. Each lies far above
/// any useful setting; its purpose is that no config can ask for unbounded work or memory (a
/// service that passes user configs through must be able to rely on a finite worst case).
/// A new count field of [`Config`] gets its bound here and a line in `Config::counts`.
pub mod bounds {
    /// Rows the dense eigensolver may receive: memory grows as `8 n^2` bytes per matrix
    /// (3.2 GB at this bound) and time as `n^3`. The default is 2000.
    pub const MAX_KEPT: usize = 20_000;
    /// RANSAC hypotheses per cluster. The default is 50; a 3-point sample from a cluster
    /// with 10% inliers succeeds with probability 1 - 1e-9 within 2 * 10^4 draws.
    pub const RANSAC_ITERATIONS: usize = 1_000_000;
    /// Restarts of the label assignment (each costs one k-means or discretisation). The
    /// default is 10.
    pub const KMEANS_RESTARTS: usize = 10_000;
    /// Smallest cluster kept: no cluster can exceed the rows handed to clustering.
    pub const MIN_CLUSTER_SIZE: usize = MAX_KEPT;
    /// Clusters the eigengap may choose: at most one per clustered row.
    pub const MAX_INSTANCES: usize = MAX_KEPT;
    /// The density thresholds `tau_n` and `min_count`: row counts are 32-bit, so a larger
    /// threshold could never be met.
    pub const DENSITY_COUNT: usize = u32::MAX as usize;
    /// Clustering rounds: each costs at most one clustering of the kept set.
    pub const MAX_ROUNDS: usize = 100;
}

impl Config {
    /// `(field, value, min, max)` of every count field, checked by [`Config::validate`].
    fn counts(&self) -> [(&'static str, usize, usize, usize); 8] {
        [
            ("tau_n", self.tau_n, 0, bounds::DENSITY_COUNT),
            ("min_count", self.min_count, 0, bounds::DENSITY_COUNT),
            // a rigid pose needs 3 points
            (
                "min_cluster_size",
                self.min_cluster_size,
                3,
                bounds::MIN_CLUSTER_SIZE,
            ),
            ("max_kept", self.max_kept, 3, bounds::MAX_KEPT),
            (
                "max_instances",
                self.max_instances.unwrap_or(1),
                1,
                bounds::MAX_INSTANCES,
            ),
            (
                "kmeans_restarts",
                self.kmeans_restarts,
                1,
                bounds::KMEANS_RESTARTS,
            ),
            (
                "ransac_iterations",
                self.ransac_iterations,
                1,
                bounds::RANSAC_ITERATIONS,
            ),
            ("max_rounds", self.max_rounds, 1, bounds::MAX_ROUNDS),
        ]
    }

    /// The same settings with every length multiplied by `factor` (for data whose noise and
    /// object size are `factor` times the synthetic benchmark's).
    pub fn scaled(&self, factor: f64) -> Self {
        Self {
            sigma_d: self.sigma_d * factor,
            affinity_sigma: self.affinity_sigma * factor,
            inlier_threshold: self.inlier_threshold * factor,
            ..self.clone()
        }
    }

    /// Checks every field; the pipeline calls this before touching any data.
    pub fn validate(&self) -> Result<()> {
        positive_length("sigma_d", self.sigma_d)?;
        positive_length("affinity_sigma", self.affinity_sigma)?;
        positive_length("inlier_threshold", self.inlier_threshold)?;
        if !(self.tau_s.is_finite() && (-1.0..1.0).contains(&self.tau_s)) {
            return Err(invalid("tau_s", self.tau_s, "must lie in [-1, 1)"));
        }
        if !(self.beta_threshold.is_finite() && (0.0..1.0).contains(&self.beta_threshold)) {
            return Err(invalid(
                "beta_threshold",
                self.beta_threshold,
                "must lie in [0, 1)",
            ));
        }
        if !(self.feature_threshold.is_finite() && (-1.0..1.0).contains(&self.feature_threshold)) {
            return Err(invalid(
                "feature_threshold",
                self.feature_threshold,
                "must lie in [-1, 1)",
            ));
        }
        for (field, value, min, max) in self.counts() {
            if !(min..=max).contains(&value) {
                return Err(Error::ConfigOutOfRange {
                    field,
                    value: value as u128,
                    min,
                    max,
                });
            }
        }
        if self.max_kept < self.min_cluster_size {
            return Err(invalid(
                "max_kept",
                self.max_kept,
                "must be >= min_cluster_size",
            ));
        }
        if !(self.ransac_confidence.is_finite()
            && self.ransac_confidence > 0.0
            && self.ransac_confidence <= 1.0)
        {
            return Err(invalid(
                "ransac_confidence",
                self.ransac_confidence,
                "must lie in (0, 1]",
            ));
        }
        if let Some(v) = self.cluster_level {
            if !(v.is_finite() && v > 0.0 && v < 2.0) {
                return Err(invalid("cluster_level", v, "must lie in (0, 2) or be None"));
            }
        }
        if let Some(v) = self.max_nfa {
            if !(v.is_finite() && v > 0.0) {
                return Err(invalid("max_nfa", v, "must be a finite number > 0 or None"));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "tests/config.rs"]
mod tests;
