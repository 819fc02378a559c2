//! Density pruning: inliers of one instance are mutually consistent and form dense rows of
//! `S`, while outliers are consistent with few others. Only per-row counts are needed, so rows
//! are computed block by block in parallel and memory stays O(block x N).

use rayon::prelude::*;

use crate::config::{Config, Pruning};
use crate::consistency::{beta_row, beta_value, inv_sigma_sq};
use crate::correspondences::{Correspondences, Features};
use crate::cpu::has_avx2;
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
    if c.pair_normals().is_none() && f32_fits(c) {
        match (config.pruning, features) {
            (Pruning::Paper, None) => {
                return Ok(paper_counts_f32(c, config.tau_s, inv, has_avx2()));
            }
            (_, Some(f)) => {
                if let Some(rule) = FeatureRule::of(config) {
                    return Ok(feature_counts_f32(c, f, rule, inv, has_avx2()));
                }
            }
            _ => {}
        }
    }
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

/// The paper's rule without features or normals, `beta_ij > tau_s`, is `|l_s - l_t| < D`
/// with `D = sqrt((1 - tau_s) / inv)`: decided in f32 on coordinates centred per side (lengths
/// do not change), eight lanes at a time and without a row buffer, and re-decided in f64
/// exactly as [`beta_value`](crate::consistency) does for the pairs whose f32 length
/// difference lies within its error bound of `D`. The counts equal the f64 ones exactly.
/// `wide`: run the AVX2 build of the row loop ([`has_avx2`]).
fn paper_counts_f32(c: &Correspondences, tau_s: f64, inv: f64, wide: bool) -> Vec<u32> {
    let n = c.len();
    if tau_s < 0.0 {
        return vec![n as u32; n]; // beta >= 0 > tau_s for every pair
    }
    LengthTestF32::new(c, tau_s, inv).counts_symmetric(wide)
}

/// Columns per tile of [`LengthTestF32::count_block`]: six f32 columns of this length (48 KB)
/// stay in the core's cache while a block of rows runs over them. Streaming every row over
/// all columns instead runs from the shared cache once N passes about 20,000 (N = 50,000:
/// three times the time per pair of N = 1000).
const COLUMN_TILE: usize = 2048;

/// A rule with features, `beta_ij` and the feature similarity `s_ij`, that only pairs with
/// `beta_ij > geometric` can pass: such pairs are a small share (well under 1 % on the
/// synthetic scenes), found by the f32 length test and decided exactly in f64.
#[derive(Clone, Copy, Debug)]
enum FeatureRule {
    /// The paper's `beta * s > tau_s` (needs `beta > 0` when `tau_s >= 0`).
    Paper { tau_s: f64 },
    /// The authors' code: `beta > beta_threshold` and `s > feature_threshold`.
    Authors {
        beta_threshold: f64,
        feature_threshold: f64,
    },
}

impl FeatureRule {
    /// The rule of `config`, or `None` where a pair with `beta = 0` could pass it (a
    /// negative threshold), which the f64 path then decides.
    fn of(config: &Config) -> Option<Self> {
        match config.pruning {
            Pruning::Paper if config.tau_s >= 0.0 => Some(Self::Paper {
                tau_s: config.tau_s,
            }),
            Pruning::AuthorsCode if config.beta_threshold >= 0.0 => Some(Self::Authors {
                beta_threshold: config.beta_threshold,
                feature_threshold: config.feature_threshold,
            }),
            _ => None,
        }
    }

    /// The `beta` a pair must exceed before its features matter.
    fn geometric(self) -> f64 {
        match self {
            Self::Paper { .. } => 0.0,
            Self::Authors { beta_threshold, .. } => beta_threshold,
        }
    }

    /// [`count_row`]'s decision for one pair, from the f64 `beta` and similarity.
    fn passes(self, beta: f64, similarity: f64) -> bool {
        match self {
            Self::Paper { tau_s } => beta > 0.0 && beta * similarity > tau_s,
            Self::Authors {
                beta_threshold,
                feature_threshold,
            } => beta > beta_threshold && similarity > feature_threshold,
        }
    }
}

/// Counts under a rule with features: the pairs within the f32 bound of the rule's length
/// test ([`FeatureRule::geometric`]) get the f64 `beta` of [`beta_value`] and the feature
/// similarity, exactly as [`count_row`] computes them; every other pair has `beta` at or
/// below that level and fails the rule. The counts equal the f64 path's exactly.
fn feature_counts_f32(
    c: &Correspondences,
    f: &Features,
    rule: FeatureRule,
    inv: f64,
    wide: bool,
) -> Vec<u32> {
    LengthTestF32::new(c, rule.geometric(), inv).featured_counts(f, rule, wide)
}

/// [`LengthTestF32::count_block`] compiled for AVX2. Without FMA: Rust never fuses
/// `a * b + c`, so the arithmetic, and every count, is the same as the baseline build's.
///
/// # Safety
/// The CPU must support AVX2 ([`has_avx2`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn count_block_avx2(
    test: &LengthTestF32<'_>,
    first: usize,
    out: &mut [u32],
    f: &Features,
    rule: FeatureRule,
) {
    test.count_block(first, out, f, rule)
}

/// [`LengthTestF32::count_upper_block`] compiled for AVX2, like [`count_block_avx2`].
///
/// # Safety
/// The CPU must support AVX2 ([`has_avx2`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn count_upper_block_avx2(
    rule: &LengthTestF32<'_>,
    rows: std::ops::Range<usize>,
    acc: &mut [u32],
) {
    rule.count_upper_block(rows, acc)
}

/// Centred coordinates up to this magnitude keep the f32 kernels' squared lengths finite
/// (about 1e36, against f32's 3.4e38); beyond it the f64 kernel decides every pair.
const F32_MAX_EXTENT: f64 = 1e18;

/// Whether every coordinate lies within [`F32_MAX_EXTENT`] of its column's mean (the
/// centring of [`centred_f32`]).
fn f32_fits(c: &Correspondences) -> bool {
    let side = |cols: &[Vec<f64>; 3]| {
        cols.iter().all(|col| {
            let mean = col.iter().sum::<f64>() / col.len().max(1) as f64;
            col.iter().all(|&v| (v - mean).abs() <= F32_MAX_EXTENT)
        })
    };
    side(c.source_columns()) && side(c.target_columns())
}

/// The columns minus their means, in f32 (lengths do not change), and the largest absolute
/// centred coordinate (in f64) that the error bound scales with.
fn centred_f32(cols: &[Vec<f64>; 3], n: usize) -> ([Vec<f32>; 3], f64) {
    let mut extent = 0.0f64;
    let out = std::array::from_fn(|k| {
        let mean = cols[k].iter().sum::<f64>() / n.max(1) as f64;
        cols[k]
            .iter()
            .map(|&v| {
                extent = extent.max((v - mean).abs());
                (v - mean) as f32
            })
            .collect()
    });
    (out, extent)
}

/// The band `[lo2, hi2]` of squared f32 length differences that f32 cannot decide against
/// `D^2 = (1 - tau_s) / inv`, for centred coordinates up to `extent`: below it the pair is
/// surely consistent, above it surely not.
fn undecided_band(tau_s: f64, inv: f64, extent: f64) -> (f32, f32) {
    // Rounding of the inputs, the differences, the sums of squares and the square roots: each
    // length is off by at most ~21 u M (u = 2^-24, M the largest centred coordinate), so the
    // difference by ~42 u M; 64 u M leaves room, plus a relative term for the f64 rule itself.
    let d = ((1.0 - tau_s) / inv).max(0.0).sqrt();
    let err = 64.0 * f64::from(f32::EPSILON) * extent + 1e-9 * d;
    let lo = (d - err).max(0.0);
    let (lo2, hi2) = ((lo * lo) as f32, ((d + err) * (d + err)) as f32);
    // f32 rounding of the bounds themselves: widen the band by one ulp each way.
    (f32_down(lo2), f32_up(hi2))
}

/// The length test `|l_s - l_t| < D` decided in f32 on centred columns `s`, `t`, with the f64
/// columns `src`, `dst` and [`beta_value`] for the pairs in the undecided band `[lo2, hi2]`:
/// the paper's rule `beta > tau_s` alone ([`Self::counts_symmetric`]), or the prefilter of a
/// rule with features, whose candidates are every pair up to `hi2`
/// ([`Self::featured_counts`]).
struct LengthTestF32<'a> {
    s: [Vec<f32>; 3],
    t: [Vec<f32>; 3],
    src: &'a [Vec<f64>; 3],
    dst: &'a [Vec<f64>; 3],
    lo2: f32,
    hi2: f32,
    tau_s: f64,
    inv: f64,
}

impl<'a> LengthTestF32<'a> {
    /// The test at `D^2 = (1 - tau) / inv` on the correspondences `c` (centred per side), for
    /// the paper's rule at `tau_s = tau` or for a feature rule's prefilter.
    fn new(c: &'a Correspondences, tau: f64, inv: f64) -> Self {
        let n = c.len();
        let (s, ms) = centred_f32(c.source_columns(), n);
        let (t, mt) = centred_f32(c.target_columns(), n);
        let (lo2, hi2) = undecided_band(tau, inv, ms.max(mt));
        Self {
            s,
            t,
            src: c.source_columns(),
            dst: c.target_columns(),
            lo2,
            hi2,
            tau_s: tau,
            inv,
        }
    }

    /// Every row's count under `rule`, whose candidates are the pairs with `q <= hi2`; blocks
    /// of rows in parallel, in 8 lanes where `wide`.
    fn featured_counts(&self, f: &Features, rule: FeatureRule, wide: bool) -> Vec<u32> {
        let mut counts = vec![0u32; self.src[0].len()];
        counts
            .par_chunks_mut(BLOCK_ROWS)
            .enumerate()
            .for_each(|(block, out)| {
                self.count_block_dispatched(block * BLOCK_ROWS, out, f, rule, wide)
            });
        counts
    }

    /// Every row's count under the paper's rule alone, from the pairs `j >= i` only: the
    /// test is symmetric bit for bit (the same differences squared, in the same order, on
    /// either side), so each pair adds to both its rows and half the lengths are computed.
    /// Blocks of rows in parallel, each adding into its task's counts; integer sums, so the
    /// result is the same whatever the split and the thread count.
    fn counts_symmetric(&self, wide: bool) -> Vec<u32> {
        let n = self.src[0].len();
        (0..n.div_ceil(BLOCK_ROWS))
            .into_par_iter()
            .fold(
                || vec![0u32; n],
                |mut acc, block| {
                    let rows = block * BLOCK_ROWS..((block + 1) * BLOCK_ROWS).min(n);
                    self.count_upper_dispatched(rows, &mut acc, wide);
                    acc
                },
            )
            .reduce(
                || vec![0u32; n],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            )
    }

    /// [`Self::count_upper_block`], in 8 lanes where `wide` ([`has_avx2`]).
    fn count_upper_dispatched(&self, rows: std::ops::Range<usize>, acc: &mut [u32], wide: bool) {
        #[cfg(target_arch = "x86_64")]
        if wide {
            // SAFETY: `wide` comes from `has_avx2`, which checked that the CPU has AVX2.
            return unsafe { count_upper_block_avx2(self, rows, acc) };
        }
        let _ = wide;
        self.count_upper_block(rows, acc)
    }

    /// Adds the pairs `(i, j)`, `i` in `rows`, `j >= i`, that pass the rule to `acc[i]` and
    /// (for `j > i`) to `acc[j]`, the columns taken [`COLUMN_TILE`] at a time.
    #[inline(always)]
    fn count_upper_block(&self, rows: std::ops::Range<usize>, acc: &mut [u32]) {
        let n = self.s[0].len();
        for i in rows.clone() {
            acc[i] += u32::from(self.passes(i, i));
        }
        for start in (rows.start..n).step_by(COLUMN_TILE) {
            let end = (start + COLUMN_TILE).min(n);
            for i in rows.clone() {
                let first = (i + 1).max(start);
                if first < end {
                    acc[i] += self.count_upper(i, first..end, acc);
                }
            }
        }
    }

    /// How many `j` in `cols` (all after `i`) pass, each passing pair also added to
    /// `acc[j]`: branch-free in f32 over the tile, then the pairs of the undecided band in f64.
    #[inline(always)]
    fn count_upper(&self, i: usize, cols: std::ops::Range<usize>, acc: &mut [u32]) -> u32 {
        let (lo2, hi2) = (self.lo2, self.hi2);
        let (mut sure, mut near) = (0u32, 0u32);
        for (q, a) in self
            .length_diffs(i, cols.clone())
            .zip(&mut acc[cols.clone()])
        {
            let pass = u32::from(q < lo2);
            sure += pass;
            *a += pass;
            near += u32::from((q >= lo2) & (q <= hi2));
        }
        if near > 0 {
            for (j, qj) in cols.clone().zip(self.length_diffs(i, cols)) {
                if qj >= lo2 && qj <= hi2 {
                    let pass = u32::from(self.passes_exactly(i, j));
                    sure += pass;
                    acc[j] += pass;
                }
            }
        }
        sure
    }

    /// Whether the pair `(i, j)` passes, decided as the row kernels decide it.
    fn passes(&self, i: usize, j: usize) -> bool {
        let q: f32 = self.length_diffs(i, j..j + 1).sum(); // the one pair's
        q < self.lo2 || (q <= self.hi2 && self.passes_exactly(i, j))
    }

    /// The paper's rule in f64, `beta_ij > tau_s`.
    #[inline(always)]
    fn passes_exactly(&self, i: usize, j: usize) -> bool {
        self.beta(i, j) > self.tau_s
    }

    /// `beta_ij` in f64, with [`beta_value`]'s arithmetic.
    #[inline(always)]
    fn beta(&self, i: usize, j: usize) -> f64 {
        let (src, dst) = (self.src, self.dst);
        let ds = std::array::from_fn(|k| src[k][j] - src[k][i]);
        let dt = std::array::from_fn(|k| dst[k][j] - dst[k][i]);
        beta_value(ds, dt, self.inv)
    }

    /// [`Self::count_block`], in 8 lanes where `wide` ([`has_avx2`]).
    fn count_block_dispatched(
        &self,
        first: usize,
        out: &mut [u32],
        f: &Features,
        rule: FeatureRule,
        wide: bool,
    ) {
        #[cfg(target_arch = "x86_64")]
        if wide {
            // SAFETY: `wide` comes from `has_avx2`, which checked that the CPU has AVX2.
            return unsafe { count_block_avx2(self, first, out, f, rule) };
        }
        let _ = wide;
        self.count_block(first, out, f, rule)
    }

    /// For rows `first..first + out.len()`: how many `j` (including `i`) pass `rule`, the
    /// columns taken [`COLUMN_TILE`] at a time.
    #[inline(always)]
    fn count_block(&self, first: usize, out: &mut [u32], f: &Features, rule: FeatureRule) {
        let n = self.s[0].len();
        out.fill(0);
        let mut lengths = Vec::new();
        for start in (0..n).step_by(COLUMN_TILE) {
            let cols = start..(start + COLUMN_TILE).min(n);
            for (k, slot) in out.iter_mut().enumerate() {
                *slot += self.count_featured(first + k, cols.clone(), f, rule, &mut lengths);
            }
        }
    }

    /// The squared f32 length differences of row `i` against `cols`, in an order the
    /// compiler vectorises (zipped slices, no bounds checks).
    #[inline(always)]
    fn length_diffs(
        &self,
        i: usize,
        cols: std::ops::Range<usize>,
    ) -> impl Iterator<Item = f32> + '_ {
        let (s, t) = (&self.s, &self.t);
        let (si, ti) = ([s[0][i], s[1][i], s[2][i]], [t[0][i], t[1][i], t[2][i]]);
        let c = cols;
        let (s0, s1, s2) = (&s[0][c.clone()], &s[1][c.clone()], &s[2][c.clone()]);
        let (t0, t1, t2) = (&t[0][c.clone()], &t[1][c.clone()], &t[2][c]);
        s0.iter()
            .zip(s1)
            .zip(s2)
            .zip(t0)
            .zip(t1.iter().zip(t2))
            .map(move |((((&a0, &a1), &a2), &b0), (&b1, &b2))| {
                length_diff_sq([a0, a1, a2], [b0, b1, b2], si, ti)
            })
    }

    /// How many `j` in `cols` pass `rule`: the lengths go to `buf` in one vectorised pass,
    /// then the few within `hi2` are decided in f64.
    #[inline(always)]
    fn count_featured(
        &self,
        i: usize,
        cols: std::ops::Range<usize>,
        f: &Features,
        rule: FeatureRule,
        buf: &mut Vec<f32>,
    ) -> u32 {
        // A plain loop rather than `extend`: the iterator's fold is then inlined into the AVX2
        // build instead of called as a baseline function.
        buf.resize(cols.len(), 0.0);
        for (slot, q) in buf.iter_mut().zip(self.length_diffs(i, cols.clone())) {
            *slot = q;
        }
        let hi2 = self.hi2;
        let mut count = 0;
        for (chunk, block) in buf.chunks(8).enumerate() {
            if block.iter().all(|&q| q > hi2) {
                continue;
            }
            for (k, &q) in block.iter().enumerate() {
                if q <= hi2 {
                    let j = cols.start + 8 * chunk + k;
                    count += u32::from(rule.passes(self.beta(i, j), f.similarity(i, j)));
                }
            }
        }
        count
    }
}

/// `(|a - ai| - |b - bi|)^2` in f32.
#[inline(always)]
fn length_diff_sq(a: [f32; 3], b: [f32; 3], ai: [f32; 3], bi: [f32; 3]) -> f32 {
    let (a0, a1, a2) = (a[0] - ai[0], a[1] - ai[1], a[2] - ai[2]);
    let (b0, b1, b2) = (b[0] - bi[0], b[1] - bi[1], b[2] - bi[2]);
    let dl = (a0 * a0 + a1 * a1 + a2 * a2).sqrt() - (b0 * b0 + b1 * b1 + b2 * b2).sqrt();
    dl * dl
}

fn f32_down(v: f32) -> f32 {
    if v > 0.0 {
        f32::from_bits(v.to_bits() - 1)
    } else {
        v
    }
}

fn f32_up(v: f32) -> f32 {
    f32::from_bits(v.to_bits() + 1)
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
