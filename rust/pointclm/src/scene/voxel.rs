//! The voxel a scene is described at: the model's size over `voxels_per_diagonal`, no finer
//! than the scan's own sampling and noise allow.

use nalgebra::Matrix3;

use crate::error::Result;
use crate::pointcloud::{check_points, PointIndex};

use super::{median, SceneRules};

/// The model's bounding-box diagonal over `voxels_per_diagonal`, raised (with a scan) to at
/// least `min_voxel_spacings` times the scan's point spacing ([`point_spacing`]) and
/// `min_voxel_noises` times its noise ([`noise_level`], at `noise_scale_voxels` model voxels).
/// Errors: an empty model, a non-finite coordinate.
pub fn default_voxel_size(
    model: &[[f64; 3]],
    scan: Option<&[[f64; 3]]>,
    params: &SceneRules,
) -> Result<f64> {
    check_points(model, "model points", 1)?;
    let voxel = diagonal(model) / params.voxels_per_diagonal;
    let Some(scan) = scan else {
        return Ok(voxel);
    };
    let (spacing, noise) = scan_scales(scan, Some(params.noise_scale_voxels * voxel))?;
    Ok(voxel
        .max(params.min_voxel_spacings * spacing)
        .max(params.min_voxel_noises * noise))
}

/// The length of the bounding-box diagonal of `points` (0 for none).
pub fn diagonal(points: &[[f64; 3]]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt()
}

/// [`point_spacing`] and [`noise_level`] of one cloud, over one index: 0 for a spacing of
/// fewer than 2 points and a noise of fewer than 8. Errors: a non-finite coordinate.
pub fn scan_scales(points: &[[f64; 3]], scale: Option<f64>) -> Result<(f64, f64)> {
    check_points(points, "scan points", 0)?;
    if points.len() < 2 {
        return Ok((0.0, 0.0));
    }
    let index = PointIndex::new(points)?;
    let noise = if points.len() >= 8 {
        noise_level(points, &index, scale)
    } else {
        0.0
    };
    Ok((point_spacing(points, &index), noise))
}

/// The median distance from a point to its nearest other point, over at most about 5000
/// evenly strided points (the index holds them all: a sample's spacing depends on how the
/// cloud was sampled).
pub fn point_spacing(points: &[[f64; 3]], index: &PointIndex) -> f64 {
    let step = (points.len() / 5000).max(1);
    let mut d: Vec<f64> = points
        .iter()
        .step_by(step)
        .map(|p| second_nearest(index, p))
        .collect();
    median(&mut d)
}

/// Neighbours of [`noise_level`]'s smaller planes without a scale.
pub const NOISE_NEIGHBOURS: usize = 24;

/// The standard deviation of the points about their surface, at (at most) about 500 evenly
/// strided points: planes fitted to each one's nearest points (as many as a surface holds
/// within `scale` at the cloud's spacing, 8 to 48; [`NOISE_NEIGHBOURS`] without a scale) and
/// to 4 times as many; each residual variance is the noise's plus a curvature term growing
/// with the fourth power of the radius, so the two sizes separate them; the median over the
/// points. Why a scale: on a sparse cloud a fixed count spans the object, beyond what
/// curvature's fourth power describes. `points` must hold at least 8 points.
pub fn noise_level(points: &[[f64; 3]], index: &PointIndex, scale: Option<f64>) -> f64 {
    let queries: Vec<&[f64; 3]> = points.iter().step_by((points.len() / 500).max(1)).collect();
    let k1 = match scale {
        None => NOISE_NEIGHBOURS,
        Some(scale) => {
            let mut spacings: Vec<f64> = queries.iter().map(|p| second_nearest(index, p)).collect();
            let spacing = median(&mut spacings);
            let k1 = (std::f64::consts::PI * (scale / spacing.max(1e-300)).powi(2)).round();
            k1.clamp(8.0, 48.0) as usize
        }
    };
    let k2 = (4 * k1).min(points.len());
    let k1 = (k2 / 4).max(4);
    let mut v1 = Vec::new();
    let mut fits = Vec::with_capacity(queries.len());
    for q in &queries {
        let near: Vec<usize> = index.nearest_k(q, k2).into_iter().map(|(i, _)| i).collect();
        let a = plane_fit(points, &near[..k1.min(near.len())]);
        let b = plane_fit(points, &near);
        v1.push(a.0);
        fits.push((a, b));
    }
    let mut variance: Vec<f64> = fits
        .iter()
        .filter_map(|&((va, ra), (vb, rb))| {
            let span = rb * rb - ra * ra;
            (span > 0.0).then(|| (va * rb * rb - vb * ra * ra) / span)
        })
        .collect();
    if variance.is_empty() {
        return median(&mut v1).max(0.0).sqrt();
    }
    median(&mut variance).max(0.0).sqrt()
}

/// The residual variance of the plane fitted to `points[rows]` (per degree of freedom left)
/// and the rows' mean squared distance from their centroid.
fn plane_fit(points: &[[f64; 3]], rows: &[usize]) -> (f64, f64) {
    let k = rows.len() as f64;
    let mut mean = [0.0; 3];
    for &r in rows {
        for (m, v) in mean.iter_mut().zip(points[r]) {
            *m += v;
        }
    }
    let mean = mean.map(|m| m / k);
    let mut cov = Matrix3::<f64>::zeros();
    let mut radius2 = 0.0;
    for &r in rows {
        let c = nalgebra::Vector3::from(points[r]) - nalgebra::Vector3::from(mean);
        cov += c * c.transpose();
        radius2 += c.norm_squared();
    }
    let low = cov
        .symmetric_eigenvalues()
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min);
    (low / (k - 3.0), radius2 / k)
}

/// The distance from `p` to its nearest other indexed point (its second nearest, itself
/// first).
fn second_nearest(index: &PointIndex, p: &[f64; 3]) -> f64 {
    let near = index.nearest_k(p, 2);
    near.get(1).map_or(0.0, |&(_, d2)| d2.sqrt())
}
