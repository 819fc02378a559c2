//! Least-squares rigid alignment (Kabsch / Umeyama without scale).

use nalgebra::{Matrix3, Matrix4, Vector3};

use crate::correspondences::Correspondences;

/// A rigid motion `p -> R p + t`; as a 4x4 matrix it is `T_target_source`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
}

impl RigidTransform {
    /// The identity motion.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// `R p + t`.
    #[inline]
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let q = self.rotation * Vector3::from(p) + self.translation;
        [q.x, q.y, q.z]
    }

    /// `||R x + t - y||^2`.
    #[inline]
    pub fn residual_sq(&self, x: [f64; 3], y: [f64; 3]) -> f64 {
        let q = self.apply(x);
        (q[0] - y[0]).powi(2) + (q[1] - y[1]).powi(2) + (q[2] - y[2]).powi(2)
    }

    /// Homogeneous 4x4 matrix, row-major.
    pub fn to_matrix(&self) -> [[f64; 4]; 4] {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&self.rotation);
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        let mut out = [[0.0; 4]; 4];
        for (r, row) in out.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = m[(r, c)];
            }
        }
        out
    }
}

/// The rotation and translation minimising `sum ||R x_i + t - y_i||^2` over `indices`, or
/// `None` when the points do not fix a rotation (fewer than 3, or all collinear).
pub fn kabsch(c: &Correspondences, indices: &[usize]) -> Option<RigidTransform> {
    if indices.len() < 3 {
        return None;
    }
    let inv_n = 1.0 / indices.len() as f64;
    let (mut cx, mut cy) = (Vector3::zeros(), Vector3::zeros());
    for &i in indices {
        cx += Vector3::from(c.source(i));
        cy += Vector3::from(c.target(i));
    }
    cx *= inv_n;
    cy *= inv_n;
    let mut h = Matrix3::zeros();
    for &i in indices {
        let x = Vector3::from(c.source(i)) - cx;
        let y = Vector3::from(c.target(i)) - cy;
        h += x * y.transpose();
    }
    rotation_from_cross_covariance(h, cx, cy)
}

/// [`kabsch`] with a weight per correspondence (`weights[k]` for `indices[k]`), minimising
/// `sum w_i ||R x_i + t - y_i||^2`; `None` also when the weights sum to zero.
pub fn kabsch_weighted(
    c: &Correspondences,
    indices: &[usize],
    weights: &[f64],
) -> Option<RigidTransform> {
    let total: f64 = weights.iter().sum();
    if indices.len() < 3 || indices.len() != weights.len() || total.is_nan() || total <= 0.0 {
        return None;
    }
    let inv = 1.0 / total;
    let (mut cx, mut cy) = (Vector3::zeros(), Vector3::zeros());
    for (&i, &w) in indices.iter().zip(weights) {
        cx += w * Vector3::from(c.source(i));
        cy += w * Vector3::from(c.target(i));
    }
    cx *= inv;
    cy *= inv;
    let mut h = Matrix3::zeros();
    for (&i, &w) in indices.iter().zip(weights) {
        let x = Vector3::from(c.source(i)) - cx;
        let y = Vector3::from(c.target(i)) - cy;
        h += w * x * y.transpose();
    }
    rotation_from_cross_covariance(h, cx, cy)
}

/// The rigid motion from the cross-covariance `h` of centred points and the two centroids.
fn rotation_from_cross_covariance(
    h: Matrix3<f64>,
    cx: Vector3<f64>,
    cy: Vector3<f64>,
) -> Option<RigidTransform> {
    // The rotation depends only on H's direction: normalising keeps the SVD clear of
    // overflow and underflow for points at extreme scales (1e80, 1e-100).
    let scale = h.amax();
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let svd = (h / scale).svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // Rank below 2: the points lie on a line (or a point) and the rotation about it is free.
    let mut s: Vec<f64> = svd.singular_values.iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    if s[1] <= 1e-9 * s[0] {
        return None;
    }
    let v = v_t.transpose();
    // Fix a reflection: flip the axis of the smallest singular value.
    let d = (v * u.transpose()).determinant().signum();
    let fix = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d));
    let rotation = v * fix * u.transpose();
    if !rotation.iter().all(|x| x.is_finite()) {
        return None;
    }
    Some(RigidTransform {
        rotation,
        translation: cy - rotation * cx,
    })
}

#[cfg(test)]
#[path = "tests/kabsch.rs"]
mod tests;
