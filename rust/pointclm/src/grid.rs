//! Points bucketed in a uniform grid, stored cell by cell, for many fixed-radius queries:
//! the points of a ball lie in a few contiguous runs of the sorted array.
//!
//! Why beside the k-d tree (kiddo) used for nearest neighbours: the a-contrario test asks one
//! radius count per correspondence and candidate pose, and FPFH one neighbourhood per point;
//! at those sizes a tree query that descends and collects into a heap or vector costs several
//! times the arithmetic of the distances themselves.

use std::ops::{ControlFlow, Range};

/// A uniform grid over a point set; see the module documentation.
pub(crate) struct UniformGrid {
    origin: [f64; 3],
    inv_cell: f64,
    dims: [usize; 3],
    /// `start[c]..start[c + 1]` are the points of cell `c` in `points` and `index`.
    start: Vec<usize>,
    points: Vec<[f64; 3]>,
    index: Vec<u32>,
}

impl UniformGrid {
    /// At most this many cells per point: a finer grid than the cell size asked for would
    /// only add empty cells, so a sparse set with a tiny radius is given coarser cells.
    const CELLS_PER_POINT: usize = 8;

    /// Cells of at least `min_cell` (coarser where the set is sparse). At most `u32::MAX`
    /// points.
    pub(crate) fn new(points: &[[f64; 3]], min_cell: f64) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if points.is_empty() {
            (lo, hi) = ([0.0; 3], [0.0; 3]);
        }
        let (dims, inv_cell) = Self::layout(lo, hi, points.len(), min_cell);
        let cell_of = |p: &[f64; 3]| {
            let i = [0, 1, 2].map(|a| (((p[a] - lo[a]) * inv_cell) as usize).min(dims[a] - 1));
            i[0] + dims[0] * (i[1] + dims[1] * i[2])
        };
        let mut start = vec![0usize; dims[0] * dims[1] * dims[2] + 1];
        for p in points {
            start[cell_of(p) + 1] += 1;
        }
        for c in 1..start.len() {
            start[c] += start[c - 1];
        }
        let mut next = start.clone();
        let mut sorted = vec![[0.0; 3]; points.len()];
        let mut index = vec![0u32; points.len()];
        for (i, p) in points.iter().enumerate() {
            let c = cell_of(p);
            sorted[next[c]] = *p;
            index[next[c]] = i as u32;
            next[c] += 1;
        }
        Self {
            origin: lo,
            inv_cell,
            dims,
            start,
            points: sorted,
            index,
        }
    }

    /// Cells per axis and the inverse cell size for the bounding box `lo..hi` of `n` points.
    fn layout(lo: [f64; 3], hi: [f64; 3], n: usize, min_cell: f64) -> ([usize; 3], f64) {
        let limit = (Self::CELLS_PER_POINT * n).max(64) as f64;
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let mut cell = min_cell.max(f64::MIN_POSITIVE);
        loop {
            if !cell.is_finite() || extent.iter().any(|e| !e.is_finite()) {
                // Extents beyond f64 (coordinates near its limit): one cell holds everything,
                // and every query scans it; slow but exact.
                return ([1, 1, 1], 0.0);
            }
            let per_axis = extent.map(|e| (e / cell).floor() + 1.0);
            if per_axis.iter().product::<f64>() <= limit {
                return (per_axis.map(|d| d as usize), 1.0 / cell);
            }
            cell *= 1.5;
        }
    }

    /// The mean number of points in a non-empty cell.
    pub(crate) fn mean_occupancy(&self) -> f64 {
        let filled = self.start.windows(2).filter(|w| w[1] > w[0]).count();
        self.points.len() as f64 / filled.max(1) as f64
    }

    /// The points in sorted (cell) order, and their indices in the input.
    pub(crate) fn points(&self) -> (&[[f64; 3]], &[u32]) {
        (&self.points, &self.index)
    }

    /// Calls `visit` with each run of the sorted points (a range into [`Self::points`]) that
    /// holds the cells meeting the box of half-side `radius` about `q`: every point within
    /// `radius` of `q` lies in one of them.
    #[inline]
    pub(crate) fn runs(&self, q: [f64; 3], radius: f64, mut visit: impl FnMut(Range<usize>)) {
        let _ = self.try_runs(q, radius, |run| {
            visit(run);
            ControlFlow::Continue(())
        });
    }

    /// [`Self::runs`] until `visit` breaks; whether it did.
    #[inline]
    pub(crate) fn try_runs(
        &self,
        q: [f64; 3],
        radius: f64,
        mut visit: impl FnMut(Range<usize>) -> ControlFlow<()>,
    ) -> ControlFlow<()> {
        let mut span = [(0usize, 0usize); 3];
        for a in 0..3 {
            // Cell indices by truncation, which is the floor on the non-negative side kept
            // (`floor` is a library call on baseline x86-64).
            let first = (q[a] - radius - self.origin[a]) * self.inv_cell;
            let last = (q[a] + radius - self.origin[a]) * self.inv_cell;
            if last < 0.0 || first >= self.dims[a] as f64 {
                return ControlFlow::Continue(());
            }
            span[a] = (
                first.max(0.0) as usize,
                (last as usize).min(self.dims[a] - 1),
            );
        }
        for k in span[2].0..=span[2].1 {
            for j in span[1].0..=span[1].1 {
                let row = self.dims[0] * (j + self.dims[1] * k);
                visit(self.start[row + span[0].0]..self.start[row + span[0].1 + 1])?;
            }
        }
        ControlFlow::Continue(())
    }
}

/// `|p - q|^2`, summed in the order every kernel of the crate uses.
#[inline(always)]
pub(crate) fn dist_sq(p: &[f64; 3], q: &[f64; 3]) -> f64 {
    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
    d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
}
