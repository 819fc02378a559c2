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
use crate::kabsch::RigidTransform;

/// The target ends of a scene, indexed once for every pose's null probability.
pub struct NullModel {
    grid: CountingGrid,
    n: usize,
    radius: f64,
    radius_sq: f64,
}

impl NullModel {
    /// Indexes the target ends of `c`; `radius` is the inlier radius.
    pub fn new(c: &Correspondences, radius: f64) -> Self {
        let targets: Vec<[f64; 3]> = (0..c.len()).map(|i| c.target(i)).collect();
        Self {
            grid: CountingGrid::new(&targets, radius),
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
            pairs += self.grid.count_within(q, self.radius, self.radius_sq);
            if pose.residual_sq(c.source(a), c.target(a)) < self.radius_sq {
                own += 1;
            }
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

/// Points bucketed in a uniform grid whose cells are at least twice the query radius, stored
/// cell by cell, so that counting the points of a ball visits at most four contiguous runs
/// (two cells along each axis).
///
/// Why not the k-d tree used elsewhere: every candidate pose asks one radius count per
/// correspondence (thousands of small queries on a few thousand points); a tree query that
/// collects its hits into a vector cost most of the pose stage on synthetic scenes.
struct CountingGrid {
    origin: [f64; 3],
    inv_cell: f64,
    dims: [usize; 3],
    /// `start[c]..start[c + 1]` are the points of cell `c` in `points`.
    start: Vec<usize>,
    points: Vec<[f64; 3]>,
}

impl CountingGrid {
    /// At most this many cells per point: a finer grid than the radius allows would only add
    /// empty cells, a sparse scene with a tiny radius is given coarser cells instead.
    const CELLS_PER_POINT: usize = 8;

    fn new(points: &[[f64; 3]], radius: f64) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if points.is_empty() {
            (lo, hi) = ([0.0; 3], [0.0; 3]);
        }
        let limit = (Self::CELLS_PER_POINT * points.len()).max(64) as f64;
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        // Cells per axis at a cell size, if their product stays within the limit.
        let fits = |cell: f64| {
            let per_axis = extent.map(|e| (e / cell).floor() + 1.0);
            let total: f64 = per_axis.iter().product();
            (total <= limit).then(|| per_axis.map(|d| d as usize))
        };
        let mut cell = (2.0 * radius).max(f64::MIN_POSITIVE);
        let dims = loop {
            if !cell.is_finite() || extent.iter().any(|e| !e.is_finite()) {
                // Extents beyond f64 (coordinates near its limit): one cell holds everything,
                // and every query scans it; slow but exact.
                cell = f64::INFINITY;
                break [1, 1, 1];
            }
            if let Some(dims) = fits(cell) {
                break dims;
            }
            cell *= 1.5;
        };
        let inv_cell = if cell.is_finite() { 1.0 / cell } else { 0.0 };
        let cell_of = |p: &[f64; 3]| {
            let i = [0, 1, 2].map(|a| (((p[a] - lo[a]) * inv_cell) as usize).min(dims[a] - 1));
            i[0] + dims[0] * (i[1] + dims[1] * i[2])
        };
        let mut start = vec![0usize; dims[0] * dims[1] * dims[2] + 1];
        for p in points {
            start[cell_of(p) + 1] += 1;
        }
        for c in 1..start.len() {
            start[c] += start[c - 1];
        }
        let mut next = start.clone();
        let mut sorted = vec![[0.0; 3]; points.len()];
        for p in points {
            let c = cell_of(p);
            sorted[next[c]] = *p;
            next[c] += 1;
        }
        Self {
            origin: lo,
            inv_cell,
            dims,
            start,
            points: sorted,
        }
    }

    /// How many points lie strictly within `radius` (squared: `radius_sq`) of `q`.
    fn count_within(&self, q: [f64; 3], radius: f64, radius_sq: f64) -> usize {
        let mut span = [(0usize, 0usize); 3];
        for a in 0..3 {
            // Cell indices by truncation, which is the floor on the non-negative side kept
            // (`floor` is a library call on baseline x86-64).
            let first = (q[a] - radius - self.origin[a]) * self.inv_cell;
            let last = (q[a] + radius - self.origin[a]) * self.inv_cell;
            if last < 0.0 || first >= self.dims[a] as f64 {
                return 0;
            }
            span[a] = (
                first.max(0.0) as usize,
                (last as usize).min(self.dims[a] - 1),
            );
        }
        let mut count = 0;
        for k in span[2].0..=span[2].1 {
            for j in span[1].0..=span[1].1 {
                let row = self.dims[0] * (j + self.dims[1] * k);
                let run = self.start[row + span[0].0]..self.start[row + span[0].1 + 1];
                for p in &self.points[run] {
                    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                    count += usize::from(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < radius_sq);
                }
            }
        }
        count
    }
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
