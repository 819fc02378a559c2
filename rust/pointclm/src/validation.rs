//! A-contrario validation of candidate instances (Desolneux, Moisan and Morel; Moisan and
//! Stival's AC-RANSAC): a pose is kept only if its inlier count would be a surprise for a pose
//! that explains nothing.
//!
//! Why: on real scans the correspondence stage proposes groups made of structured outliers
//! (a flat patch matched to a flat part, a copy of the clutter) as well as true copies, and no
//! fixed inlier count separates them: a copy may hold 5 correct matches among 300 or 200
//! among 5000. The null model here is "the matches carry no information": source and target
//! ends paired at random. Under it, a pose `T` explains a correspondence with probability
//! `p_T`, the share of all (source end, other target end) pairs that `T` brings within the
//! inlier radius. Measuring `p_T` on the data itself accounts for where the target points
//! lie: a pose that sends the model into a dense part of the scan needs more inliers to count.
//! The number of false alarms is `NFA = n_tests * P[Binomial(n, p_T) >= k - 3]` (the 3 points
//! of the minimal sample that fixed the pose are inliers for free), and an instance is kept
//! when `NFA <= max_nfa`.

use crate::correspondences::Correspondences;
use crate::grid::{dist_sq, UniformGrid};
use crate::kabsch::RigidTransform;

/// The target ends of a scene, indexed once for every pose's null probability.
pub struct NullModel {
    /// Cells twice the radius: a ball meets at most two per axis, four runs in all.
    grid: UniformGrid,
    n: usize,
    radius: f64,
    radius_sq: f64,
}

impl NullModel {
    /// Indexes the target ends of `c`; `radius` is the inlier radius.
    pub fn new(c: &Correspondences, radius: f64) -> Self {
        let targets: Vec<[f64; 3]> = (0..c.len()).map(|i| c.target(i)).collect();
        Self {
            grid: UniformGrid::new(&targets, 2.0 * radius),
            n: c.len(),
            radius,
            radius_sq: radius * radius,
        }
    }

    /// `p_T`: the share of pairs (source end `a`, target end `b != a`) that `pose` brings
    /// within the inlier radius, and `k`, the correspondences it explains (`a == b`).
    pub fn null_probability(&self, c: &Correspondences, pose: &RigidTransform) -> (f64, usize) {
        let (mut pairs, mut own) = (0usize, 0usize);
        for a in 0..self.n {
            let q = pose.apply(c.source(a));
            pairs += count_within(&self.grid, q, self.radius, self.radius_sq);
            // `pose.residual_sq` of the pair, from the point already moved.
            own += usize::from(dist_sq(&q, &c.target(a)) < self.radius_sq);
        }
        // Boundary points may be counted by one test and not the other: never below zero.
        let others = pairs.saturating_sub(own);
        // At least one pair, so that a pose in empty space still has p > 0.
        let p = others.max(1) as f64 / (self.n as f64 * (self.n as f64 - 1.0)).max(1.0);
        (p.min(1.0), own)
    }

    /// `log10 NFA` of a pose explaining `k` of the `n` correspondences, among `n_tests`
    /// candidates.
    pub fn log10_nfa(&self, c: &Correspondences, pose: &RigidTransform, n_tests: usize) -> f64 {
        let (p, k) = self.null_probability(c, pose);
        (n_tests.max(1) as f64).log10() + log10_binomial_tail(self.n, k.saturating_sub(3), p)
    }
}

/// How many points of `grid` lie strictly within `radius` (squared: `radius_sq`) of `q`.
fn count_within(grid: &UniformGrid, q: [f64; 3], radius: f64, radius_sq: f64) -> usize {
    let (points, _) = grid.points();
    let mut count = 0;
    grid.runs(q, radius, |run| {
        for p in &points[run] {
            count += usize::from(dist_sq(p, &q) < radius_sq);
        }
    });
    count
}

/// `log10 P[Binomial(n, p) >= k]`, summed in log space from the mode-side end so that tails
/// far below `f64::MIN_POSITIVE` stay exact enough to compare.
pub fn log10_binomial_tail(n: usize, k: usize, p: f64) -> f64 {
    if k == 0 || p >= 1.0 {
        return 0.0;
    }
    if k > n || p <= 0.0 {
        return f64::NEG_INFINITY;
    }
    let (lp, lq) = (p.ln(), (-p).ln_1p());
    // ln C(n, k) as a sum: exact, and no log-gamma needed.
    let mut log_choose = 0.0;
    for i in 0..k {
        log_choose += ((n - i) as f64).ln() - ((i + 1) as f64).ln();
    }
    let mut term = log_choose + k as f64 * lp + (n - k) as f64 * lq;
    let first = term;
    let mut sum = 1.0; // terms relative to the first one
    for j in k..n {
        // pmf(j + 1) / pmf(j) = (n - j) / (j + 1) * p / (1 - p)
        term += ((n - j) as f64).ln() - ((j + 1) as f64).ln() + lp - lq;
        let rel = (term - first).exp();
        sum += rel;
        if rel < 1e-17 * sum && (j as f64) > n as f64 * p {
            break;
        }
    }
    ((first + sum.ln()) / std::f64::consts::LN_10).min(0.0)
}

#[cfg(test)]
#[path = "tests/validation.rs"]
mod tests;
