//! Descriptor matching: from per-point descriptors of the source (the model) and the target
//! (the scene) to putative correspondences, as the paper's appendix builds them for Scan2CAD.
//!
//! Every target point is matched to its `k` most similar source descriptors; the descriptor
//! distance is each match's saliency score. The `top_k` most salient matches are kept
//! (optionally only mutual ones), then `n_samples` of them are drawn at random, so that the
//! pipeline sees a bounded number of correspondences whatever the cloud sizes.
//!
//! Why more than the nearest: with several copies in the scan, a model point has one mutual
//! nearest scan point at most, so mutual nearest matching caps every copy but the best-seen at
//! a handful of true matches; and a noisy scan descriptor's true partner is often second or
//! third. `k > 1` lets every scan point propose its few best model points.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, Par};
use rand::seq::index::sample;
use rayon::prelude::*;

use crate::correspondences::Features;
use crate::error::{Error, Result};
use crate::seeds::{stream, STAGE_MATCHING};

/// How many matches to keep and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchingConfig {
    /// Keep the `top_k` matches with the smallest descriptor distance (paper: 10,000).
    pub top_k: usize,
    /// Keep only mutual matches: the target point is also among the `k` nearest target
    /// descriptors of the source point (with `k = 1`: mutual nearest neighbours).
    pub mutual: bool,
    /// Source descriptors matched to each target descriptor, nearest first (>= 1).
    pub k: usize,
    /// Then draw this many of them uniformly at random (paper: 1000); `None` keeps all.
    pub n_samples: Option<usize>,
}

impl Default for MatchingConfig {
    fn default() -> Self {
        Self {
            top_k: 10_000,
            mutual: false,
            k: 1,
            n_samples: Some(1000),
        }
    }
}

/// Matched pairs, most salient (smallest descriptor distance) first.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Matches {
    /// Row of the source descriptor (source point index).
    pub source: Vec<usize>,
    /// Row of the target descriptor (target point index).
    pub target: Vec<usize>,
    /// Euclidean distance between the two descriptors.
    pub distance: Vec<f64>,
}

impl Matches {
    /// Number of matches.
    pub fn len(&self) -> usize {
        self.source.len()
    }

    /// True when nothing matched.
    pub fn is_empty(&self) -> bool {
        self.source.is_empty()
    }
}

/// Matches every target descriptor to its `k` nearest source descriptors, then keeps and samples
/// as `config` says. Parallel over target rows on the current rayon pool; the result depends
/// only on the inputs and `seed`.
pub fn match_features(
    source: &Features,
    target: &Features,
    config: &MatchingConfig,
    seed: u64,
) -> Result<Matches> {
    check_inputs(source, target, config)?;
    let k = config.k.min(source.len());
    let (src_of_tgt, dist2) = nearest_rows(target, source, k);
    Ok(select(source, target, config, seed, k, &src_of_tgt, &dist2))
}

/// Every target row's `k` nearest source rows (`k` capped at the source's rows), nearest
/// first, flattened row after row, with their squared descriptor distances.
///
/// Why apart from [`match_features`]: a target row's nearest source rows do not depend on the
/// other target rows, so a caller matching several subsets of one target (peeling matches the
/// scan points no accepted copy explains, pass after pass) computes them once and hands each
/// subset's rows to [`match_features_given`].
#[derive(Debug, Clone, PartialEq)]
pub struct NearestSources {
    pub k: usize,
    pub source: Vec<usize>,
    pub dist2: Vec<f64>,
}

/// [`NearestSources`] of every target row; parallel on the current rayon pool, exact.
pub fn nearest_sources(source: &Features, target: &Features, k: usize) -> Result<NearestSources> {
    let config = MatchingConfig {
        k,
        ..MatchingConfig::default()
    };
    check_inputs(source, target, &config)?;
    let k = k.min(source.len());
    let (source_rows, dist2) = nearest_rows(target, source, k);
    Ok(NearestSources {
        k,
        source: source_rows,
        dist2,
    })
}

/// [`match_features`] with the target rows' nearest source rows already known (`nearest`,
/// row for row with `target`, as [`nearest_sources`] gives them): the same result, without
/// the search from the target side.
pub fn match_features_given(
    source: &Features,
    target: &Features,
    nearest: &NearestSources,
    config: &MatchingConfig,
    seed: u64,
) -> Result<Matches> {
    check_inputs(source, target, config)?;
    let k = config.k.min(source.len());
    if nearest.k != k {
        return Err(Error::InvalidParameter {
            name: "nearest",
            value: format!("{} neighbours per row", nearest.k),
            reason: "must hold as many neighbours per row as the matching's k (capped at the source rows)",
        });
    }
    for (what, got) in [
        (
            "nearest source rows (k per target row)",
            nearest.source.len(),
        ),
        ("nearest distances (k per target row)", nearest.dist2.len()),
    ] {
        if got != target.len() * k {
            return Err(Error::LengthMismatch {
                what,
                expected: target.len() * k,
                got,
            });
        }
    }
    if let Some(row) = nearest.source.iter().position(|&s| s >= source.len()) {
        return Err(Error::InvalidParameter {
            name: "nearest",
            value: format!("source row {} at position {row}", nearest.source[row]),
            reason: "names a source row that does not exist",
        });
    }
    if let Some(row) = nearest.dist2.iter().position(|d| !d.is_finite()) {
        return Err(Error::NonFinite {
            what: "nearest distances",
            row: row / k,
        });
    }
    Ok(select(
        source,
        target,
        config,
        seed,
        k,
        &nearest.source,
        &nearest.dist2,
    ))
}

/// The matches kept from each target row's `k` nearest source rows (candidate p is the
/// (p % k)-th nearest source row of target row p / k): mutual ones if asked, the `top_k`
/// closest, then `n_samples` drawn with `seed`.
fn select(
    source: &Features,
    target: &Features,
    config: &MatchingConfig,
    seed: u64,
    k: usize,
    src_of_tgt: &[usize],
    dist2: &[f64],
) -> Matches {
    let mut order: Vec<usize> = (0..src_of_tgt.len()).collect();
    if config.mutual && k == 1 && config.k == 1 {
        let mutual = mutual_nearest(source, target, src_of_tgt, dist2);
        order.retain(|&p| mutual[p]);
    } else if config.mutual {
        let kt = config.k.min(target.len());
        let (tgt_of_src, _) = nearest_rows(source, target, kt);
        order.retain(|&p| {
            let s = src_of_tgt[p];
            tgt_of_src[s * kt..(s + 1) * kt].contains(&(p / k))
        });
    }
    // Ties broken by target index then rank, so the order is total and reproducible.
    order.sort_unstable_by(|&a, &b| dist2[a].total_cmp(&dist2[b]).then(a.cmp(&b)));
    order.truncate(config.top_k);
    if let Some(n) = config.n_samples {
        if n < order.len() {
            let mut rng = stream(seed, STAGE_MATCHING, 0);
            let mut picked = sample(&mut rng, order.len(), n).into_vec();
            picked.sort_unstable();
            order = picked.into_iter().map(|i| order[i]).collect();
        }
    }
    Matches {
        source: order.iter().map(|&p| src_of_tgt[p]).collect(),
        target: order.iter().map(|&p| p / k).collect(),
        distance: order.iter().map(|&p| dist2[p].max(0.0).sqrt()).collect(),
    }
}

/// Which target rows are mutual nearest neighbours of their nearest source row, given each
/// target row's nearest source row and squared distance (exact, as [`nearest_rows`] gives
/// them): the same verdicts as searching every source row's nearest target row, ties to the
/// lower row, without that search.
///
/// Why: only a source row that some target row chose can be in a mutual pair, and only with
/// the closest target row that chose it (`p*`, at `t`). A target row `q` is at least its own
/// nearest distance `d_q` from every source row (the distances are the same f64 sums in both
/// directions: a difference's negation is exact), so only the rows with `d_q <= t` can be
/// nearer to that source row than `p*`. Those are a prefix of the rows sorted by `d_q`: on
/// FPFH scans 1-3 % of the full source x target search.
fn mutual_nearest(
    source: &Features,
    target: &Features,
    src_of_tgt: &[usize],
    dist2: &[f64],
) -> Vec<bool> {
    let n = src_of_tgt.len();
    // The closest target row of each chosen source row (ties to the lower row).
    let mut closest: Vec<Option<usize>> = vec![None; source.len()];
    for p in 0..n {
        let c = &mut closest[src_of_tgt[p]];
        if c.is_none_or(|q| dist2[p] < dist2[q]) {
            *c = Some(p);
        }
    }
    let mut by_distance: Vec<usize> = (0..n).collect();
    by_distance.sort_unstable_by(|&a, &b| dist2[a].total_cmp(&dist2[b]).then(a.cmp(&b)));
    let sorted: Vec<f64> = by_distance.iter().map(|&p| dist2[p]).collect();
    let chosen: Vec<(usize, usize)> = closest
        .iter()
        .enumerate()
        .filter_map(|(s, c)| c.map(|p| (s, p)))
        .collect();
    let winners: Vec<usize> = chosen
        .par_iter()
        .filter_map(|&(s, best)| {
            let t = dist2[best];
            let query = source.row(s);
            let reach = sorted.partition_point(|&d| d <= t);
            // A nearer row, or an equally near lower row, takes the source row from `best`.
            // The distance summed in four lanes decides unless it lies within its rounding
            // of `t`; then the sum in `nearest_rows`' order does.
            let slack = 1e-12 * t + 1e-300;
            let beaten = by_distance[..reach].iter().any(|&q| {
                q != best && {
                    let row = target.row(q);
                    let quick = lane_sum_sq(query, row);
                    if quick < t - slack {
                        true
                    } else if quick > t + slack {
                        false
                    } else {
                        let d = direct_d2(query, row);
                        d < t || (d == t && q < best)
                    }
                }
            });
            (!beaten).then_some(best)
        })
        .collect();
    let mut mutual = vec![false; n];
    for p in winners {
        mutual[p] = true;
    }
    mutual
}

/// `|a - b|^2` summed in four interleaved lanes (which vectorise): the same squares as the
/// sequential sum, added in another order, so within a relative 33 rounding units of it.
#[inline]
fn lane_sum_sq(a: &[f64], b: &[f64]) -> f64 {
    let mut lanes = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| (x - y) * (x - y))
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            lanes[l] += (x[l] - y[l]) * (x[l] - y[l]);
        }
    }
    (lanes[0] + lanes[1]) + (lanes[2] + lanes[3]) + tail
}

/// The errors [`match_features`] reports before any work.
fn check_inputs(source: &Features, target: &Features, config: &MatchingConfig) -> Result<()> {
    if source.is_empty() || target.is_empty() {
        return Err(Error::TooFewPoints {
            what: if source.is_empty() {
                "source descriptors"
            } else {
                "target descriptors"
            },
            got: 0,
            min: 1,
        });
    }
    if source.dim() != target.dim() {
        return Err(Error::LengthMismatch {
            what: "target descriptor length (must equal the source's)",
            expected: source.dim(),
            got: target.dim(),
        });
    }
    if config.top_k == 0 {
        return Err(Error::InvalidParameter {
            name: "top_k",
            value: "0".into(),
            reason: "must keep at least one match",
        });
    }
    if config.k == 0 {
        return Err(Error::InvalidParameter {
            name: "k",
            value: "0".into(),
            reason: "must match each target descriptor to at least one source descriptor",
        });
    }
    if config.n_samples == Some(0) {
        return Err(Error::InvalidParameter {
            name: "n_samples",
            value: "0".into(),
            reason: "must sample at least one match (or None for all)",
        });
    }
    Ok(())
}

/// Rows of queries handled per matrix product: large enough for an efficient product, small
/// enough that a block of distances (`BLOCK x base rows`) stays in cache-sized memory.
const BLOCK: usize = 128;

/// Descriptors with an entry beyond this magnitude could overflow f32 products; they take the
/// f64 path. FPFH histograms hold values up to 100.
const F32_MAX_ENTRY: f64 = 1e15;

/// For every query row, its `k` nearest base rows (`1 <= k <= base.len()`), nearest first, and
/// the squared distances to them, flattened row after row (`n * k`). Exact brute force:
/// `|q|^2 + |b|^2 - 2 q.b` by blocked matrix products screens the rows, then the distances
/// of every row the screen cannot rule out are computed directly and ranked (ties by base
/// row), so the result is the exact k nearest rows.
///
/// Why f32 for the screen: the products are most of the matching's time, twice as fast in
/// f32; their error bound widens the screen by a sliver (a few rows at most), and the direct
/// distances in f64 decide.
fn nearest_rows(queries: &Features, base: &Features, k: usize) -> (Vec<usize>, Vec<f64>) {
    let small =
        |f: &Features| (0..f.len()).all(|i| f.row(i).iter().all(|v| v.abs() <= F32_MAX_ENTRY));
    if small(queries) && small(base) {
        screened_rows::<f32>(queries, base, k)
    } else {
        screened_rows::<f64>(queries, base, k)
    }
}

/// [`nearest_rows`] with the screen's products in `T`.
fn screened_rows<T: Screen>(
    queries: &Features,
    base: &Features,
    k: usize,
) -> (Vec<usize>, Vec<f64>) {
    let base_norm: Vec<f64> = (0..base.len())
        .map(|i| base.row(i).iter().map(|v| v * v).sum())
        .collect();
    let n = queries.len();
    let base_mat = Mat::<T>::from_fn(base.len(), base.dim(), |i, j| T::from_f64(base.row(i)[j]));
    let blocks: Vec<(Vec<usize>, Vec<f64>)> = (0..n.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| screened_block(queries, base, &base_mat, &base_norm, b, k))
        .collect();
    let mut idx = Vec::with_capacity(n * k);
    let mut d2 = Vec::with_capacity(n * k);
    for (a, b) in blocks {
        idx.extend(a);
        d2.extend(b);
    }
    (idx, d2)
}

/// The matrix products' precision: f32 for the usual descriptors, f64 for huge ones.
trait Screen: faer::traits::ComplexField + Copy {
    /// Rounding unit.
    const UNIT: f64;
    /// The column as f32 when the screen runs in f32 (descriptors up to [`F32_MAX_ENTRY`], so
    /// every product is finite): the nearest-row fast path's input.
    fn f32_column(col: &[Self]) -> Option<&[f32]>;
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
}

impl Screen for f32 {
    const UNIT: f64 = f32::EPSILON as f64 / 2.0;
    fn f32_column(col: &[Self]) -> Option<&[f32]> {
        Some(col)
    }
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
}

impl Screen for f64 {
    const UNIT: f64 = f64::EPSILON / 2.0;
    fn f32_column(_: &[Self]) -> Option<&[f32]> {
        None
    }
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// The k nearest base rows of the queries in block `b` (see [`nearest_rows`]).
fn screened_block<T: Screen>(
    queries: &Features,
    base: &Features,
    base_mat: &Mat<T>,
    base_norm: &[f64],
    b: usize,
    k: usize,
) -> (Vec<usize>, Vec<f64>) {
    let dim = base.dim();
    let lo = b * BLOCK;
    let hi = (lo + BLOCK).min(queries.len());
    let q = Mat::<T>::from_fn(dim, hi - lo, |j, i| T::from_f64(queries.row(lo + i)[j]));
    // Column i of g holds q_i . b_j for every base row j, contiguous in j.
    let mut g = Mat::<T>::zeros(base.len(), hi - lo);
    matmul(
        g.as_mut(),
        Accum::Replace,
        base_mat.as_ref(),
        q.as_ref(),
        T::from_f64(1.0),
        Par::Seq,
    );
    // |computed - true| of `|b|^2 - 2 q.b` is below `err * (|q|^2 + |b|^2)`: the conversion,
    // the sum of dim products (any order, with or without FMA) and the subtraction, with room
    // to spare; `tiny` covers underflow.
    let err = 4.0 * (dim as f64 + 4.0) * T::UNIT;
    let tiny = 1e-30;
    let mut best = (
        Vec::with_capacity((hi - lo) * k),
        Vec::with_capacity((hi - lo) * k),
    );
    // Reused by every query of the block: no allocation per query on this hot path.
    let mut scratch = (Vec::with_capacity(k + 1), Vec::new());
    let max_norm = base_norm.iter().fold(0.0f64, |m, &v| m.max(v));
    let norm32: Vec<f32> = base_norm.iter().map(|&v| v as f32).collect();
    // The fast path's bound also covers the f32 norms and the f32 difference (3 roundings of
    // at most |q|^2 + |b|^2 each).
    let err32 = err + 8.0 * f64::from(f32::EPSILON);
    for i in 0..hi - lo {
        let query = queries.row(lo + i);
        let qn: f64 = query.iter().map(|v| v * v).sum();
        let col = g.col_as_slice(i);
        if let Some(col32) = T::f32_column(col) {
            let screened = ScreenedQuery {
                query,
                qn,
                col: col32,
                norm: &norm32,
                max_norm,
                bound: (err32, tiny),
            };
            nearest_screened_dispatched(&screened, base, k, &mut scratch, &mut best);
            continue;
        }
        let bounds = |j: usize| {
            let v = base_norm[j] - 2.0 * col[j].to_f64();
            let e = err * (qn + base_norm[j]) + tiny;
            // Overflowing descriptors (f64 path only) rule nothing out: the direct distance
            // decides, infinite ones ranking last.
            if v.is_finite() && e.is_finite() {
                (v - e, v + e)
            } else {
                (f64::NEG_INFINITY, f64::INFINITY)
            }
        };
        rank_query(query, base, k, bounds, &mut scratch, &mut best);
    }
    best
}

/// Appends the k nearest base rows of `query` and their squared distances to `out`, nearest
/// first, given bounds on every row's squared distance up to a constant (`bounds(j)`: lower,
/// upper). One sweep: `top` keeps the k smallest upper bounds so far, whose largest only
/// shrinks; a row whose lower bound exceeds it can never be among the k nearest, so only rows
/// under the running cut are kept, the final cut prunes them, and direct distances rank the
/// rest. `scratch` holds `top` and the candidates (cleared here).
fn rank_query(
    query: &[f64],
    base: &Features,
    k: usize,
    bounds: impl Fn(usize) -> (f64, f64),
    scratch: &mut (Ranked, Ranked),
    out: &mut (Vec<usize>, Vec<f64>),
) {
    let (top, cands) = scratch;
    top.clear();
    cands.clear();
    for j in 0..base.len() {
        let (lower, upper) = bounds(j);
        if top.len() < k || lower <= top[k - 1].0 {
            cands.push((lower, j));
            keep_smallest(top, k, upper, j);
        }
    }
    let cut = top[top.len() - 1].0;
    top.clear();
    for &(lower, j) in cands.iter() {
        if lower <= cut {
            let d2 = direct_d2(query, base.row(j));
            keep_smallest(top, k, d2, j);
        }
    }
    for &(d2, j) in top.iter() {
        out.0.push(j);
        out.1.push(d2);
    }
}

/// The nearest base row of `query` from the f32 screen's column `col` (`q . b_j` for every
/// base row) and `norm` (`|b_j|^2` in f32; `max_norm` the largest in f64): what
/// [`rank_query`] gives for `k = 1`, without its running list. Every `c_j = |b_j|^2 - 2 q . b_j`
/// as computed in f32 is within `e = err (|q|^2 + max_norm) + tiny` of its true value (`err`
/// covers the product, the norm's and the difference's f32 roundings), so the nearest row has
/// `c_j <= min c + 2 e`; those rows are ranked by direct distance in f64, ties to the lower
/// row. Both sweeps are branch-free f32 arithmetic, compiled for AVX2 where the CPU has it.
#[inline(always)]
fn nearest_one(s: &ScreenedQuery<'_>, base: &Features, out: &mut (Vec<usize>, Vec<f64>)) {
    let (query, qn, col, norm, max_norm) = (s.query, s.qn, s.col, s.norm, s.max_norm);
    let (err, tiny) = s.bound;
    const LANES: usize = 8;
    let c = |g: f32, bn: f32| bn - 2.0 * g;
    let mut lanes = [f32::INFINITY; LANES];
    let (cg, cb) = (col.chunks_exact(LANES), norm.chunks_exact(LANES));
    let mut least = cg
        .remainder()
        .iter()
        .zip(cb.remainder())
        .fold(f32::INFINITY, |m, (&g, &bn)| m.min(c(g, bn)));
    for (g, bn) in cg.zip(cb) {
        for l in 0..LANES {
            let x = c(g[l], bn[l]);
            lanes[l] = if x < lanes[l] { x } else { lanes[l] };
        }
    }
    for m in lanes {
        least = least.min(m);
    }
    let mut limit = widened(
        f64::from(least) + 2.0 * (err * (qn + max_norm) + tiny),
        tiny,
    );
    let mut best: Option<(f64, usize)> = None;
    let mut rank = |j: usize| {
        let d2 = direct_d2(query, base.row(j));
        if best.is_none_or(|(b, _)| d2 < b) {
            best = Some((d2, j));
        }
    };
    under_limit(col, norm, &mut limit, |j, _, _| rank(j));
    // `base` is never empty (k <= base.len()), and the row of the least `c` is under the limit.
    let (d2, j) = best.unwrap_or((f64::INFINITY, 0));
    out.0.push(j);
    out.1.push(d2);
}

/// `|a - b|^2` summed in row order: the exact distance every ranking compares.
#[inline(always)]
fn direct_d2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// `limit` (in f64) as an f32 no smaller: widened past the rounding of the conversion.
#[inline(always)]
fn widened(limit: f64, tiny: f64) -> f32 {
    (limit + limit.abs() * 1e-6 + tiny) as f32
}

/// Calls `visit(row, c, limit)`, in row order, for every row whose screened value
/// `c = |b|^2 - 2 q . b` (f32, from the screen's column `col` and the rows' norms `norm`) is at
/// most `limit`, which `visit` may lower. Few rows pass: each block of 8 lanes is tested
/// branch-free first, and only a block holding one is scanned row by row.
#[inline(always)]
fn under_limit(
    col: &[f32],
    norm: &[f32],
    limit: &mut f32,
    mut visit: impl FnMut(usize, f32, &mut f32),
) {
    const LANES: usize = 8;
    let c = |g: f32, bn: f32| bn - 2.0 * g;
    let (cg, cb) = (col.chunks_exact(LANES), norm.chunks_exact(LANES));
    let tail = cg.len() * LANES;
    let (rg, rb) = (cg.remainder(), cb.remainder());
    for (block, (g, bn)) in cg.zip(cb).enumerate() {
        let mut any = false;
        for l in 0..LANES {
            any |= c(g[l], bn[l]) <= *limit;
        }
        if any {
            for l in 0..LANES {
                let x = c(g[l], bn[l]);
                if x <= *limit {
                    visit(block * LANES + l, x, limit);
                }
            }
        }
    }
    for (l, (&g, &bn)) in rg.iter().zip(rb).enumerate() {
        let x = c(g, bn);
        if x <= *limit {
            visit(tail + l, x, limit);
        }
    }
}

/// The `k` nearest base rows of the query, nearest first: what [`rank_query`] gives, from the
/// f32 screen as [`nearest_one`] reads it. One sweep keeps the `k` least screened values `c`
/// and every row whose `c` is within twice the error bound of the running `k`-th least (the
/// running value only falls, so every row of the true `k` nearest passes when it comes); the
/// final `k`-th least cuts the candidates again, and direct f64 distances rank the rest, ties
/// to the lower row. Why: peeling in a heap looks up every model point's 64 nearest scan
/// points, and the general sweep's per-row bookkeeping was most of its time.
#[inline(always)]
fn nearest_k(
    s: &ScreenedQuery<'_>,
    base: &Features,
    k: usize,
    scratch: &mut (Ranked, Ranked),
    out: &mut (Vec<usize>, Vec<f64>),
) {
    let (query, qn, col, norm, max_norm) = (s.query, s.qn, s.col, s.norm, s.max_norm);
    let (err, tiny) = s.bound;
    let slack = 2.0 * (err * (qn + max_norm) + tiny);
    let limit_of = |kth: f64| widened(kth + slack, tiny);
    let (top, cands) = scratch;
    top.clear();
    cands.clear();
    let mut limit = f32::INFINITY;
    under_limit(col, norm, &mut limit, |j, x, limit| {
        cands.push((f64::from(x), j));
        keep_smallest(top, k, f64::from(x), j);
        if top.len() == k {
            *limit = limit_of(top[k - 1].0);
        }
    });
    // `base` holds at least `k` rows, so `top` is full.
    let limit = limit_of(top[top.len() - 1].0);
    top.clear();
    for &(x, j) in cands.iter() {
        if x as f32 <= limit {
            let d2 = direct_d2(query, base.row(j));
            keep_smallest(top, k, d2, j);
        }
    }
    for &(d2, j) in top.iter() {
        out.0.push(j);
        out.1.push(d2);
    }
}

/// The query's `k` nearest base rows from its f32 screen: [`nearest_one`] for one,
/// [`nearest_k`] for more.
#[inline(always)]
fn nearest_screened(
    s: &ScreenedQuery<'_>,
    base: &Features,
    k: usize,
    scratch: &mut (Ranked, Ranked),
    out: &mut (Vec<usize>, Vec<f64>),
) {
    if k == 1 {
        nearest_one(s, base, out)
    } else {
        nearest_k(s, base, k, scratch, out)
    }
}

/// [`nearest_screened`] compiled for AVX2 (no FMA: the arithmetic is the baseline build's).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn nearest_screened_avx2(
    s: &ScreenedQuery<'_>,
    base: &Features,
    k: usize,
    scratch: &mut (Ranked, Ranked),
    out: &mut (Vec<usize>, Vec<f64>),
) {
    nearest_screened(s, base, k, scratch, out)
}

/// [`nearest_screened`], in 8 lanes where the CPU has AVX2.
fn nearest_screened_dispatched(
    s: &ScreenedQuery<'_>,
    base: &Features,
    k: usize,
    scratch: &mut (Ranked, Ranked),
    out: &mut (Vec<usize>, Vec<f64>),
) {
    #[cfg(target_arch = "x86_64")]
    if crate::cpu::has_avx2() {
        // SAFETY: the CPU has AVX2, checked on the line above.
        return unsafe { nearest_screened_avx2(s, base, k, scratch, out) };
    }
    nearest_screened(s, base, k, scratch, out)
}

/// One query of [`nearest_one`]: its row and squared norm, its f32 screen column and the base
/// rows' f32 squared norms (and the largest, in f64), and the bound's `(err, tiny)`.
struct ScreenedQuery<'a> {
    query: &'a [f64],
    qn: f64,
    col: &'a [f32],
    norm: &'a [f32],
    max_norm: f64,
    bound: (f64, f64),
}

/// `(value, row)` pairs.
type Ranked = Vec<(f64, usize)>;

/// Inserts `(v, j)` into `top`, sorted and at most `k` long; rows come in increasing order, so
/// among equal values the lower row stays ahead.
fn keep_smallest(top: &mut Vec<(f64, usize)>, k: usize, v: f64, j: usize) {
    if top.len() == k && v >= top[k - 1].0 {
        return;
    }
    let at = top.partition_point(|&(w, _)| w <= v);
    top.insert(at, (v, j));
    top.truncate(k);
}

#[cfg(test)]
#[path = "tests/matching.rs"]
mod tests;
