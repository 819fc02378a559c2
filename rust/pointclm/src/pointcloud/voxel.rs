//! Voxel-grid downsampling: one point (the centroid) per occupied voxel.

use std::collections::HashMap;

use super::{check_points, check_positive};
use crate::error::{Error, Result};

/// The centroid of the points in each occupied cell of a grid of `voxel_size` cubes.
///
/// The grid is anchored at the cloud's minimum corner (minus half a voxel), as in Open3D.
/// Output order is by voxel index (x, then y, then z), so it does not depend on hashing or on
/// the input order of points within a voxel.
pub fn voxel_downsample(points: &[[f64; 3]], voxel_size: f64) -> Result<Vec<[f64; 3]>> {
    check_points(points, "points to downsample", 1)?;
    check_positive("voxel_size", voxel_size)?;
    let mut lo = [f64::INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
        }
    }
    let origin = lo.map(|v| v - 0.5 * voxel_size);
    let mut cells: HashMap<[i64; 3], ([f64; 3], usize)> = HashMap::new();
    for p in points {
        let mut key = [0i64; 3];
        for k in 0..3 {
            let cell = ((p[k] - origin[k]) / voxel_size).floor();
            // A grid of more than 2^52 cells per axis cannot be indexed exactly.
            if cell.abs() > 4.5e15 {
                return Err(Error::InvalidParameter {
                    name: "voxel_size",
                    value: voxel_size.to_string(),
                    reason: "too small for the extent of the cloud",
                });
            }
            key[k] = cell as i64;
        }
        let entry = cells.entry(key).or_insert(([0.0; 3], 0));
        for (acc, v) in entry.0.iter_mut().zip(p) {
            *acc += v;
        }
        entry.1 += 1;
    }
    let mut cells: Vec<_> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|(key, _)| *key);
    Ok(cells
        .into_iter()
        .map(|(_, (sum, n))| sum.map(|v| v / n as f64))
        .collect())
}

#[cfg(test)]
#[path = "../tests/voxel.rs"]
mod tests;
