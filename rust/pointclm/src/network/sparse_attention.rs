//! The beta-scaled attention computed from the consistent pairs only.
//!
//! The attention's logits are `z_ij = beta_ij * scale * q_i . k_j`, and `beta_ij` is zero for
//! every pair whose lengths disagree by more than `sigma_d`: on the synthetic scenes 99.4 %
//! of them. Such a pair has `z_ij = 0`, so its softmax weight is `exp(-m_i)` (with `m_i` the
//! row's largest logit) whatever its key, and the row's output is
//!
//! `out_i = (sum_S e^(z_ij - m_i) v_j + e^(-m_i) (V - sum_S v_j)) / (sum_S e^(z_ij - m_i) + e^(-m_i) (N - |S|))`
//!
//! with `S` the pairs of row `i` with `beta_ij > 0` and `V` the sum of all values. The same
//! function as the dense attention ([`super::layers::attention_rows`]); only the rounding
//! differs (sums in another order, in f64 here). Its cost is `|S| x C` per row instead of
//! `N x C`, and `beta` is evaluated once per scene instead of once per layer.

use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;

use super::layers::Geometry;

/// Share of consistent pairs above which the dense attention is used: its matrix products
/// run several times faster per pair than the gathers here.
pub(crate) const MAX_SPARSE_SHARE: f64 = 1.0 / 16.0;

/// Consistent pairs the sparse attention may hold in all (8 bytes each: 400 MB), whatever the
/// share: past it the dense attention, whose memory is `O(block x N)`, runs instead.
pub(crate) const MAX_SPARSE_PAIRS: usize = 50_000_000;

/// The pairs with `beta_ij > 0`, row by row, with `beta` exactly as
/// [`Geometry::scale_by_beta`] computes it.
pub(crate) struct SparseBeta {
    offsets: Vec<usize>,
    cols: Vec<u32>,
    beta: Vec<f32>,
}

impl SparseBeta {
    /// The consistent pairs of `geometry`, or `None` when they are more than `max_share` of
    /// all pairs (the forward pass uses [`MAX_SPARSE_SHARE`]) or than [`MAX_SPARSE_PAIRS`],
    /// or the rows do not fit `u32`. Rows stop being collected once the budget is exceeded.
    pub(crate) fn new(geometry: &Geometry, parallel: bool, max_share: f64) -> Option<Self> {
        let n = geometry.len();
        if u32::try_from(n).is_err() {
            return None;
        }
        let budget = ((max_share * (n as f64) * (n as f64)) as usize).min(MAX_SPARSE_PAIRS);
        let held = AtomicUsize::new(0);
        let row = |buf: &mut Vec<f32>, i: usize| -> (Vec<u32>, Vec<f32>) {
            if held.load(Ordering::Relaxed) > budget {
                return (Vec::new(), Vec::new());
            }
            buf.clear();
            buf.resize(n, 1.0);
            pulp::Arch::new().dispatch(BetaRow {
                geometry,
                i,
                row: buf,
            });
            let hits = buf.iter().enumerate().filter(|(_, &b)| b > 0.0);
            let (cols, beta): (Vec<u32>, Vec<f32>) = hits.map(|(j, &b)| (j as u32, b)).unzip();
            held.fetch_add(cols.len(), Ordering::Relaxed);
            (cols, beta)
        };
        let rows: Vec<(Vec<u32>, Vec<f32>)> = if parallel {
            (0..n)
                .into_par_iter()
                .map_init(Vec::new, |buf, i| row(buf, i))
                .collect()
        } else {
            let mut buf = Vec::new();
            (0..n).map(|i| row(&mut buf, i)).collect()
        };
        if held.into_inner() > budget {
            return None;
        }
        let nnz: usize = rows.iter().map(|(c, _)| c.len()).sum();
        let mut offsets = Vec::with_capacity(n + 1);
        let (mut cols, mut beta) = (Vec::with_capacity(nnz), Vec::with_capacity(nnz));
        offsets.push(0);
        for (c, b) in rows {
            cols.extend(c);
            beta.extend(b);
            offsets.push(cols.len());
        }
        Some(Self {
            offsets,
            cols,
            beta,
        })
    }

    /// Columns and `beta` of row `i`'s consistent pairs.
    #[inline(always)]
    fn row(&self, i: usize) -> (&[u32], &[f32]) {
        let range = self.offsets[i]..self.offsets[i + 1];
        (&self.cols[range.clone()], &self.beta[range])
    }
}

/// `beta_ij` for all `j` into a row of ones, compiled for AVX2 where the CPU has it (see
/// [`super::layers`] on why a `pulp::WithSimd` type rather than a closure).
struct BetaRow<'a> {
    geometry: &'a Geometry,
    i: usize,
    row: &'a mut [f32],
}

impl pulp::WithSimd for BetaRow<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        self.geometry.scale_by_beta(self.i, self.row);
    }
}

/// Row-major `n x width` matrices given as a slice, a column offset and a row stride (the
/// layout of the forward pass's activations, where q, k and v share rows).
#[derive(Clone, Copy)]
pub(crate) struct Strided<'a> {
    pub data: &'a [f32],
    pub offset: usize,
    pub stride: usize,
    pub width: usize,
}

impl Strided<'_> {
    #[inline(always)]
    fn row(&self, i: usize) -> &[f32] {
        let start = i * self.stride + self.offset;
        &self.data[start..start + self.width]
    }

    /// The sum of all rows, in f64 and in row order.
    pub(crate) fn column_sums(&self, n: usize) -> Vec<f64> {
        let mut sum = vec![0.0; self.width];
        for i in 0..n {
            for (s, &v) in sum.iter_mut().zip(self.row(i)) {
                *s += f64::from(v);
            }
        }
        sum
    }
}

/// `a . b` summed in eight fixed lanes: independent sums that vectorise (one running sum
/// waits on each of its additions), in an order that does not depend on the CPU.
#[inline(always)]
fn dot_lanes(a: &[f32], b: &[f32]) -> f32 {
    const LANES: usize = 8;
    let mut lanes = [0.0f32; LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..LANES {
            lanes[l] += x[l] * y[l];
        }
    }
    lanes.iter().sum::<f32>() + tail
}

/// Rows `first .. first + rows` of the attention (`out`: `rows x width`, row-major), from the
/// block's queries `q` (rows `0..rows`), all keys `k` and values `v`, the sum of all values
/// `v_total` ([`Strided::column_sums`]) and the consistent pairs.
pub(crate) fn attention_rows_sparse(
    q: Strided<'_>,
    (k, v): (Strided<'_>, Strided<'_>),
    v_total: &[f64],
    sparse: &SparseBeta,
    (first, n, scale): (usize, usize, f32),
    out: &mut [f32],
) {
    pulp::Arch::new().dispatch(SparseRows {
        q,
        kv: (k, v),
        v_total,
        sparse,
        rows: (first, n, scale),
        out,
    });
}

/// [`attention_rows_sparse`]'s arguments, so that its loops are compiled inside pulp's
/// `#[target_feature]` function (AVX2 where the CPU has it).
struct SparseRows<'a> {
    q: Strided<'a>,
    kv: (Strided<'a>, Strided<'a>),
    v_total: &'a [f64],
    sparse: &'a SparseBeta,
    rows: (usize, usize, f32),
    out: &'a mut [f32],
}

impl pulp::WithSimd for SparseRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        sparse_rows(self);
    }
}

#[inline(always)]
fn sparse_rows(args: SparseRows<'_>) {
    let SparseRows {
        q,
        kv: (k, v),
        v_total,
        sparse,
        rows: (first, n, scale),
        out,
    } = args;
    let c = v.width;
    let mut logits = Vec::new();
    let (mut weighted, mut plain) = (vec![0.0f64; c], vec![0.0f64; c]);
    for (r, out_row) in out.chunks_exact_mut(c).enumerate() {
        let (cols, beta) = sparse.row(first + r);
        let qi = q.row(r);
        // Pairs outside S have logit 0; with none (every pair consistent) the max is over S.
        let mut max = if cols.len() < n {
            0.0f32
        } else {
            f32::NEG_INFINITY
        };
        logits.clear();
        for (&j, &b) in cols.iter().zip(beta) {
            let dot = dot_lanes(qi, k.row(j as usize));
            let z = scale * dot * b;
            max = max.max(z);
            logits.push(z);
        }
        weighted.fill(0.0);
        plain.fill(0.0);
        let mut total = 0.0f64;
        for (&j, &z) in cols.iter().zip(&logits) {
            let e = f64::from(z - max).exp();
            total += e;
            for ((w, p), &x) in weighted.iter_mut().zip(&mut plain).zip(v.row(j as usize)) {
                *w += e * f64::from(x);
                *p += f64::from(x);
            }
        }
        let rest = (-f64::from(max)).exp();
        let denominator = total + rest * (n - cols.len()) as f64;
        for (((o, &w), &p), &all) in out_row.iter_mut().zip(&weighted).zip(&plain).zip(v_total) {
            *o = ((w + rest * (all - p)) / denominator) as f32;
        }
    }
}
