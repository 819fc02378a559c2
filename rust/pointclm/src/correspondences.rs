//! Validated input: correspondences (source point, target point) and optional features.

use crate::error::{Error, Result};

/// The smallest input a rigid pose can be estimated from.
pub const MIN_CORRESPONDENCES: usize = 3;

/// `N` putative correspondences `c_i = (x_i, y_i)`, checked finite, stored as columns so the
/// O(N^2) consistency kernels stream contiguous memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Correspondences {
    src: [Vec<f64>; 3],
    dst: [Vec<f64>; 3],
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
        Ok(Self { src, dst })
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
