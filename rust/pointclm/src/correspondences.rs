//! Validated input: correspondences (source point, target point), optional surface normals at
//! both ends and descriptor similarities, and optional features.

use crate::error::{Error, Result};

/// The smallest input a rigid pose can be estimated from.
pub const MIN_CORRESPONDENCES: usize = 3;

/// The normal term's default cosine tolerance (see [`Correspondences::with_normals`]): about
/// the disagreement of two PCA normals estimated over 2 voxels on noisy scans (up to ~30
/// degrees apart, |cos| moving by up to ~0.5). Not yet tuned on the validation models
/// (`benchmarks/cloud_normals.py` is the tool for it).
pub const DEFAULT_NORMAL_TOLERANCE: f64 = 0.5;

/// `N` putative correspondences `c_i = (x_i, y_i)`, checked finite, stored as columns so the
/// O(N^2) consistency kernels stream contiguous memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Correspondences {
    src: [Vec<f64>; 3],
    dst: [Vec<f64>; 3],
    normals: Option<Box<PairNormals>>,
    /// One descriptor similarity per correspondence, an input of the embedding network only.
    similarity: Option<Box<[f64]>>,
}

/// Unit surface normals at both ends of every correspondence, stored as columns like the
/// points, and the normal term's tolerance.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PairNormals {
    pub(crate) src: [Vec<f64>; 3],
    pub(crate) dst: [Vec<f64>; 3],
    /// `1 / tolerance^2`, the tolerance on differences of cosines.
    pub(crate) inv_tol_sq: f64,
    /// The tolerance itself, which also widens the plane-distance terms with the line length.
    pub(crate) tol: f64,
}

impl PairNormals {
    #[inline(always)]
    pub(crate) fn source(&self, i: usize) -> [f64; 3] {
        [self.src[0][i], self.src[1][i], self.src[2][i]]
    }

    #[inline(always)]
    pub(crate) fn target(&self, i: usize) -> [f64; 3] {
        [self.dst[0][i], self.dst[1][i], self.dst[2][i]]
    }
}

impl Correspondences {
    /// From paired source and target points (`source[i]` matches `target[i]`).
    pub fn new(source: &[[f64; 3]], target: &[[f64; 3]]) -> Result<Self> {
        if source.len() != target.len() {
            return Err(Error::LengthMismatch {
                what: "target points (one per source point)",
                expected: source.len(),
                got: target.len(),
            });
        }
        if source.len() < MIN_CORRESPONDENCES {
            return Err(Error::TooFewCorrespondences {
                got: source.len(),
                min: MIN_CORRESPONDENCES,
            });
        }
        let mut src: [Vec<f64>; 3] = Default::default();
        let mut dst: [Vec<f64>; 3] = Default::default();
        for (row, (s, t)) in source.iter().zip(target).enumerate() {
            if !s.iter().chain(t).all(|v| v.is_finite()) {
                return Err(Error::NonFinite {
                    what: "correspondences",
                    row,
                });
            }
            for k in 0..3 {
                src[k].push(s[k]);
                dst[k].push(t[k]);
            }
        }
        Ok(Self {
            src,
            dst,
            normals: None,
            similarity: None,
        })
    }

    /// Adds a unit surface normal at both ends of every correspondence (rescaled to unit
    /// length; a zero or non-finite normal is an error). Spatial consistency then also asks the
    /// pair's point pair feature to agree: a rigid motion preserves the angle between the two
    /// normals and the distance of each point from the other's tangent plane, so `beta` is
    /// multiplied by `[1 - (da / tol)^2]_+` for the cosine between the normals and by
    /// `[1 - (dh / (tol * l + sigma))^2]_+` for each plane distance `h = n . d` (`l` the
    /// pair's mean length, `sigma` the kernel's length tolerance: short lines say little about
    /// angles, so their tolerance stays the length kernel's).
    ///
    /// Normal signs are not trusted (a model's outward normals and a scan's sensor-facing ones
    /// disagree on concave or back-facing parts), so every term compares absolute values.
    /// `tolerance` is on cosines, in (0, 2]; see [`DEFAULT_NORMAL_TOLERANCE`].
    pub fn with_normals(
        mut self,
        source_normals: &[[f64; 3]],
        target_normals: &[[f64; 3]],
        tolerance: f64,
    ) -> Result<Self> {
        if !(tolerance.is_finite() && tolerance > 0.0 && tolerance <= 2.0) {
            return Err(Error::InvalidParameter {
                name: "normal_tolerance",
                value: tolerance.to_string(),
                reason: "must lie in (0, 2] (a tolerance on cosines)",
            });
        }
        let n = self.len();
        let mut cols: [[Vec<f64>; 3]; 2] = Default::default();
        for (side, (normals, what)) in [
            (source_normals, "source normals"),
            (target_normals, "target normals"),
        ]
        .into_iter()
        .enumerate()
        {
            if normals.len() != n {
                return Err(Error::LengthMismatch {
                    what: "normals (one per correspondence at each end)",
                    expected: n,
                    got: normals.len(),
                });
            }
            for (row, v) in normals.iter().enumerate() {
                let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if !(norm.is_finite() && norm > 0.0) {
                    return Err(Error::InvalidParameter {
                        name: what,
                        value: format!("row {row}: {v:?}"),
                        reason: "each normal must be a finite, non-zero vector",
                    });
                }
                for k in 0..3 {
                    cols[side][k].push(v[k] / norm);
                }
            }
        }
        let [src, dst] = cols;
        self.normals = Some(Box::new(PairNormals {
            src,
            dst,
            inv_tol_sq: 1.0 / (tolerance * tolerance),
            tol: tolerance,
        }));
        Ok(self)
    }

    /// True when [`Correspondences::with_normals`] gave normals.
    pub fn has_normals(&self) -> bool {
        self.normals.is_some()
    }

    /// Unit normals (source end, target end) of correspondence `i`, if given.
    pub fn normals(&self, i: usize) -> Option<([f64; 3], [f64; 3])> {
        self.normals.as_ref().map(|p| {
            (
                [p.src[0][i], p.src[1][i], p.src[2][i]],
                [p.dst[0][i], p.dst[1][i], p.dst[2][i]],
            )
        })
    }

    pub(crate) fn pair_normals(&self) -> Option<&PairNormals> {
        self.normals.as_deref()
    }

    /// Adds the descriptor similarity of every correspondence's match (one finite value per
    /// row; the data that trains the network defines it, in (0, 1]). Only an embedding network
    /// trained with the `similarity` input reads it; spatial consistency does not.
    ///
    /// Errors: [`Error::LengthMismatch`] when there is not one value per correspondence,
    /// [`Error::NonFinite`] for a NaN or infinite value.
    pub fn with_similarity(mut self, values: &[f64]) -> Result<Self> {
        if values.len() != self.len() {
            return Err(Error::LengthMismatch {
                what: "similarity values (one per correspondence)",
                expected: self.len(),
                got: values.len(),
            });
        }
        if let Some(row) = values.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                what: "similarity",
                row,
            });
        }
        self.similarity = Some(values.into());
        Ok(self)
    }

    /// The descriptor similarities given by [`Correspondences::with_similarity`], one per row.
    pub fn similarity(&self) -> Option<&[f64]> {
        self.similarity.as_deref()
    }

    /// From rows `(x, y, z, x', y', z')`: source point then target point.
    pub fn from_rows(rows: &[[f64; 6]]) -> Result<Self> {
        let source: Vec<[f64; 3]> = rows.iter().map(|r| [r[0], r[1], r[2]]).collect();
        let target: Vec<[f64; 3]> = rows.iter().map(|r| [r[3], r[4], r[5]]).collect();
        Self::new(&source, &target)
    }

    /// Number of correspondences.
    pub fn len(&self) -> usize {
        self.src[0].len()
    }

    /// Always false: construction rejects fewer than [`MIN_CORRESPONDENCES`].
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Source point of correspondence `i`.
    #[inline]
    pub fn source(&self, i: usize) -> [f64; 3] {
        [self.src[0][i], self.src[1][i], self.src[2][i]]
    }

    /// Target point of correspondence `i`.
    #[inline]
    pub fn target(&self, i: usize) -> [f64; 3] {
        [self.dst[0][i], self.dst[1][i], self.dst[2][i]]
    }

    pub(crate) fn source_columns(&self) -> &[Vec<f64>; 3] {
        &self.src
    }

    pub(crate) fn target_columns(&self) -> &[Vec<f64>; 3] {
        &self.dst
    }
}

/// One feature vector per correspondence (row-major `N x dim`), e.g. the learned embedding.
/// Similarity is the plain dot product, so the embedding should be L2-normalised.
#[derive(Debug, Clone, PartialEq)]
pub struct Features {
    data: Vec<f64>,
    dim: usize,
}

impl Features {
    /// `data` holds `n * dim` values, row after row.
    pub fn new(data: Vec<f64>, dim: usize) -> Result<Self> {
        if dim == 0 {
            return Err(Error::InvalidConfig {
                field: "features",
                value: "0 columns".into(),
                reason: "need at least one feature dimension",
            });
        }
        if data.len() % dim != 0 {
            return Err(Error::LengthMismatch {
                what: "feature values (a multiple of dim)",
                expected: data.len().div_ceil(dim) * dim,
                got: data.len(),
            });
        }
        if let Some(pos) = data.iter().position(|v| !v.is_finite()) {
            return Err(Error::NonFinite {
                what: "features",
                row: pos / dim,
            });
        }
        Ok(Self { data, dim })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.data.len() / self.dim
    }

    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Feature dimension.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Feature vector of row `i`.
    #[inline]
    pub fn row(&self, i: usize) -> &[f64] {
        &self.data[i * self.dim..(i + 1) * self.dim]
    }

    /// Checks that there is one feature row per correspondence.
    pub(crate) fn check_rows(&self, n: usize) -> Result<()> {
        if self.len() != n {
            return Err(Error::LengthMismatch {
                what: "feature rows (one per correspondence)",
                expected: n,
                got: self.len(),
            });
        }
        Ok(())
    }

    #[inline]
    pub(crate) fn similarity(&self, i: usize, j: usize) -> f64 {
        self.row(i)
            .iter()
            .zip(self.row(j))
            .map(|(a, b)| a * b)
            .sum()
    }
}

#[cfg(test)]
#[path = "tests/correspondences.rs"]
mod tests;
