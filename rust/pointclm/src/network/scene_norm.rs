//! One block of the forward pass with per-scene normalization
//! ([`Normalization::Scene`](super::Normalization::Scene)).
//!
//! A BatchNorm that normalises by the statistics of its input over all N rows cannot run
//! row by row: every row's convolution output must exist before the mean and variance do.
//! Each sweep of [`super::forward`] therefore splits at each BatchNorm: a sweep writes the
//! convolution's output for every block of rows, the per-channel statistics are reduced over
//! them, and the next sweep normalises (and applies the ReLU) before going on. The
//! convolution outputs of the message MLP live in one extra N x width buffer (its first and
//! second halves), so memory stays O(N x width).
//!
//! The statistics are exact to f64 over the f32 activations (a mean, then the centred sum of
//! squares) and reduced per fixed block of rows, the partial sums added in block order, so
//! that they, like the rest of the pass, do not depend on the number of threads.

use rayon::prelude::*;

use super::forward::{add_residual, attend, block, Pass};
use super::layers::{Normaliser, SceneNorm};
use super::Block;
use crate::error::{checked_elements, try_filled, Result};

/// The message MLP's convolution outputs (N x w: the first convolution's `w / 2` channels,
/// then the second's); a typed error where it does not fit in memory.
pub(super) fn hidden_buffer(n: usize, w: usize) -> Result<Vec<f32>> {
    let len = checked_elements("network message activations", &[n, w], 4)?;
    try_filled("network message activations", len, 0.0f32)
}

/// One [pointcn, non-local] block whose BatchNorms `norms` (pointcn's, the message MLP's
/// two) normalise per scene: `feat` (N x w) is its input and becomes its output; `act`
/// (N x 4w) and `hidden` (N x w) are working buffers.
pub(super) fn layer(
    pass: &Pass,
    layer: &Block,
    norms: &[SceneNorm; 3],
    feat: &mut [f32],
    act: &mut [f32],
    hidden: &mut [f32],
) {
    pointcn_and_qkv(pass, layer, &norms[0], feat, act);
    non_local(pass, layer, [&norms[1], &norms[2]], feat, act, hidden);
}

/// Sweep (A) split at pointcn's BatchNorm: the convolution into the first `w` columns of
/// `act`, then the BatchNorm and ReLU in place, and q, k, v from them.
fn pointcn_and_qkv(pass: &Pass, layer: &Block, norm: &SceneNorm, feat: &[f32], act: &mut [f32]) {
    let (w, rows) = (pass.width, pass.block_rows);
    let aw = 4 * w;
    pass.for_blocks(act, rows * aw, &|k, out, _| {
        let x = block(feat, w, k, rows);
        layer.pointcn.apply(x.len() / w, (x, w), (out, aw), false);
    });
    let norm = normaliser(pass, norm, act, (0, w, aw));
    pass.for_blocks(act, rows * aw, &|_, out, s| {
        let count = out.len() / aw;
        s.pointcn.resize(count * w, 0.0);
        norm.relu(count, (out, aw), (&mut s.pointcn, w));
        layer
            .qkv
            .apply(count, (&s.pointcn, w), (&mut out[w..], aw), false);
        for (dst, src) in out.chunks_exact_mut(aw).zip(s.pointcn.chunks_exact(w)) {
            dst[..w].copy_from_slice(src);
        }
    });
}

/// Sweep (B) split at the message MLP's two BatchNorms `norms`: attention and the first
/// convolution into `hidden[.., ..w/2]`; its BatchNorm, ReLU and the second convolution
/// into `hidden[.., w/2..]`; its BatchNorm, ReLU, the last convolution and the residual
/// into `feat`.
fn non_local(
    pass: &Pass,
    layer: &Block,
    norms: [&SceneNorm; 2],
    feat: &mut [f32],
    act: &[f32],
    hidden: &mut [f32],
) {
    let (w, rows) = (pass.width, pass.block_rows);
    let (aw, h) = (4 * w, w / 2);
    let [m0, m1, m2] = &layer.message;
    let sweep_rows = |k: usize, count: usize| &act[k * rows * aw..(k * rows + count) * aw];
    pass.with_all_rows(act, |all| {
        pass.for_blocks(hidden, rows * w, &|k, out, s| {
            let count = out.len() / w;
            attend(all, k * rows, sweep_rows(k, count), count, s);
            m0.apply(count, (&s.message, w), (out, w), false);
        })
    });
    let first = normaliser(pass, norms[0], hidden, (0, h, w));
    pass.for_blocks(hidden, rows * w, &|_, out, s| {
        let count = out.len() / w;
        s.hidden[0].resize(count * h, 0.0);
        first.relu(count, (out, w), (&mut s.hidden[0], h));
        m1.apply(count, (&s.hidden[0], h), (&mut out[h..], w), false);
    });
    let second = normaliser(pass, norms[1], hidden, (h, h, w));
    pass.for_blocks(feat, rows * w, &|k, out, s| {
        let count = out.len() / w;
        let x = block(hidden, w, k, rows);
        s.hidden[1].resize(count * h, 0.0);
        second.relu(count, (&x[h..], w), (&mut s.hidden[1], h));
        s.update.resize(count * w, 0.0);
        m2.apply(count, (&s.hidden[1], h), (&mut s.update, w), false);
        add_residual(out, sweep_rows(k, count), &s.update, w);
    });
}

/// `norm` with the statistics ([`channel_stats`]) of columns `offset..offset + width` of `m`
/// (rows of `stride` values).
fn normaliser(
    pass: &Pass,
    norm: &SceneNorm,
    m: &[f32],
    columns: (usize, usize, usize),
) -> Normaliser {
    let (mean, var) = channel_stats(m, columns, pass.block_rows, pass.parallel);
    norm.with_stats(&mean, &var)
}

/// The mean and biased variance, over all rows, of columns `offset..offset + width` of `m`
/// (rows of `stride` values), reduced per block of `block_rows` rows ([`block_sums`]). One
/// row has variance 0; without rows both are 0 (nothing is normalised then).
pub(super) fn channel_stats(
    m: &[f32],
    (offset, width, stride): (usize, usize, usize),
    block_rows: usize,
    parallel: bool,
) -> (Vec<f64>, Vec<f64>) {
    let n = (m.len() / stride).max(1) as f64;
    let cols = offset..offset + width;
    let sums = |add: &(dyn Fn(&[f32], &mut [f64]) + Sync)| {
        block_sums(m, (stride, width), block_rows, parallel, add)
    };
    let mut mean = sums(&|row, acc| {
        for (a, &x) in acc.iter_mut().zip(&row[cols.clone()]) {
            *a += f64::from(x);
        }
    });
    mean.iter_mut().for_each(|m| *m /= n);
    // centred: no cancellation where the mean is large against the spread
    let mut var = sums(&|row, acc| {
        for ((a, &x), mu) in acc.iter_mut().zip(&row[cols.clone()]).zip(&mean) {
            let d = f64::from(x) - mu;
            *a += d * d;
        }
    });
    var.iter_mut().for_each(|v| *v /= n);
    (mean, var)
}

/// `sum over rows of add(row)` (`width` sums) over the rows (of `stride` values) of `m`: per
/// fixed block of `block_rows` rows, in parallel on the current rayon pool if asked, then the
/// blocks' partial sums added in block order, so that the result is the same for any number
/// of threads.
fn block_sums(
    m: &[f32],
    (stride, width): (usize, usize),
    block_rows: usize,
    parallel: bool,
    add: &(dyn Fn(&[f32], &mut [f64]) + Sync),
) -> Vec<f64> {
    let one = |rows: &[f32]| {
        let mut acc = vec![0.0f64; width];
        for row in rows.chunks_exact(stride) {
            add(row, &mut acc);
        }
        acc
    };
    let chunk = block_rows * stride;
    let partial: Vec<Vec<f64>> = if parallel {
        m.par_chunks(chunk).map(one).collect()
    } else {
        m.chunks(chunk).map(one).collect()
    };
    partial.iter().fold(vec![0.0f64; width], |mut total, p| {
        total.iter_mut().zip(p).for_each(|(t, v)| *t += v);
        total
    })
}
