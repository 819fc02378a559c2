//! The SCNonlocal forward pass over fixed blocks of rows.
//!
//! Everything but the attention is row-local, and the attention of a block of rows needs only
//! that block's queries and all keys and values. Each layer therefore runs in two sweeps over
//! the same fixed blocks: (A) pointcn and q/k/v for every block, then (B) attention, message
//! MLP and residual for every block. The blocks do not depend on the thread count and each is
//! computed sequentially, so the result is bit-identical however the sweeps are scheduled.
//! With per-scene normalization each sweep splits further at its BatchNorms
//! ([`super::scene_norm`]).

use std::sync::Mutex;

use faer::MatRef;
use rayon::prelude::*;

use super::layers::{attention_rows, AttentionScratch, Geometry};
use super::sparse_attention::{
    attention_rows_sparse, SparseBeta, Strided, MAX_SPARSE_PAIRS, MAX_SPARSE_SHARE,
};
use super::{scene_norm, Architecture, Block, Network, Normalization};
use crate::correspondences::{Correspondences, Features, PairNormals};
use crate::error::{checked_elements, try_filled, Error, Result};

/// Rows per block: the attention holds `BLOCK_ROWS x N` logits per thread (0.5 MB at
/// N = 1000), small enough for the L2 cache, large enough for efficient matrix products.
pub(crate) const BLOCK_ROWS: usize = 128;

/// Correspondences the dense attention takes (2^15): its time grows as `N^2` (about 30 s
/// on two cores at this size for the default network), so input whose consistent pairs are
/// too many for the sparse attention and that has more rows is refused up front with
/// [`Error::TooManyForDenseAttention`] instead of running for minutes. The sparse attention
/// (consistent pairs at most 1/16 of all pairs and at most `MAX_SPARSE_PAIRS`) has no
/// such bound.
pub const MAX_DENSE_ATTENTION_ROWS: usize = 1 << 15;

/// Per-thread buffers.
#[derive(Default)]
pub(super) struct Scratch {
    pub pointcn: Vec<f32>,
    attention: AttentionScratch,
    pub message: Vec<f32>,
    pub hidden: [Vec<f32>; 2],
    pub update: Vec<f32>,
}

/// What every sweep of one forward pass shares: the fixed blocks, the geometry, and one
/// scratch per thread.
pub(super) struct Pass<'a> {
    pub parallel: bool,
    pub block_rows: usize,
    pub width: usize,
    geometry: &'a Geometry,
    sparse: Option<&'a SparseBeta>,
    scale: f32,
    scratch: Vec<Mutex<Scratch>>,
}

impl Pass<'_> {
    /// Runs `f(k, rows_of_block_k, scratch)` over the chunks of `buf` (`chunk` values each)
    /// ([`for_blocks`]).
    pub(super) fn for_blocks(
        &self,
        buf: &mut [f32],
        chunk: usize,
        f: &(dyn Fn(usize, &mut [f32], &mut Scratch) + Sync),
    ) {
        for_blocks(self.parallel, buf, chunk, &self.scratch, f)
    }

    /// Calls `f` with what sweep (B) reads from the activations `act` (rows of `4w`:
    /// pointcn, q, k, v), including the sum of all values where the sparse attention runs.
    pub(super) fn with_all_rows<R>(&self, act: &[f32], f: impl FnOnce(&AllRows) -> R) -> R {
        let (n, w) = (act.len() / (4 * self.width), self.width);
        let v_total = self.sparse.map(|_| strided(act, 3 * w, w).column_sums(n));
        let sparse_view = self.sparse.zip(v_total.as_deref());
        f(&AllRows::new(
            act,
            w,
            self.geometry,
            self.scale,
            sparse_view,
        ))
    }
}

/// The embedding of every correspondence: the lift, then per block sweep (A) pointcn and
/// q/k/v ([`pointcn_and_qkv`]) and sweep (B) attention, message MLP and residual
/// ([`non_local`]), then rows scaled to unit length.
pub(crate) fn embed(
    net: &Network,
    c: &Correspondences,
    parallel: bool,
    block_rows: usize,
) -> Result<Features> {
    embed_with(net, c, parallel, block_rows, MAX_SPARSE_SHARE)
}

/// [`embed`], with the sparse attention used up to `max_sparse_share` of consistent pairs
/// (0: always the dense one).
pub(crate) fn embed_with(
    net: &Network,
    c: &Correspondences,
    parallel: bool,
    block_rows: usize,
    max_sparse_share: f64,
) -> Result<Features> {
    embed_limited(
        net,
        c,
        parallel,
        block_rows,
        max_sparse_share,
        MAX_DENSE_ATTENTION_ROWS,
    )
}

/// [`embed_with`], with the dense attention refused above `max_dense_rows` rows.
pub(crate) fn embed_limited(
    net: &Network,
    c: &Correspondences,
    parallel: bool,
    block_rows: usize,
    max_sparse_share: f64,
    max_dense_rows: usize,
) -> Result<Features> {
    let n = c.len();
    let arch = &net.architecture;
    let (w, channels) = (arch.width, arch.input_channels());
    let (normals, similarity) = required_inputs(c, arch)?;
    let input = network_input(c, normals, similarity)?;
    let mut geometry = Geometry::new(c, arch.sigma_d);
    if let Some(pn) = normals {
        geometry = geometry.with_normals(pn, arch.sigma_d, arch.normal_tolerance);
    }
    let sparse = SparseBeta::new(&geometry, parallel, max_sparse_share);
    if sparse.is_none() && n > max_dense_rows {
        return Err(Error::TooManyForDenseAttention {
            n,
            max: max_dense_rows,
            share_denominator: (1.0 / MAX_SPARSE_SHARE).round() as usize,
            max_pairs: MAX_SPARSE_PAIRS,
        });
    }
    let pass = Pass {
        parallel,
        block_rows,
        width: w,
        geometry: &geometry,
        sparse: sparse.as_ref(),
        scale: (w as f64).powf(-0.5) as f32,
        scratch: thread_scratch(parallel),
    };

    let (mut feat, mut act) = buffers(n, w)?;
    // per-scene normalization's message MLP activations; empty (unused) otherwise
    let mut hidden = match net.architecture.normalization {
        Normalization::Running => Vec::new(),
        Normalization::Scene => scene_norm::hidden_buffer(n, w)?,
    };
    pass.for_blocks(&mut feat, block_rows * w, &|k, out, _| {
        let x = block(&input, channels, k, block_rows);
        net.lift
            .apply(x.len() / channels, (x, channels), (out, w), false);
    });
    for layer in &net.blocks {
        crate::cancel::check()?;
        match &layer.scene {
            None => running_layer(&pass, layer, &mut feat, &mut act),
            Some(norms) => scene_norm::layer(&pass, layer, norms, &mut feat, &mut act, &mut hidden),
        }
    }
    normalised(&feat, w)
}

/// One block with folded BatchNorms: sweep (A) pointcn and q/k/v ([`pointcn_and_qkv`]),
/// then sweep (B) attention, message MLP and residual ([`non_local`]).
fn running_layer(pass: &Pass, layer: &Block, feat: &mut [f32], act: &mut [f32]) {
    let (w, block_rows) = (pass.width, pass.block_rows);
    let aw = 4 * w;
    pass.for_blocks(act, block_rows * aw, &|k, out, s| {
        pointcn_and_qkv(layer, block(feat, w, k, block_rows), w, out, s);
    });
    pass.with_all_rows(act, |all| {
        pass.for_blocks(feat, block_rows * w, &|k, out, s| {
            let first = k * block_rows;
            let rows = &act[first * aw..(first + out.len() / w) * aw];
            non_local(layer, all, first, rows, out, s);
        });
    });
}

/// `feat`, the running feature (N x w), and `act`, per row the pointcn output then q, k and
/// v (N x 4w, so that sweep (A) writes one chunk per block); a typed error where they do not
/// fit in memory.
fn buffers(n: usize, w: usize) -> Result<(Vec<f32>, Vec<f32>)> {
    let feat = try_filled(
        "network features",
        checked_elements("network features", &[n, w], 4)?,
        0.0f32,
    )?;
    let act = try_filled(
        "network activations",
        checked_elements("network activations", &[n, 4, w], 4)?,
        0.0f32,
    )?;
    Ok((feat, act))
}

/// Columns `offset..offset + w` of the activations (rows of `4w`).
fn strided(act: &[f32], offset: usize, w: usize) -> Strided<'_> {
    Strided {
        data: act,
        offset,
        stride: 4 * w,
        width: w,
    }
}

/// One scratch per thread of the pool, reused by every block that thread runs: a fresh one
/// per rayon task would allocate (and the kernel zero) the logits again in every sweep.
fn thread_scratch(parallel: bool) -> Vec<Mutex<Scratch>> {
    let threads = if parallel {
        rayon::current_num_threads()
    } else {
        1
    };
    (0..threads).map(|_| Mutex::default()).collect()
}

/// Sweep (A) of one block of rows `x` (`w` columns): `out` gets, per row, the pointcn output
/// followed by q, k and v (`4w` columns).
fn pointcn_and_qkv(layer: &Block, x: &[f32], w: usize, out: &mut [f32], s: &mut Scratch) {
    let aw = 4 * w;
    let count = x.len() / w;
    s.pointcn.resize(count * w, 0.0);
    layer
        .pointcn
        .apply(count, (x, w), (&mut s.pointcn, w), true);
    layer
        .qkv
        .apply(count, (&s.pointcn, w), (&mut out[w..], aw), false);
    for (dst, src) in out.chunks_exact_mut(aw).zip(s.pointcn.chunks_exact(w)) {
        dst[..w].copy_from_slice(src);
    }
}

/// What sweep (B) of a layer reads for every block: the keys and values of all rows, the
/// geometry of the correspondences and the attention's logit scale.
pub(super) struct AllRows<'a> {
    keys: MatRef<'a, f32>,
    values: MatRef<'a, f32>,
    geometry: &'a Geometry,
    scale: f32,
    /// The consistent pairs and what the sparse attention reads, where they are few enough.
    sparse: Option<Sparse<'a>>,
}

impl<'a> AllRows<'a> {
    /// What sweep (B) reads from the activations `act` (rows of `4w`: pointcn, q, k, v), with
    /// the consistent pairs and the sum of all values where the sparse attention runs.
    fn new(
        act: &'a [f32],
        w: usize,
        geometry: &'a Geometry,
        scale: f32,
        sparse: Option<(&'a SparseBeta, &'a [f64])>,
    ) -> Self {
        let n = act.len() / (4 * w);
        Self {
            keys: MatRef::from_row_major_slice_with_stride(&act[2 * w..], n, w, 4 * w),
            values: MatRef::from_row_major_slice_with_stride(&act[3 * w..], n, w, 4 * w),
            geometry,
            scale,
            sparse: sparse.map(|(beta, v_total)| Sparse {
                beta,
                keys: strided(act, 2 * w, w),
                values: strided(act, 3 * w, w),
                v_total,
            }),
        }
    }
}

/// The sparse attention's view of a layer ([`attention_rows_sparse`]).
struct Sparse<'a> {
    beta: &'a SparseBeta,
    keys: Strided<'a>,
    values: Strided<'a>,
    v_total: &'a [f64],
}

/// Sweep (B) of the block of rows starting at row `first`: `rows` are its sweep (A) outputs
/// (`4w` columns); `out` (`w` columns) becomes pointcn output + message MLP(attention).
fn non_local(
    layer: &Block,
    all: &AllRows,
    first: usize,
    rows: &[f32],
    out: &mut [f32],
    s: &mut Scratch,
) {
    let w = all.keys.ncols();
    let count = out.len() / w;
    attend(all, first, rows, count, s);
    let [m0, m1, m2] = &layer.message;
    let [h0, h1] = &mut s.hidden;
    h0.resize(count * m0.outputs(), 0.0);
    h1.resize(count * m1.outputs(), 0.0);
    s.update.resize(count * w, 0.0);
    m0.apply(count, (&s.message, w), (h0, m0.outputs()), true);
    m1.apply(count, (h0, m0.outputs()), (h1, m1.outputs()), true);
    m2.apply(count, (h1, m1.outputs()), (&mut s.update, w), false);
    add_residual(out, rows, &s.update, w);
}

/// `out = pointcn output + update`, row by row: the residual adds the input of the non-local
/// block. `rows` are the block's sweep (A) outputs (`4w` columns), `out` and `update` have
/// `w` columns.
pub(super) fn add_residual(out: &mut [f32], rows: &[f32], update: &[f32], w: usize) {
    for ((o, pc), u) in out
        .chunks_exact_mut(w)
        .zip(rows.chunks_exact(4 * w))
        .zip(update.chunks_exact(w))
    {
        for ((o, &p), &u) in o.iter_mut().zip(&pc[..w]).zip(u) {
            *o = p + u;
        }
    }
}

/// The attention of the `count` rows starting at row `first` into `s.message` (`count x w`):
/// `rows` are their sweep (A) outputs (`4w` columns: pointcn, q, k, v).
pub(super) fn attend(all: &AllRows, first: usize, rows: &[f32], count: usize, s: &mut Scratch) {
    let w = all.keys.ncols();
    let aw = 4 * w;
    let queries = MatRef::from_row_major_slice_with_stride(&rows[w..], count, w, aw);
    s.message.resize(count * w, 0.0);
    match &all.sparse {
        Some(sp) => {
            let q = Strided {
                data: rows,
                offset: w,
                stride: aw,
                width: w,
            };
            attention_rows_sparse(
                q,
                (sp.keys, sp.values),
                sp.v_total,
                sp.beta,
                (first, all.keys.nrows(), all.scale),
                &mut s.message,
            );
        }
        None => attention_rows(
            queries,
            all.keys,
            all.values,
            all.geometry,
            first,
            all.scale,
            &mut s.attention,
            &mut s.message,
        ),
    }
}

/// Rows of block `k` of a row-major matrix with `cols` columns.
pub(super) fn block(m: &[f32], cols: usize, k: usize, block_rows: usize) -> &[f32] {
    let start = k * block_rows * cols;
    &m[start..(start + block_rows * cols).min(m.len())]
}

/// Runs `f(k, rows_of_block_k, scratch)` over the chunks of `buf` (`chunk` values each), in
/// parallel on the current rayon pool or in order on this thread, with the scratch of the
/// running thread.
fn for_blocks(
    parallel: bool,
    buf: &mut [f32],
    chunk: usize,
    scratch: &[Mutex<Scratch>],
    f: &(dyn Fn(usize, &mut [f32], &mut Scratch) + Sync),
) {
    let run = |k: usize, x: &mut [f32]| {
        let mine = rayon::current_thread_index().unwrap_or(0) % scratch.len();
        // Uncontended: a thread runs one block at a time. A poisoned or busy lock (not
        // expected) falls back to a fresh scratch rather than failing.
        match scratch[mine].try_lock() {
            Ok(mut s) => f(k, x, &mut s),
            Err(_) => f(k, x, &mut Scratch::default()),
        }
    };
    if parallel {
        buf.par_chunks_mut(chunk)
            .enumerate()
            .for_each(|(k, x)| run(k, x));
    } else {
        for (k, x) in buf.chunks_mut(chunk).enumerate() {
            run(k, x);
        }
    }
}

/// The inputs beyond the coordinates that the architecture needs, read from `c` (`None` for
/// those it does not need, even where `c` has them); [`Error::MissingInput`] when `c` lacks
/// one.
fn required_inputs<'c>(
    c: &'c Correspondences,
    arch: &Architecture,
) -> Result<(Option<&'c PairNormals>, Option<&'c [f64]>)> {
    let normals = match (arch.inputs.normals, c.pair_normals()) {
        (false, _) => None,
        (true, Some(pn)) => Some(pn),
        (true, None) => {
            return Err(Error::MissingInput {
                input: "normals",
                hint: "give the unit normals at both ends with Correspondences::with_normals \
                       (in Python: Network.embed(..., normals=) with an (N, 6) array of source \
                       normal | target normal, or (N, 12) correspondences)",
            })
        }
    };
    let similarity = match (arch.inputs.similarity, c.similarity()) {
        (false, _) => None,
        (true, Some(v)) => Some(v),
        (true, None) => {
            return Err(Error::MissingInput {
                input: "similarity",
                hint: "give the descriptor similarity of each match with \
                       Correspondences::with_similarity (in Python: Network.embed(..., \
                       similarity=) with an (N,) array)",
            })
        }
    };
    Ok((normals, similarity))
}

/// The network's input rows in f32: the centred coordinates ([`centred_input`]), then, not
/// centred, the unit normals at both ends and the similarity where the network reads them
/// (the channel order of `pointclm.model.network.SCNonlocal`).
fn network_input(
    c: &Correspondences,
    normals: Option<&PairNormals>,
    similarity: Option<&[f64]>,
) -> Result<Vec<f32>> {
    let xyz = centred_input(c)?;
    if normals.is_none() && similarity.is_none() {
        return Ok(xyz);
    }
    let channels = 6 + 6 * usize::from(normals.is_some()) + usize::from(similarity.is_some());
    let mut x = Vec::with_capacity(c.len() * channels);
    for (i, row) in xyz.chunks_exact(6).enumerate() {
        x.extend_from_slice(row);
        if let Some(pn) = normals {
            // unit vectors: always within f32
            x.extend(
                pn.source(i)
                    .into_iter()
                    .chain(pn.target(i))
                    .map(|v| v as f32),
            );
        }
        if let Some(values) = similarity {
            let v = values[i] as f32;
            if !v.is_finite() {
                return Err(Error::NonFinite {
                    what: "similarity (beyond the f32 range of the network)",
                    row: i,
                });
            }
            x.push(v);
        }
    }
    Ok(x)
}

/// The coordinates of each correspondence minus the scene mean, in f32. Like torch, the
/// coordinates are rounded to f32 first and the mean is taken of the rounded values.
fn centred_input(c: &Correspondences) -> Result<Vec<f32>> {
    let n = c.len();
    let mut x = Vec::with_capacity(n * 6);
    for i in 0..n {
        for v in c.source(i).into_iter().chain(c.target(i)) {
            let v32 = v as f32;
            if !v32.is_finite() {
                return Err(Error::NonFinite {
                    what: "correspondences (beyond the f32 range of the network)",
                    row: i,
                });
            }
            x.push(v32);
        }
    }
    let mut mean = [0.0f64; 6];
    for row in x.chunks_exact(6) {
        for (m, &v) in mean.iter_mut().zip(row) {
            *m += f64::from(v);
        }
    }
    let mean = mean.map(|m| (m / n as f64) as f32);
    for row in x.chunks_exact_mut(6) {
        for (v, m) in row.iter_mut().zip(mean) {
            *v -= m;
        }
    }
    Ok(x)
}

/// Rows scaled to unit length as torch's `normalize` (`x / max(||x||, 1e-12)`), in f64.
fn normalised(feat: &[f32], w: usize) -> Result<Features> {
    let mut out = Vec::with_capacity(feat.len());
    for (row, x) in feat.chunks_exact(w).enumerate() {
        let norm = x
            .iter()
            .map(|&v| f64::from(v) * f64::from(v))
            .sum::<f64>()
            .sqrt();
        if !norm.is_finite() {
            // Only reachable with coordinates so large that f32 products overflow.
            return Err(Error::NonFinite {
                what: "embedding (coordinates too large for the f32 network)",
                row,
            });
        }
        let denom = norm.max(1e-12);
        out.extend(x.iter().map(|&v| f64::from(v) / denom));
    }
    Features::new(out, w)
}
