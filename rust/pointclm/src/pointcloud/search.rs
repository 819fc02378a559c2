//! Neighbour search in 3-D with a k-d tree (kiddo), and the "hybrid" neighbourhoods that
//! normals and FPFH are computed over.

use std::num::NonZero;
use std::ops::ControlFlow;

use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use super::{check_count, check_points, check_positive};
use crate::error::Result;
use crate::grid::{dist_sq, UniformGrid};

/// A k-d tree over a point cloud, built once and queried many times; optionally a uniform
/// grid beside it for [`Self::nearest_within`] ([`Self::with_cells`]).
pub struct PointIndex {
    tree: ImmutableKdTree<f64, u64, 3, 32>,
    len: usize,
    grid: Option<UniformGrid>,
}

impl PointIndex {
    /// Builds the tree; the cloud must be non-empty and finite.
    pub fn new(points: &[[f64; 3]]) -> Result<Self> {
        check_points(points, "points to index", 1)?;
        Ok(Self {
            tree: ImmutableKdTree::new_from_slice(points),
            len: points.len(),
            grid: None,
        })
    }

    /// [`Self::new`] with a grid of cells at least `cell` wide beside the tree, which
    /// [`Self::nearest_within`] then scans instead of the tree. Why: ICP and the verification
    /// ask one bounded nearest-point query per model point and step, at radii of one to a few
    /// cells; the tree's bounded query collects its answer into a fresh vector each time, while
    /// the grid's is a few contiguous runs of the sorted points.
    pub fn with_cells(points: &[[f64; 3]], cell: f64) -> Result<Self> {
        check_positive("cell", cell)?;
        let mut index = Self::new(points)?;
        index.grid = Some(UniformGrid::new(points, cell));
        Ok(index)
    }

    /// Number of indexed points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false: construction rejects an empty cloud.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Up to `max_nn` points within `radius` of `query`, nearest first, as
    /// `(index, squared distance)`. A point of the cloud finds itself first.
    pub fn hybrid(&self, query: &[f64; 3], radius: f64, max_nn: usize) -> Vec<(usize, f64)> {
        let max_nn = NonZero::new(max_nn).unwrap_or(NonZero::<usize>::MIN);
        self.tree
            .nearest_n_within::<SquaredEuclidean>(query, radius * radius, max_nn, true)
            .into_iter()
            .map(|n| (n.item as usize, n.distance))
            .collect()
    }

    /// The nearest indexed point to `query` closer than `radius`: `(index, squared
    /// distance)`, or `None`. Faster than [`Self::nearest`] for far queries: the search
    /// stops at the radius instead of looking for the nearest point however far.
    pub fn nearest_within(&self, query: &[f64; 3], radius: f64) -> Option<(usize, f64)> {
        let r_sq = radius * radius;
        if let Some(grid) = &self.grid {
            return nearest_in_grid(grid, query, radius, r_sq, false);
        }
        self.tree
            .nearest_n_within::<SquaredEuclidean>(query, r_sq, NonZero::<usize>::MIN, true)
            .into_iter()
            .map(|n| (n.item as usize, n.distance))
            .find(|&(_, d)| d < r_sq)
    }

    /// [`Self::nearest_within`], told of an indexed point `near` (its index and squared
    /// distance to `query`), as ICP is of each model point's pair at the previous step: the
    /// same answer, found in the small box that point bounds when it lies within the radius.
    /// Why: between ICP steps a pose moves a fraction of a voxel, so the previous pair is
    /// usually within half a voxel and its box meets a few cells instead of 27.
    pub fn nearest_within_near(
        &self,
        query: &[f64; 3],
        radius: f64,
        near: Option<(usize, f64)>,
    ) -> Option<(usize, f64)> {
        match (&self.grid, near) {
            (Some(grid), Some((_, d))) if d < radius * radius => {
                // Every point at most as near as `near` lies in the box of half-side
                // sqrt(d), widened against the rounding of the root.
                let side = d.sqrt() * (1.0 + 1e-9) + f64::MIN_POSITIVE;
                nearest_in_grid(grid, query, side, d, true)
            }
            _ => self.nearest_within(query, radius),
        }
    }

    /// Whether an indexed point lies strictly within `radius` of `query`: the same answer as
    /// [`Self::nearest_within`]`.is_some()`, stopping at the first point found.
    pub fn any_within(&self, query: &[f64; 3], radius: f64) -> bool {
        let r_sq = radius * radius;
        let Some(grid) = &self.grid else {
            return self.nearest_within(query, radius).is_some();
        };
        let (points, _) = grid.points();
        grid.try_runs(*query, radius, |run| {
            if points[run].iter().any(|p| dist_sq(p, query) < r_sq) {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .is_break()
    }

    /// Every indexed point within `radius` of `query` (inclusive), in no particular order but
    /// the same for the same index and query: `(index, squared distance)`.
    pub fn within(&self, query: &[f64; 3], radius: f64) -> impl Iterator<Item = (usize, f64)> {
        self.tree
            .within_unsorted::<SquaredEuclidean>(query, radius * radius)
            .into_iter()
            .map(|n| (n.item as usize, n.distance))
    }

    /// The `k` nearest indexed points to `query`, nearest first: `(index, squared
    /// distance)` (fewer when the cloud holds fewer).
    pub fn nearest_k(&self, query: &[f64; 3], k: usize) -> Vec<(usize, f64)> {
        let k = NonZero::new(k.min(self.len)).unwrap_or(NonZero::<usize>::MIN);
        self.tree
            .nearest_n::<SquaredEuclidean>(query, k)
            .into_iter()
            .map(|n| (n.item as usize, n.distance))
            .collect()
    }

    /// The nearest indexed point to `query`: `(index, squared distance)`.
    pub fn nearest(&self, query: &[f64; 3]) -> (usize, f64) {
        let n = self.tree.nearest_one::<SquaredEuclidean>(query);
        (n.item as usize, n.distance)
    }

    /// The hybrid neighbourhood of every point of `points` (the cloud this index was built
    /// on, for normals and FPFH), computed in parallel on the current rayon pool.
    pub fn neighbourhoods(
        &self,
        points: &[[f64; 3]],
        radius: f64,
        max_nn: usize,
    ) -> Result<Neighbourhoods> {
        check_positive("radius", radius)?;
        check_count("max_nn", max_nn, 1)?;
        let grid = (points.len() <= u32::MAX as usize)
            .then(|| grid_neighbourhoods(points, radius, max_nn))
            .flatten();
        Ok(grid.unwrap_or_else(|| {
            Neighbourhoods::build(points.len(), |i, chunk, _| {
                let list = self.hybrid(&points[i], radius, max_nn);
                chunk.push(list.into_iter().map(|(j, d)| (j as u32, d)));
            })
        }))
    }
}

/// Which points have fewer than `min_neighbours` other points within `radius` (inclusive):
/// stray points (a depth sensor's flying pixels, multipath) among the points of a surface.
/// Why a count within the normals' radius: a point needs a few neighbours to fit the plane it
/// is described by, and a surface sampled at that scale gives every point a dozen, while a
/// stray point in open space has none. Each count stops once it is decided.
pub fn isolated_points(
    points: &[[f64; 3]],
    radius: f64,
    min_neighbours: usize,
) -> Result<Vec<bool>> {
    check_points(points, "points", 1)?;
    check_positive("radius", radius)?;
    let grid = UniformGrid::new(points, radius);
    let (sorted, _) = grid.points();
    let r_sq = radius * radius;
    Ok(points
        .par_iter()
        .map(|p| {
            // The point itself is among those found.
            let mut found = 0usize;
            let enough = grid.try_runs(*p, radius, |run| {
                found += sorted[run].iter().filter(|q| dist_sq(p, q) <= r_sq).count();
                if found > min_neighbours {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            });
            enough.is_continue()
        })
        .collect())
}

/// The nearest point of `grid` strictly within `radius` (squared: `r_sq`) of `query` (at
/// most `r_sq` away if `inclusive`; then every such point must lie within the box of
/// half-side `radius`), the lowest input index among equally near ones: `(index, squared
/// distance)`.
fn nearest_in_grid(
    grid: &UniformGrid,
    query: &[f64; 3],
    radius: f64,
    r_sq: f64,
    inclusive: bool,
) -> Option<(usize, f64)> {
    let (points, index) = grid.points();
    let mut best: Option<(u32, f64)> = None;
    grid.runs(*query, radius, |run| {
        for k in run {
            let d = dist_sq(&points[k], query);
            let better = best.is_none_or(|(i, b)| d < b || (d == b && index[k] < i));
            if (d < r_sq || (inclusive && d == r_sq)) && better {
                best = Some((index[k], d));
            }
        }
    });
    best.map(|(i, d)| (i as usize, d))
}

/// [`PointIndex::hybrid`] of every point of `points` within the cloud itself, from a grid of
/// cells the size of the radius (a ball meets at most 27, in nine contiguous runs): the
/// points within `radius` (inclusive, as the tree's search), the `max_nn` nearest kept,
/// nearest first, the point itself first among those at distance 0, other ties by index.
/// The same lists as the tree's wherever distances do not tie; several times faster for
/// FPFH's neighbourhoods of 50-100 points.
///
/// `None` when the cells hold so many points that a query would scan far more than `max_nn`
/// of them (a radius large against the cloud): the tree, which stops at the `max_nn` nearest,
/// is then faster.
fn grid_neighbourhoods(points: &[[f64; 3]], radius: f64, max_nn: usize) -> Option<Neighbourhoods> {
    let grid = UniformGrid::new(points, radius);
    // A query scans up to 27 cells.
    if 27.0 * grid.mean_occupancy() > 16.0 * max_nn.max(16) as f64 {
        return None;
    }
    let (sorted, index) = grid.points();
    let r_sq = radius * radius;
    Some(Neighbourhoods::build(points.len(), |i, chunk, keys| {
        let p = &points[i];
        // Nearest first, the point itself ahead of any duplicate (FPFH skips the first
        // entry as the point itself), then by index: one integer key per neighbour (squared
        // distances are non-negative, so their bits sort as the numbers do), which sorts
        // several times faster than a comparator over the three fields.
        keys.clear();
        grid.runs(*p, radius, |run| {
            for (q, &j) in sorted[run.clone()].iter().zip(&index[run]) {
                let d = dist_sq(p, q);
                if d <= r_sq {
                    let other = u128::from(j as usize != i);
                    keys.push(u128::from(d.to_bits()) << 64 | other << 32 | u128::from(j));
                }
            }
        });
        if keys.len() > max_nn {
            keys.select_nth_unstable(max_nn - 1);
            keys.truncate(max_nn);
        }
        let sorted = sort_by_distance(keys, r_sq);
        chunk.push(
            sorted
                .iter()
                .map(|&k| (k as u32, f64::from_bits((k >> 64) as u64))),
        );
    }))
}

/// Lists shorter than this are sorted by comparisons alone, and so are longer ones than
/// [`BUCKETS`] (a radius far beyond FPFH's 100 neighbours).
const BUCKET_SORT_FROM: usize = 32;
const BUCKETS: usize = 256;

/// `keys` (squared distance bits above, within `r_sq`) in increasing order: the order of
/// `sort_unstable`, as a slice of `keys` (which it extends as scratch). Why buckets: the
/// squared distances of a surface's points within a radius spread evenly over `0..r_sq` (the
/// count within `rho` grows as `rho^2`), so `n` buckets of equal width hold one or two keys
/// each, and a counting pass plus a few tiny sorts replace a comparison sort of 50-100 keys.
/// The bucket of a key is monotone in its distance, so keys only need sorting within their
/// bucket.
fn sort_by_distance(keys: &mut Vec<u128>, r_sq: f64) -> &[u128] {
    let n = keys.len();
    let scale = n as f64 / r_sq;
    if !(BUCKET_SORT_FROM..=BUCKETS).contains(&n) || !scale.is_finite() {
        keys.sort_unstable();
        return keys;
    }
    let bucket = |k: u128| ((f64::from_bits((k >> 64) as u64) * scale) as usize).min(n - 1);
    let mut ends = [0u16; BUCKETS + 1];
    for &k in keys.iter() {
        ends[bucket(k) + 1] += 1;
    }
    for b in 0..n {
        ends[b + 1] += ends[b];
    }
    keys.resize(2 * n, 0);
    let (input, out) = keys.split_at_mut(n);
    for &k in input.iter() {
        let b = bucket(k);
        out[usize::from(ends[b])] = k;
        ends[b] += 1;
    }
    // Each bucket now ends where the next begins: sort the runs.
    let mut begin = 0;
    for &end in &ends[..n] {
        let end = usize::from(end);
        if end > begin + 1 {
            out[begin..end].sort_unstable();
        }
        begin = end;
    }
    &keys[n..]
}

/// Points per chunk of [`Neighbourhoods`]: one parallel task's share. Why chunks: lists built
/// per point cost an allocation each and a serial copy into one flat array at the end, which
/// took as long as the search on two threads.
const CHUNK: usize = 256;

/// Neighbour lists of every point, stored flat (CSR) in chunks of [`CHUNK`] points: the lists
/// are reused by the two passes of FPFH instead of searching twice as Open3D does.
#[derive(Debug, Clone)]
pub struct Neighbourhoods {
    chunks: Vec<HoodChunk>,
    len: usize,
}

/// The lists of [`CHUNK`] consecutive points.
#[derive(Debug, Clone)]
struct HoodChunk {
    offsets: Vec<usize>,
    index: Vec<u32>,
    dist2: Vec<f64>,
}

impl HoodChunk {
    /// Appends the next point's list.
    fn push(&mut self, list: impl Iterator<Item = (u32, f64)>) {
        for (j, d) in list {
            self.index.push(j);
            self.dist2.push(d);
        }
        self.offsets.push(self.index.len());
    }
}

impl Neighbourhoods {
    /// The lists of points `0..n`, `fill(i, chunk, scratch)` appending point `i`'s, chunks in
    /// parallel on the current rayon pool (`scratch` is reused within a chunk).
    fn build(n: usize, fill: impl Fn(usize, &mut HoodChunk, &mut Vec<u128>) + Sync) -> Self {
        let chunks = (0..n.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut chunk = HoodChunk {
                    offsets: vec![0],
                    index: Vec::new(),
                    dist2: Vec::new(),
                };
                let mut scratch = Vec::new();
                for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                    fill(i, &mut chunk, &mut scratch);
                }
                chunk
            })
            .collect();
        Self { chunks, len: n }
    }

    /// Neighbours of point `i`, nearest first (the point itself first).
    #[inline]
    pub fn of(&self, i: usize) -> (&[u32], &[f64]) {
        let chunk = &self.chunks[i / CHUNK];
        let at = i % CHUNK;
        let (a, b) = (chunk.offsets[at], chunk.offsets[at + 1]);
        (&chunk.index[a..b], &chunk.dist2[a..b])
    }

    /// Number of points the lists belong to.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when there are no lists.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

#[cfg(test)]
#[path = "../tests/search.rs"]
mod tests;
