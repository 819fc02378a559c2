//! A learned local descriptor: what a point's neighbourhood looks like from any side.
//!
//! Each neighbour within the radius is seen from the point as its point pair feature (the
//! distance, the angles of both normals to the line between them and to each other, the
//! neighbour's height over the point's tangent plane): five numbers that no rotation
//! changes. A small MLP lifts each neighbour's five numbers, their maximum and mean over the
//! neighbourhood (and the share of the neighbours found) go through a second MLP, and the
//! result is scaled to unit length. Trained contrastively on partial views against complete
//! models (`pointclm train-descriptor`), it plays FPFH's part: the same neighbourhoods, a
//! learned summary instead of fixed histograms.

use std::fmt;
use std::path::Path;

use rayon::prelude::*;
use safetensors::SafeTensors;
use serde_json::Value;

use super::layers::Dense;
use super::weights::{read_pair, Reader};
use crate::correspondences::Features;
use crate::error::{Error, Result};
use crate::pointcloud::{check_index, check_normals, check_points, check_positive};
use crate::pointcloud::{Neighbourhoods, PointIndex};

/// Values per neighbour fed to the network (see the module documentation).
pub const PAIR_FEATURES: usize = 5;
/// The largest neighbourhood a descriptor file may ask for: beyond it the descriptor would
/// cost far more than FPFH for nothing a local descriptor can use.
const MAX_NEIGHBOURS: usize = 1024;
/// The widest layer a descriptor file may declare (the shipped one is 64).
const MAX_WIDTH: usize = 4096;

/// Points described together: their neighbours' rows form one matrix product per layer.
/// Fixed blocks of consecutive points, so that the result does not depend on the threads.
const BLOCK_POINTS: usize = 64;

/// torch's `Linear(inp, out)` named `name` (weight `out x inp`) as a core dense layer.
fn linear(r: &mut Reader<'_, '_>, name: &str, out: usize, inp: usize) -> Result<Dense> {
    let weight = r.tensor(&format!("{name}.weight"), &[out, inp])?;
    let bias = r.tensor(&format!("{name}.bias"), &[out])?;
    Ok(Dense::new(&weight, &bias, None))
}

/// A trained descriptor network, ready to describe clouds: `Send + Sync`.
pub struct LearnedDescriptor {
    /// Neighbours per point (the point itself excluded).
    neighbours: usize,
    /// The nearest neighbours within the radius looked at (at least `neighbours`); when
    /// more are found than `neighbours`, that many are taken evenly spaced in distance order,
    /// so that they cover the whole radius rather than its centre.
    candidates: usize,
    /// The neighbourhood radius in voxels of the cloud described.
    radius_voxels: f64,
    lift: [Dense; 2],
    head: [Dense; 2],
    name: String,
}

impl LearnedDescriptor {
    /// Loads `path` (the `.safetensors` file) and the `.json` beside it; errors as
    /// [`Network::from_file`](super::Network::from_file).
    pub fn from_file(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (bytes, meta) = read_pair(path)?;
        Self::from_bytes(&bytes, &meta, &path.display().to_string())
    }

    /// From the bytes of a safetensors file and the text of its JSON metadata (`name` is
    /// used in error messages only). The metadata holds `"descriptor": {"neighbours": K,
    /// "candidates": M, "radius_voxels": R, "widths": [h1, h2, h3, out]}` (`candidates`
    /// defaults to `neighbours`).
    pub fn from_bytes(safetensors: &[u8], metadata: &str, name: &str) -> Result<Self> {
        let malformed = |reason: String| Error::WeightsMalformed {
            path: name.to_string(),
            reason,
        };
        let (neighbours, candidates, radius_voxels, widths) = shape(metadata).map_err(malformed)?;
        let st = SafeTensors::deserialize(safetensors)
            .map_err(|e| malformed(format!("not a safetensors file: {e}")))?;
        let mut r = Reader {
            st: &st,
            name,
            used: Default::default(),
            scene: false,
        };
        let [h1, h2, h3, out] = widths;
        let lift = [
            linear(&mut r, "point.0", h1, PAIR_FEATURES)?,
            linear(&mut r, "point.2", h2, h1)?,
        ];
        let head = [
            linear(&mut r, "head.0", h3, 2 * h2 + 1)?,
            linear(&mut r, "head.2", out, h3)?,
        ];
        if let Some(t) = st.names().into_iter().find(|t| !r.used.contains(*t)) {
            return Err(malformed(format!(
                "unexpected tensor {t} for a learned descriptor"
            )));
        }
        Ok(Self {
            neighbours,
            candidates,
            radius_voxels,
            lift,
            head,
            name: name.to_string(),
        })
    }

    /// Length of each descriptor.
    pub fn dim(&self) -> usize {
        self.head[1].outputs()
    }

    /// The neighbourhood radius, in voxels of the cloud described.
    pub fn radius_voxels(&self) -> f64 {
        self.radius_voxels
    }

    /// Neighbours per point the network was trained with.
    pub fn neighbours(&self) -> usize {
        self.neighbours
    }

    /// Unit-length descriptors of `points` (indexed by `index`) with their unit `normals`,
    /// over neighbourhoods of `radius_voxels() * voxel`.
    ///
    /// Points run in parallel on the current rayon pool; each descriptor is computed alone,
    /// so the result is the same whatever the number of threads. A point without neighbours
    /// gets the descriptor of an empty neighbourhood (the same for every such point).
    pub fn describe(
        &self,
        points: &[[f64; 3]],
        normals: &[[f64; 3]],
        index: &PointIndex,
        voxel: f64,
    ) -> Result<Features> {
        check_points(points, "points to describe", 1)?;
        check_normals(normals, points.len(), "normals", "normals (one per point)")?;
        check_index(index, points)?;
        check_positive("voxel", voxel)?;
        let radius = self.radius_voxels * voxel;
        let hoods = index.neighbourhoods(points, radius, self.candidates + 1)?;
        let blocks: Vec<Vec<f32>> = (0..points.len().div_ceil(BLOCK_POINTS))
            .into_par_iter()
            .map(|b| {
                let range = b * BLOCK_POINTS..((b + 1) * BLOCK_POINTS).min(points.len());
                self.block(range, points, normals, &hoods, radius)
            })
            .collect();
        let data = blocks.iter().flatten().map(|&v| f64::from(v)).collect();
        Features::new(data, self.dim())
    }

    /// The neighbours of point `i` the network reads: among the `candidates` nearest within
    /// the radius (itself excluded), `neighbours` evenly spaced in distance order, by the same
    /// integer rule as training.
    fn chosen<'h>(&self, i: usize, hoods: &'h Neighbourhoods) -> impl Iterator<Item = usize> + 'h {
        let (nbrs, _) = hoods.of(i);
        let skip = nbrs.iter().position(|&j| j as usize == i);
        let found = (nbrs.len() - usize::from(skip.is_some())).min(self.candidates);
        let k = self.neighbours;
        let at = move |t: usize| {
            let t = if found > k {
                (2 * t + 1) * found / (2 * k)
            } else {
                t
            };
            // the index in `nbrs` of the t-th neighbour other than the point itself
            let j = match skip {
                Some(s) if t >= s => t + 1,
                _ => t,
            };
            nbrs[j] as usize
        };
        (0..found.min(k)).map(at)
    }

    /// Descriptors of the points in `range`, row after row.
    fn block(
        &self,
        range: std::ops::Range<usize>,
        points: &[[f64; 3]],
        normals: &[[f64; 3]],
        hoods: &Neighbourhoods,
        radius: f64,
    ) -> Vec<f32> {
        let (h1, h2) = (self.lift[0].outputs(), self.lift[1].outputs());
        let mut feats: Vec<f32> = Vec::new();
        let mut counts = Vec::with_capacity(range.len());
        for i in range.clone() {
            let before = feats.len();
            for j in self.chosen(i, hoods) {
                let f = pair_feature(points[i], normals[i], points[j], normals[j], radius);
                feats.extend_from_slice(&f);
            }
            counts.push((feats.len() - before) / PAIR_FEATURES);
        }
        let rows = feats.len() / PAIR_FEATURES;
        let mut hidden = vec![0.0f32; rows * h1];
        self.lift[0].apply(rows, (&feats, PAIR_FEATURES), (&mut hidden, h1), true);
        let mut lifted = vec![0.0f32; rows * h2];
        self.lift[1].apply(rows, (&hidden, h1), (&mut lifted, h2), true);
        let width = 2 * h2 + 1;
        let mut pooled = vec![0.0f32; counts.len() * width];
        let mut start = 0;
        for (p, &count) in pooled.chunks_exact_mut(width).zip(&counts) {
            let (max, rest) = p.split_at_mut(h2);
            for row in lifted[start * h2..(start + count) * h2].chunks_exact(h2) {
                for ((m, s), &v) in max.iter_mut().zip(rest.iter_mut()).zip(row) {
                    *m = m.max(v);
                    *s += v;
                }
            }
            let c = count.max(1) as f32;
            rest[..h2].iter_mut().for_each(|s| *s /= c);
            rest[h2] = count as f32 / self.neighbours as f32;
            start += count;
        }
        let n = counts.len();
        let h3 = self.head[0].outputs();
        let mut head = vec![0.0f32; n * h3];
        self.head[0].apply(n, (&pooled, width), (&mut head, h3), true);
        let dim = self.dim();
        let mut z = vec![0.0f32; n * dim];
        self.head[1].apply(n, (&head, h3), (&mut z, dim), false);
        for row in z.chunks_exact_mut(dim) {
            let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
            row.iter_mut().for_each(|v| *v /= norm);
        }
        z
    }
}

/// The point pair feature of neighbour `q` (normal `m`) seen from `p` (normal `n`), lengths in
/// units of `radius`: distance, cos(n, d), cos(m, d), cos(n, m), height of `q` over `p`'s
/// tangent plane.
fn pair_feature(p: [f64; 3], n: [f64; 3], q: [f64; 3], m: [f64; 3], radius: f64) -> [f32; 5] {
    let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let len = dot(d, d).sqrt();
    let u = d.map(|v| v / len.max(1e-12));
    [
        (len / radius) as f32,
        dot(u, n) as f32,
        dot(u, m) as f32,
        dot(n, m) as f32,
        (dot(d, n) / radius) as f32,
    ]
}

/// `(neighbours, candidates, radius_voxels, [h1, h2, h3, out])` from the metadata JSON.
fn shape(meta: &str) -> std::result::Result<(usize, usize, f64, [usize; 4]), String> {
    let meta: Value =
        serde_json::from_str(meta).map_err(|e| format!("metadata is not valid JSON: {e}"))?;
    let d = meta
        .get("descriptor")
        .ok_or("metadata has no \"descriptor\"")?;
    let count = |key: &str, max: usize| -> std::result::Result<usize, String> {
        match d.get(key).and_then(Value::as_u64) {
            Some(v) if (1..=max as u64).contains(&v) => Ok(v as usize),
            _ => Err(format!("descriptor.{key} must be an integer in 1..={max}")),
        }
    };
    let neighbours = count("neighbours", MAX_NEIGHBOURS)?;
    let candidates = match d.get("candidates") {
        None => neighbours,
        Some(_) => count("candidates", MAX_NEIGHBOURS)?,
    };
    if candidates < neighbours {
        return Err("descriptor.candidates must be at least descriptor.neighbours".into());
    }
    let radius = match d.get("radius_voxels").and_then(Value::as_f64) {
        Some(r) if r.is_finite() && r > 0.0 && r <= 100.0 => r,
        _ => return Err("descriptor.radius_voxels must be a number in (0, 100]".into()),
    };
    let widths = d
        .get("widths")
        .and_then(Value::as_array)
        .filter(|w| w.len() == 4)
        .ok_or("descriptor.widths must list 4 layer widths")?;
    let mut out = [0usize; 4];
    for (o, w) in out.iter_mut().zip(widths) {
        *o = match w.as_u64() {
            Some(v) if (1..=MAX_WIDTH as u64).contains(&v) => v as usize,
            _ => {
                return Err(format!(
                    "descriptor.widths must be integers in 1..={MAX_WIDTH}"
                ))
            }
        };
    }
    Ok((neighbours, candidates, radius, out))
}

impl fmt::Debug for LearnedDescriptor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LearnedDescriptor")
            .field("name", &self.name)
            .field("neighbours", &self.neighbours)
            .field("radius_voxels", &self.radius_voxels)
            .field("dim", &self.dim())
            .finish()
    }
}

#[cfg(test)]
#[path = "../tests/learned_descriptor.rs"]
mod tests;
