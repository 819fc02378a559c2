//! The network's building blocks in `f32`: 1x1 convolutions as matrix products (faer), and
//! the beta-scaled softmax attention for a block of rows.
//!
//! Activations are row-major `rows x channels` slices, so that a block of rows is one
//! contiguous chunk and blocks can be handed to threads without copies.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};

use crate::correspondences::{Correspondences, PairNormals};

/// PyTorch's default `BatchNorm1d` epsilon, which the shipped networks were trained with.
pub(crate) const BN_EPS: f64 = 1e-5;

/// The four per-channel tensors of an eval-mode BatchNorm.
pub(crate) struct BatchNorm {
    pub weight: Vec<f64>,
    pub bias: Vec<f64>,
    pub mean: Vec<f64>,
    pub var: Vec<f64>,
}

/// The affine parameters (gamma, beta) of a BatchNorm that normalises by the statistics of
/// its own input over the scene ([`Normalization::Scene`](super::Normalization::Scene)):
/// `gamma (z - mean) / sqrt(var + eps) + beta`, with [`BN_EPS`].
pub(crate) struct SceneNorm {
    pub gamma: Vec<f64>,
    pub beta: Vec<f64>,
}

impl SceneNorm {
    /// The map for one scene, from the per-channel mean and biased variance of the input.
    pub(crate) fn with_stats(&self, mean: &[f64], var: &[f64]) -> Normaliser {
        // the mean as an unevaluated f32 sum hi + lo (see `Normaliser::relu`)
        let mean_hi: Vec<f32> = mean.iter().map(|&m| m as f32).collect();
        let mean_lo = mean
            .iter()
            .zip(&mean_hi)
            .map(|(&m, &hi)| (m - f64::from(hi)) as f32)
            .collect();
        let scale = self
            .gamma
            .iter()
            .zip(var)
            .map(|(g, v)| (g / (v + BN_EPS).sqrt()) as f32)
            .collect();
        Normaliser {
            mean_hi,
            mean_lo,
            scale,
            beta: self.beta.iter().map(|&b| b as f32).collect(),
        }
    }
}

/// A [`SceneNorm`] with one scene's statistics, in f32.
pub(crate) struct Normaliser {
    mean_hi: Vec<f32>,
    mean_lo: Vec<f32>,
    scale: Vec<f32>,
    beta: Vec<f32>,
}

impl Normaliser {
    /// `y = ReLU(scale (x - mean) + beta)` for `rows` rows of `x` and `y` (row strides as
    /// given). The mean is subtracted as `(x - hi) - lo`: `x - hi` is exact near the mean
    /// and otherwise rounded relative to itself, so the centred value keeps f32 precision
    /// even where the mean is hundreds of standard deviations (a channel that varies little
    /// over the scene), unlike torch's fused `x * alpha + (beta - mean * alpha)`. All in
    /// f32 with plain indexed loops, so that it vectorises.
    pub(crate) fn relu(&self, rows: usize, (x, xs): (&[f32], usize), (y, ys): (&mut [f32], usize)) {
        let c = self.scale.len();
        let (hi, lo) = (&self.mean_hi[..c], &self.mean_lo[..c]);
        let (scale, beta) = (&self.scale[..c], &self.beta[..c]);
        for r in 0..rows {
            let (x, y) = (&x[r * xs..r * xs + c], &mut y[r * ys..r * ys + c]);
            for k in 0..c {
                y[k] = (((x[k] - hi[k]) - lo[k]) * scale[k] + beta[k]).max(0.0);
            }
        }
    }
}

/// A 1x1 convolution `y = W x + b` with the eval-mode BatchNorm that follows it, if any,
/// folded in: that BatchNorm is the per-channel affine map `gamma (z - mu) / sqrt(var + eps)
/// + beta`, so conv and BN compose into one product and one bias.
pub(crate) struct Dense {
    /// `out x in`.
    weight: Mat<f32>,
    bias: Vec<f32>,
}

impl Dense {
    /// `weight` is row-major `out x in` (a conv kernel of size 1), `bias` has `out` values.
    /// The folding is done in f64 and rounded once.
    pub(crate) fn new(weight: &[f64], bias: &[f64], bn: Option<&BatchNorm>) -> Self {
        let out = bias.len();
        let inp = weight.len() / out;
        let (scale, shift): (Vec<f64>, Vec<f64>) = match bn {
            None => (vec![1.0; out], bias.to_vec()),
            Some(bn) => (0..out)
                .map(|o| {
                    let s = bn.weight[o] / (bn.var[o] + BN_EPS).sqrt();
                    (s, (bias[o] - bn.mean[o]) * s + bn.bias[o])
                })
                .unzip(),
        };
        Self {
            weight: Mat::from_fn(out, inp, |o, i| (weight[o * inp + i] * scale[o]) as f32),
            bias: shift.iter().map(|&b| b as f32).collect(),
        }
    }

    pub(crate) fn inputs(&self) -> usize {
        self.weight.ncols()
    }

    pub(crate) fn outputs(&self) -> usize {
        self.weight.nrows()
    }

    /// `y = x W^T + b` (then ReLU if asked) for `rows` rows: `x` is `rows x in` and `y`
    /// `rows x out`, both row-major with the given row strides (so that they can be column
    /// ranges of wider matrices).
    pub(crate) fn apply(
        &self,
        rows: usize,
        (x, x_stride): (&[f32], usize),
        (y, y_stride): (&mut [f32], usize),
        relu: bool,
    ) {
        let (inp, out) = (self.inputs(), self.outputs());
        // faer 0.24's `from_row_major_slice_with_stride_mut` builds a column-major view (its
        // `MatRef` twin is right), so the row-major view is made as a transposed column-major one.
        let y_view = MatMut::from_column_major_slice_with_stride_mut(y, out, rows, y_stride);
        matmul(
            y_view.transpose_mut(),
            Accum::Replace,
            MatRef::from_row_major_slice_with_stride(x, rows, inp, x_stride),
            self.weight.as_ref().transpose(),
            1.0f32,
            Par::Seq,
        );
        for r in 0..rows {
            let row = &mut y[r * y_stride..r * y_stride + out];
            for (v, b) in row.iter_mut().zip(&self.bias) {
                *v += b;
                if relu {
                    *v = v.max(0.0);
                }
            }
        }
    }
}

/// The correspondences in `f32` as torch sees them, for `beta` inside the attention. The
/// core's f64 kernels (`consistency`) are not used here: torch computes this `beta` from the
/// float32 input, and following its rounding keeps the embeddings closer to torch's; f32 also
/// doubles the SIMD width of this N x N loop.
pub(crate) struct Geometry {
    src: [Vec<f32>; 3],
    dst: [Vec<f32>; 3],
    sigma_sq: f32,
    /// The normal term, for a network with the `normals` input.
    normals: Option<Box<NormalGeometry>>,
}

/// The unit normals at both ends in `f32` and the normal term's constants, rounded to f32
/// as torch rounds the Python floats it multiplies tensors by.
struct NormalGeometry {
    src: [Vec<f32>; 3],
    dst: [Vec<f32>; 3],
    sigma: f32,
    half_tolerance: f32,
    tolerance_sq: f32,
}

impl Geometry {
    pub(crate) fn new(c: &Correspondences, sigma_d: f64) -> Self {
        let cols = |k: usize, src: bool| -> Vec<f32> {
            (0..c.len())
                .map(|i| {
                    let p = if src { c.source(i) } else { c.target(i) };
                    p[k] as f32
                })
                .collect()
        };
        Self {
            src: [cols(0, true), cols(1, true), cols(2, true)],
            dst: [cols(0, false), cols(1, false), cols(2, false)],
            // torch divides by the Python float sigma^2, which it rounds to the tensor's dtype
            sigma_sq: (sigma_d * sigma_d) as f32,
            normals: None,
        }
    }

    /// `beta` times the normal term of the normals `pn` (one pair per row of `self`) with
    /// cosine tolerance `tolerance`: the formula of the core's `NormalRow::beta` in f32.
    pub(crate) fn with_normals(mut self, pn: &PairNormals, sigma_d: f64, tolerance: f64) -> Self {
        let cols = |side: &[Vec<f64>; 3]| -> [Vec<f32>; 3] {
            std::array::from_fn(|k| side[k].iter().map(|&x| x as f32).collect())
        };
        self.normals = Some(Box::new(NormalGeometry {
            src: cols(&pn.src),
            dst: cols(&pn.dst),
            sigma: sigma_d as f32,
            half_tolerance: (tolerance * 0.5) as f32,
            tolerance_sq: (tolerance * tolerance) as f32,
        }));
        self
    }

    pub(crate) fn len(&self) -> usize {
        self.src[0].len()
    }

    /// Multiplies `row[j]` by `beta_ij = [1 - d_ij^2 / sigma_d^2]_+`, times the normal term
    /// where there are normals, for all `j`.
    #[inline(always)]
    pub(crate) fn scale_by_beta(&self, i: usize, row: &mut [f32]) {
        // one branch per row: the plain loop stays as lean as it was without normals
        match &self.normals {
            None => self.scale_by_length_beta(i, row),
            Some(normals) => self.scale_by_normal_beta(normals, i, row),
        }
    }

    #[inline(always)]
    fn scale_by_length_beta(&self, i: usize, row: &mut [f32]) {
        let n = self.len();
        let (s, t) = (&self.src, &self.dst);
        let (sx, sy, sz) = (s[0][i], s[1][i], s[2][i]);
        let (tx, ty, tz) = (t[0][i], t[1][i], t[2][i]);
        let (s0, s1, s2) = (&s[0][..n], &s[1][..n], &s[2][..n]);
        let (t0, t1, t2) = (&t[0][..n], &t[1][..n], &t[2][..n]);
        let sigma_sq = self.sigma_sq;
        for (j, v) in row[..n].iter_mut().enumerate() {
            let (a, b, c) = (s0[j] - sx, s1[j] - sy, s2[j] - sz);
            let (d, e, f) = (t0[j] - tx, t1[j] - ty, t2[j] - tz);
            let dist = (a * a + b * b + c * c).sqrt() - (d * d + e * e + f * f).sqrt();
            *v *= (1.0 - dist * dist / sigma_sq).max(0.0);
        }
    }

    /// The length term times the normal term (see `Correspondences::with_normals`), each
    /// operation in the order `pointclm.model.network.normal_consistency` does it in torch.
    #[inline(always)]
    fn scale_by_normal_beta(&self, g: &NormalGeometry, i: usize, row: &mut [f32]) {
        let n = self.len();
        let (s, t, m, u) = (&self.src, &self.dst, &g.src, &g.dst);
        let (si, ti) = ([s[0][i], s[1][i], s[2][i]], [t[0][i], t[1][i], t[2][i]]);
        let (mi, ui) = ([m[0][i], m[1][i], m[2][i]], [u[0][i], u[1][i], u[2][i]]);
        let (s0, s1, s2) = (&s[0][..n], &s[1][..n], &s[2][..n]);
        let (t0, t1, t2) = (&t[0][..n], &t[1][..n], &t[2][..n]);
        let (m0, m1, m2) = (&m[0][..n], &m[1][..n], &m[2][..n]);
        let (u0, u1, u2) = (&u[0][..n], &u[1][..n], &u[2][..n]);
        let (sigma_sq, sigma) = (self.sigma_sq, g.sigma);
        let (half_tol, tol_sq) = (g.half_tolerance, g.tolerance_sq);
        for (j, v) in row[..n].iter_mut().enumerate() {
            let ds = [s0[j] - si[0], s1[j] - si[1], s2[j] - si[2]];
            let dt = [t0[j] - ti[0], t1[j] - ti[1], t2[j] - ti[2]];
            let (mj, uj) = ([m0[j], m1[j], m2[j]], [u0[j], u1[j], u2[j]]);
            let (ls, lt) = (dot3(ds, ds).sqrt(), dot3(dt, dt).sqrt());
            let d = ls - lt;
            let length = (1.0 - d * d / sigma_sq).max(0.0);
            // absolute values: normal signs are not trusted (see `with_normals`)
            let da = dot3(mi, mj).abs() - dot3(ui, uj).abs();
            let dp = dot3(mi, ds).abs() - dot3(ui, dt).abs();
            let dq = dot3(mj, ds).abs() - dot3(uj, dt).abs();
            let w = half_tol * (ls + lt) + sigma;
            let w_sq = w * w;
            // (i, j) and (j, i) swap dp and dq: their product first keeps beta symmetric
            let planes = (1.0 - dp * dp / w_sq).max(0.0) * (1.0 - dq * dq / w_sq).max(0.0);
            *v *= length * (1.0 - da * da / tol_sq).max(0.0) * planes;
        }
    }
}

/// `a . b` summed in index order (as torch's per-component sums).
#[inline(always)]
fn dot3(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Lanes of the reductions below: fixed, so that sums do not depend on the SIMD width.
const LANES: usize = 8;

/// Replaces `z` by `exp(z - max z)` and returns the sum (the softmax without its division).
#[inline(always)]
pub(crate) fn softmax_unnormalised(z: &mut [f32]) -> f32 {
    let mut lane_max = [f32::NEG_INFINITY; LANES];
    let mut chunks = z.chunks_exact(LANES);
    for c in &mut chunks {
        for k in 0..LANES {
            lane_max[k] = lane_max[k].max(c[k]);
        }
    }
    let max = chunks
        .remainder()
        .iter()
        .chain(&lane_max)
        .fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    let mut lane_sum = [0.0f32; LANES];
    let mut chunks = z.chunks_exact_mut(LANES);
    for c in &mut chunks {
        for k in 0..LANES {
            c[k] = exp_nonpositive(c[k] - max);
            lane_sum[k] += c[k];
        }
    }
    let mut sum = 0.0;
    for v in chunks.into_remainder() {
        *v = exp_nonpositive(*v - max);
        sum += *v;
    }
    lane_sum.iter().fold(sum, |a, &b| a + b)
}

/// `exp(x)` for `x <= 0` to about 1 ulp (Cephes' `expf`), written without branches or libm
/// calls so that it vectorises: `exp` of `f32` in std is a scalar call, and the softmax
/// takes N^2 of them per layer.
#[inline(always)]
pub(crate) fn exp_nonpositive(x: f32) -> f32 {
    // Below -87 the result is under f32's smallest normal; clamping keeps 2^n a normal
    // number, and the error (< 1.2e-38) vanishes against the row's maximum term, exp(0) = 1.
    let x = x.max(-87.0);
    // n = round(x / ln 2) by the 1.5 * 2^23 trick: adding it leaves n in the low mantissa
    // bits of `t`, so 2^n is built with integer operations only (a float -> int cast does
    // not vectorise: Rust's `as` saturates).
    const MAGIC: f32 = 12_582_912.0;
    let t = x * std::f32::consts::LOG2_E + MAGIC;
    let n = t - MAGIC;
    let two_n = f32::from_bits(t.to_bits().wrapping_sub(MAGIC.to_bits()).wrapping_add(127) << 23);
    // ln 2 split in two so that `n ln 2` is exact enough.
    let r = x - n * 0.693_359_4 - n * -2.121_944_4e-4;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let e = p * r * r + r + 1.0;
    e * two_n
}

/// Scales a block of logit rows by `beta` and replaces them by their unnormalised softmax.
///
/// A `pulp::WithSimd` type rather than a closure: its body (all `#[inline(always)]`) is then
/// compiled inside pulp's `#[target_feature]` function, for AVX2 + FMA where the CPU has them,
/// which more than doubles the speed of these loops over the SSE2 baseline. (A closure body
/// stays a separate, baseline-compiled function.)
struct BetaSoftmax<'a> {
    logits: &'a mut [f32],
    inv_sum: &'a mut [f32],
    geometry: &'a Geometry,
    first: usize,
    n: usize,
}

impl pulp::WithSimd for BetaSoftmax<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) {
        let rows = self
            .logits
            .chunks_exact_mut(self.n)
            .zip(self.inv_sum.iter_mut());
        for (r, (row, inv)) in rows.enumerate() {
            self.geometry.scale_by_beta(self.first + r, row);
            *inv = 1.0 / softmax_unnormalised(row);
        }
    }
}

/// Per-thread buffers for the attention of one block of rows.
#[derive(Default)]
pub(crate) struct AttentionScratch {
    logits: Vec<f32>,
    inv_sum: Vec<f32>,
}

/// Rows `first .. first + rows` of the non-local attention:
/// `out_i = sum_j softmax_j(beta_ij * scale * q_i . k_j) v_j`.
///
/// `q` is the block's queries (`rows x c`, row-major with row stride `stride`), `k` and `v`
/// all `n` keys and values (same layout); `out` is `rows x c`, row-major. The logits exist
/// for this block only (`rows x n`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn attention_rows(
    q: MatRef<'_, f32>,
    k: MatRef<'_, f32>,
    v: MatRef<'_, f32>,
    geometry: &Geometry,
    first: usize,
    scale: f32,
    scratch: &mut AttentionScratch,
    out: &mut [f32],
) {
    let (rows, c, n) = (q.nrows(), q.ncols(), k.nrows());
    scratch.logits.resize(rows * n, 0.0);
    scratch.inv_sum.resize(rows, 0.0);
    let logits = &mut scratch.logits[..rows * n];
    matmul(
        MatMut::from_row_major_slice_mut(logits, rows, n),
        Accum::Replace,
        q,
        k.transpose(),
        scale,
        Par::Seq,
    );
    let inv_sum = &mut scratch.inv_sum[..rows];
    pulp::Arch::new().dispatch(BetaSoftmax {
        logits,
        inv_sum,
        geometry,
        first,
        n,
    });
    let out = &mut out[..rows * c];
    matmul(
        MatMut::from_row_major_slice_mut(out, rows, c),
        Accum::Replace,
        MatRef::from_row_major_slice(logits, rows, n),
        v,
        1.0f32,
        Par::Seq,
    );
    for (row, &inv) in out.chunks_exact_mut(c).zip(inv_sum.iter()) {
        for x in row {
            *x *= inv;
        }
    }
}
