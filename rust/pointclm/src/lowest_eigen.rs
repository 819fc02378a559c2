//! The lowest eigenpairs of a symmetric matrix by block Krylov iteration with Rayleigh-Ritz
//! projection and thick restarts (a restarted block Lanczos with full re-orthogonalisation).
//!
//! Why: clustering reads only the bottom of the normalised Laplacian's spectrum (the
//! eigengap and the first eigenvectors), and the dense O(n^3) decomposition took most of the
//! pipeline's time from a few hundred kept rows on. faer's Krylov-Schur was tried and looped
//! on affinities with several almost disconnected groups: there the Krylov space becomes
//! invariant and its next direction is rounding noise. Here a direction that vanishes under
//! re-orthogonalisation is replaced by a fresh random one, so the iteration always explores,
//! and a work budget hands the rare hard case back to the dense decomposition.
//!
//! The caller says when it has seen enough of the spectrum (`enough`), given the converged
//! prefix of the lowest eigenvalues. Sequential and seeded: the same matrix gives the same
//! result whatever the thread count.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{
    self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors, SelfAdjointEvdParams,
};
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par, Spec};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// Columns added to the Krylov basis per product with the matrix: a block keeps the products
/// compute-bound (one pass over the matrix serves all its columns) and finds eigenvalues of
/// multiplicity up to its width.
pub const BLOCK: usize = 16;

/// An eigenvector has converged when its Ritz residual `||M y - theta y||` is below this
/// times the matrix's norm bound. Its error is about the residual over its gap to the rest of
/// the spectrum, and the clustering's k-means places rows on the unit sphere of the
/// embedding: two or three digits suffice. The products run in f32 (rounding near
/// 1e-7 * sqrt(n) of the norm), far below.
pub const VECTOR_TOL: f64 = 1e-3;

/// The first `k` Ritz vectors have converged as a subspace when the sine of its largest
/// angle to the invariant subspace of the `k` lowest eigenvalues is below this, bounded by
/// Davis and Kahan's sin-theta theorem: the Frobenius norm of the `k` residuals over the gap
/// between their Ritz values and the rest of the spectrum. Spectral clustering reads only
/// that subspace (k-means on the row-normalised embedding is the same in any orthonormal
/// basis of it) and places rows on the unit sphere, where the groups lie a right angle apart:
/// a hundredth of a radian moves nothing, while vectors of nearly equal eigenvalues (groups
/// almost disconnected) take many more products to converge one by one.
pub const SUBSPACE_TOL: f64 = 5e-2;

/// An eigenvalue has converged when its Ritz residual is below this times the norm bound: a
/// true eigenvalue lies within the residual of the Ritz value (and within its square over the
/// gap to the rest), while the eigengap compares gaps of 1e-2 and more.
pub const VALUE_TOL: f64 = 1e-2;

/// The lowest converged eigenpairs.
#[derive(Debug, Clone)]
pub struct Lowest {
    /// The Ritz values, ascending: the lowest eigenvalues to [`VALUE_TOL`] for the first
    /// `converged`, upper bounds of the eigenvalues of their rank after that.
    pub values: Vec<f64>,
    /// How many leading `values` have converged.
    pub converged: usize,
    /// The count the caller's `enough` asked for.
    pub needed: usize,
    /// The eigenvectors of the first `needed` values as columns (`n x needed`), converged to
    /// [`VECTOR_TOL`].
    pub vectors: Mat<f64>,
}

/// What one Rayleigh-Ritz projection says about the lowest eigenvalues, for `enough` to judge.
#[derive(Debug, Clone, Copy)]
pub struct Estimates<'a> {
    /// The Ritz values, ascending. Each is at least the eigenvalue of its rank (Courant-Fischer:
    /// the `i`-th lowest Ritz value of any subspace bounds the `i`-th lowest eigenvalue from
    /// above), converged or not.
    pub values: &'a [f64],
    /// The residual norms `||M y - theta y||` of the first Ritz pairs (fewer than `values`):
    /// an eigenvalue lies within each of its Ritz value.
    pub residuals: &'a [f64],
    /// How many leading values have converged to [`VALUE_TOL`].
    pub converged: usize,
}

impl Estimates<'_> {
    /// The converged prefix of the values.
    pub fn converged_values(&self) -> &[f64] {
        &self.values[..self.converged]
    }

    /// A lower estimate of eigenvalue `i` (0-based): its Ritz value less the residual where
    /// that was measured. Like the converged prefix, it assumes that no eigenvalue below has
    /// been missed by the subspace.
    pub fn lower(&self, i: usize) -> Option<f64> {
        self.residuals.get(i).map(|r| self.values[i] - r)
    }
}

/// The lowest eigenpairs of the symmetric matrix `m`, as many as `enough` asks for: it is
/// called after each Rayleigh-Ritz projection with its [`Estimates`] and returns how many
/// eigenvectors it needs once these settle its question (`None`: look further). The Ritz
/// values after the converged prefix bound the eigenvalues of their rank from above, so a
/// caller can rule out what lies beyond without waiting for the dense rest of the spectrum.
/// Returns `None` when the work would exceed `max_basis` basis vectors (at most the matrix's
/// order): the caller then decomposes densely.
///
/// The vectors, one column per needed pair, have converged to [`VECTOR_TOL`].
/// `m` must be symmetric and finite (the caller checks). `seed` draws the starting block.
pub fn lowest_eigenpairs(
    m: MatRef<'_, f64>,
    max_basis: usize,
    seed: u64,
    enough: impl Fn(&Estimates<'_>) -> Option<usize>,
) -> Option<Lowest> {
    let n = m.nrows();
    let max_basis = max_basis.min(n);
    if n == 0 || max_basis < 2 * BLOCK {
        return None;
    }
    let single = Mat::<f32>::from_fn(n, n, |i, j| m[(i, j)] as f32);
    let norm = norm_bound(m);
    let mut rng = crate::seeds::stream(seed, crate::seeds::STAGE_EIGEN, n as u64);
    let mut basis = Basis::new(n, max_basis);
    let mut next = random_block(n, BLOCK, &mut rng);
    // Ritz pairs wanted before a restart; doubled whenever they have all converged but
    // `enough` still asks for more.
    let mut wanted = 2 * BLOCK;
    // Each product adds BLOCK columns; a thick restart keeps at most `wanted + BLOCK`. Every
    // round either grows the converged prefix or spends a bounded number of products.
    let max_products = 8 * max_basis.div_ceil(BLOCK) + 16;
    for _ in 0..max_products {
        let added = basis.extend(&single, next, &mut rng);
        if added == 0 {
            return None;
        }
        // Rayleigh-Ritz once the basis holds the wanted pairs and a block beyond them.
        if basis.used < (wanted + BLOCK).min(n) {
            next = basis.last_products(added);
            continue;
        }
        let ritz = basis.ritz(wanted, norm)?;
        if let Some(found) = ritz.enough_found(&basis, &enough) {
            return Some(found);
        }
        if ritz.prefix >= wanted {
            wanted *= 2;
            if wanted + 2 * BLOCK > max_basis {
                return None;
            }
        }
        if basis.used + BLOCK > max_basis {
            // Thick restart on the lowest Ritz vectors; the residuals of the unconverged ones
            // continue the Krylov sequence (they are orthogonal to the kept vectors).
            let keep = (wanted + BLOCK).min(basis.used - BLOCK);
            let from = ritz.vectors_done.min(ritz.prefix);
            next = basis.restart(&ritz.theta, ritz.y.as_ref(), keep, from);
        } else {
            next = basis.last_products(added);
        }
    }
    None
}

/// The largest absolute column sum of `m` (the 1-norm, equal to the infinity norm of a
/// symmetric matrix): it bounds the spectral norm, so the tolerances scale with the matrix.
fn norm_bound(m: MatRef<'_, f64>) -> f64 {
    (0..m.nrows())
        .map(|j| m.col(j).iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE)
}

/// One Rayleigh-Ritz projection: the Ritz values `theta` (ascending) and the vectors `y`
/// in the basis, the residuals of the lowest ones, and how many of the lowest have converged
/// as values (`prefix`, [`VALUE_TOL`]) and as vectors (`vectors_done`, [`VECTOR_TOL`]).
struct Ritz {
    theta: Vec<f64>,
    y: Mat<f64>,
    residuals: Vec<f64>,
    prefix: usize,
    vectors_done: usize,
}

impl Ritz {
    /// Whether the first `k` Ritz vectors span the lowest invariant subspace to
    /// [`SUBSPACE_TOL`] (Davis-Kahan, with the gap's lower end at Ritz value `k` less its
    /// residual).
    fn span_done(&self, k: usize) -> bool {
        let (Some(&next), Some(&r_next)) = (self.theta.get(k), self.residuals.get(k)) else {
            return false;
        };
        let gap = next - r_next - self.theta[k.saturating_sub(1)];
        let spread = self.residuals[..k]
            .iter()
            .map(|r| r * r)
            .sum::<f64>()
            .sqrt();
        k >= 1 && gap > 0.0 && spread <= SUBSPACE_TOL * gap
    }

    /// The pairs `enough` asks for (a full spectrum is always enough), when no more vectors
    /// than have converged.
    fn enough_found(
        &self,
        basis: &Basis,
        enough: impl Fn(&Estimates<'_>) -> Option<usize>,
    ) -> Option<Lowest> {
        let needed = if self.prefix == basis.n {
            Some(self.prefix)
        } else {
            enough(&Estimates {
                values: &self.theta,
                residuals: &self.residuals,
                converged: self.prefix,
            })
        };
        let needed = needed
            .filter(|&k| self.prefix >= 1 && (k <= self.vectors_done || self.span_done(k)))?;
        Some(Lowest {
            values: self.theta.clone(),
            converged: self.prefix,
            needed,
            vectors: basis.combine(self.y.as_ref(), needed),
        })
    }
}

/// The orthonormal Krylov basis `Q`, its products `W = M Q` and the projection `Q^T M Q`,
/// column-major, with room for `cap` columns.
struct Basis {
    n: usize,
    cap: usize,
    used: usize,
    q: Vec<f64>,
    w: Vec<f64>,
    /// `Q^T W`, `cap x cap`, column-major; its leading `used x used` block is current.
    t: Vec<f64>,
}

impl Basis {
    fn new(n: usize, cap: usize) -> Self {
        Basis {
            n,
            cap,
            used: 0,
            q: vec![0.0; n * cap],
            w: vec![0.0; n * cap],
            t: vec![0.0; cap * cap],
        }
    }

    /// Orthonormalises `block` (column-major, `n` rows) against the basis and appends it,
    /// with its products and projection; returns the number of columns added.
    fn extend(&mut self, single: &Mat<f32>, block: Vec<f64>, rng: &mut ChaCha8Rng) -> usize {
        let start = self.used;
        let added = self.append_orthonormal(block, rng);
        if added == 0 {
            return 0;
        }
        self.multiply_new(single, start, added);
        self.project_new(start, start + added);
        self.used = start + added;
        added
    }

    /// Appends the columns of `block` that are new against the basis, orthonormalised, after
    /// column `used` (without counting them as used yet), while there is room; returns how
    /// many.
    ///
    /// The whole block is projected off the basis at once (block classical Gram-Schmidt,
    /// twice: two matrix products per pass), then each column off the columns appended
    /// before it. One product per column, as before, cost more in call overhead than in
    /// arithmetic at the sizes clustering sees.
    fn append_orthonormal(&mut self, mut block: Vec<f64>, rng: &mut ChaCha8Rng) -> usize {
        let n = self.n;
        let start = self.used;
        let width = (block.len() / n).min(self.cap - start);
        block.truncate(width * n);
        let before: Vec<f64> = block.chunks_exact(n).map(norm).collect();
        if start > 0 && width > 0 {
            let q = MatRef::from_column_major_slice(&self.q[..n * start], n, start);
            let mut p = Mat::<f64>::zeros(start, width);
            for _ in 0..2 {
                let b = MatRef::from_column_major_slice(&block, n, width);
                matmul(p.as_mut(), Accum::Replace, q.transpose(), b, 1.0, Par::Seq);
                let b = MatMut::from_column_major_slice_mut(&mut block, n, width);
                matmul(b, Accum::Add, q, p.as_ref(), -1.0, Par::Seq);
            }
        }
        let mut added = 0;
        for (c, &was) in before.iter().enumerate() {
            let mut v = block[c * n..(c + 1) * n].to_vec();
            // A direction that vanishes against the basis means the Krylov space became
            // invariant there: explore with a fresh random one instead.
            let mut ok = was.is_finite() && self.finish_column(&mut v, start, added, was);
            for _ in 0..3 {
                if ok {
                    break;
                }
                v = random_block(n, 1, rng);
                ok = self.orthonormalize(&mut v, start + added);
            }
            if !ok {
                continue;
            }
            let j = start + added;
            self.q[j * n..(j + 1) * n].copy_from_slice(&v);
            added += 1;
        }
        block.clear();
        added
    }

    /// Projects `v` (already off the first `start` columns) off the `added` columns after
    /// them, twice, and normalises it; false when less than 1e-8 of its norm `before` any
    /// projection is left.
    fn finish_column(&self, v: &mut [f64], start: usize, added: usize, before: f64) -> bool {
        if before == 0.0 {
            return false;
        }
        let n = self.n;
        for _ in 0..2 {
            for j in start..start + added {
                let qj = &self.q[j * n..(j + 1) * n];
                let p = dot(qj, v);
                v.iter_mut().zip(qj).for_each(|(x, q)| *x -= p * q);
            }
        }
        normalize_unless_vanished(v, before)
    }

    /// `W_new = M Q_new` for the `added` columns from `start`, in f32: one pass over the
    /// matrix for the whole block.
    fn multiply_new(&mut self, single: &Mat<f32>, start: usize, added: usize) {
        let n = self.n;
        let qf = Mat::<f32>::from_fn(n, added, |i, c| self.q[(start + c) * n + i] as f32);
        let mut wf = Mat::<f32>::zeros(n, added);
        matmul(
            wf.as_mut(),
            Accum::Replace,
            single.as_ref(),
            qf.as_ref(),
            1.0,
            Par::Seq,
        );
        for c in 0..added {
            let col = &mut self.w[(start + c) * n..(start + c + 1) * n];
            for (i, v) in col.iter_mut().enumerate() {
                *v = f64::from(wf[(i, c)]);
            }
        }
    }

    /// Projection columns `start..total` against the whole basis `0..total`, symmetrised
    /// within the new block and mirrored into the rows of the old one.
    fn project_new(&mut self, start: usize, total: usize) {
        let n = self.n;
        // One product `Q^T W_new` rather than a serial dot product per entry.
        let q = MatRef::from_column_major_slice(&self.q[..n * total], n, total);
        let w = MatRef::from_column_major_slice(&self.w[start * n..total * n], n, total - start);
        let mut qw = Mat::<f64>::zeros(total, total - start);
        matmul(qw.as_mut(), Accum::Replace, q.transpose(), w, 1.0, Par::Seq);
        for c in start..total {
            for r in 0..total {
                self.t[c * self.cap + r] = qw[(r, c - start)];
            }
        }
        for c in start..total {
            for r in start..total {
                let s = 0.5 * (self.t[c * self.cap + r] + self.t[r * self.cap + c]);
                self.t[c * self.cap + r] = s;
                self.t[r * self.cap + c] = s;
            }
            for r in 0..start {
                self.t[r * self.cap + c] = self.t[c * self.cap + r];
            }
        }
    }

    /// Rayleigh-Ritz on the current basis, with the residuals of the lowest
    /// `wanted + BLOCK` pairs measured against `norm`; `None` when the small decomposition
    /// fails.
    fn ritz(&self, wanted: usize, norm: f64) -> Option<Ritz> {
        let (theta, y) = small_evd(self.projected())?;
        let keep = (wanted + BLOCK).min(self.used);
        let residuals = self.residual_norms(&theta, y.as_ref(), keep);
        let prefix = residuals
            .iter()
            .take_while(|&&r| r <= VALUE_TOL * norm)
            .count();
        let vectors_done = residuals
            .iter()
            .take_while(|&&r| r <= VECTOR_TOL * norm)
            .count();
        Some(Ritz {
            theta,
            y,
            residuals,
            prefix,
            vectors_done,
        })
    }

    /// Classical Gram-Schmidt twice against the first `upto` columns, then normalisation;
    /// false when less than 1e-8 of `v` is new. Each pass is two matrix-vector products
    /// (`p = Q^T v`, `v -= Q p`): vectorised, where one dot product per column runs at the
    /// latency of a serial sum.
    fn orthonormalize(&self, v: &mut [f64], upto: usize) -> bool {
        let before = norm(v);
        if before == 0.0 || !before.is_finite() {
            return false;
        }
        let n = self.n;
        let q = MatRef::from_column_major_slice(&self.q[..n * upto], n, upto);
        let mut p = Mat::<f64>::zeros(upto, 1);
        for _ in 0..2 {
            let col = MatRef::from_column_major_slice(v, n, 1);
            matmul(
                p.as_mut(),
                Accum::Replace,
                q.transpose(),
                col,
                1.0,
                Par::Seq,
            );
            let col = MatMut::from_column_major_slice_mut(v, n, 1);
            matmul(col, Accum::Add, q, p.as_ref(), -1.0, Par::Seq);
        }
        normalize_unless_vanished(v, before)
    }

    /// The products of the last `added` basis vectors: the next Krylov block.
    fn last_products(&self, added: usize) -> Vec<f64> {
        self.w[(self.used - added) * self.n..self.used * self.n].to_vec()
    }

    /// The leading `used x used` projection.
    fn projected(&self) -> Mat<f64> {
        Mat::from_fn(self.used, self.used, |r, c| self.t[c * self.cap + r])
    }

    /// `||W y_i - theta_i Q y_i||` for the first `count` Ritz pairs.
    fn residual_norms(&self, theta: &[f64], y: MatRef<'_, f64>, count: usize) -> Vec<f64> {
        let n = self.n;
        let q = MatRef::from_column_major_slice(&self.q[..n * self.used], n, self.used);
        let w = MatRef::from_column_major_slice(&self.w[..n * self.used], n, self.used);
        let ys = y.subcols(0, count);
        let mut qy = Mat::<f64>::zeros(n, count);
        let mut wy = Mat::<f64>::zeros(n, count);
        matmul(qy.as_mut(), Accum::Replace, q, ys, 1.0, Par::Seq);
        matmul(wy.as_mut(), Accum::Replace, w, ys, 1.0, Par::Seq);
        (0..count)
            .map(|c| {
                (0..n)
                    .map(|i| {
                        let r = wy[(i, c)] - theta[c] * qy[(i, c)];
                        r * r
                    })
                    .sum::<f64>()
                    .sqrt()
            })
            .collect()
    }

    /// `Q y` for the first `count` Ritz vectors.
    fn combine(&self, y: MatRef<'_, f64>, count: usize) -> Mat<f64> {
        let n = self.n;
        let q = MatRef::from_column_major_slice(&self.q[..n * self.used], n, self.used);
        let mut out = Mat::<f64>::zeros(n, count);
        matmul(
            out.as_mut(),
            Accum::Replace,
            q,
            y.subcols(0, count),
            1.0,
            Par::Seq,
        );
        out
    }

    /// Keeps the lowest `keep` Ritz vectors as the basis (their products follow exactly:
    /// `W y`) and returns the residuals of up to a block of unconverged ones, from `from`.
    fn restart(&mut self, theta: &[f64], y: MatRef<'_, f64>, keep: usize, from: usize) -> Vec<f64> {
        let n = self.n;
        let used = self.used;
        let q = MatRef::from_column_major_slice(&self.q[..n * used], n, used);
        let w = MatRef::from_column_major_slice(&self.w[..n * used], n, used);
        let ys = y.subcols(0, keep);
        let mut qy = Mat::<f64>::zeros(n, keep);
        let mut wy = Mat::<f64>::zeros(n, keep);
        matmul(qy.as_mut(), Accum::Replace, q, ys, 1.0, Par::Seq);
        matmul(wy.as_mut(), Accum::Replace, w, ys, 1.0, Par::Seq);
        let from = from.min(keep.saturating_sub(1));
        let width = BLOCK.min(keep - from);
        let mut next = vec![0.0; n * width];
        for c in 0..width {
            let k = from + c;
            for i in 0..n {
                next[c * n + i] = wy[(i, k)] - theta[k] * qy[(i, k)];
            }
        }
        for c in 0..keep {
            for i in 0..n {
                self.q[c * n + i] = qy[(i, c)];
                self.w[c * n + i] = wy[(i, c)];
            }
        }
        self.t.iter_mut().for_each(|v| *v = 0.0);
        for (c, &th) in theta.iter().enumerate().take(keep) {
            self.t[c * self.cap + c] = th;
        }
        self.used = keep;
        next
    }
}

/// Dense eigendecomposition of the small projected matrix (ascending).
fn small_evd(t: Mat<f64>) -> Option<(Vec<f64>, Mat<f64>)> {
    let k = t.nrows();
    let par = Par::Seq;
    let params: Spec<SelfAdjointEvdParams, f64> = Default::default();
    let mut s = faer::diag::Diag::<f64>::zeros(k);
    let mut u = Mat::<f64>::zeros(k, k);
    let mut buf = MemBuffer::new(self_adjoint_evd_scratch::<f64>(
        k,
        ComputeEigenvectors::Yes,
        par,
        params,
    ));
    self_adjoint_evd(
        t.as_ref(),
        s.as_mut(),
        Some(u.as_mut()),
        par,
        MemStack::new(&mut buf),
        params,
    )
    .ok()?;
    Some(((0..k).map(|i| s[i]).collect(), u))
}

/// Normalises `v` unless less than 1e-8 of its norm `before` its projections is left (the
/// direction was already in the basis); false then.
fn normalize_unless_vanished(v: &mut [f64], before: f64) -> bool {
    let after = norm(v);
    if after <= 1e-8 * before {
        return false;
    }
    v.iter_mut().for_each(|x| *x /= after);
    true
}

fn random_block(n: usize, width: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..n * width)
        .map(|_| rng.random::<f64>() * 2.0 - 1.0)
        .collect()
}

/// Four interleaved partial sums: one serial sum runs at the latency of an addition, these
/// let the compiler use vector lanes.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for k in 0..4 {
            acc[k] += x[k] * y[k];
        }
    }
    (acc[0] + acc[2]) + (acc[1] + acc[3]) + tail
}

#[inline]
fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
#[path = "tests/lowest_eigen.rs"]
mod tests;
