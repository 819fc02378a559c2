//! Seeded k-means++ with restarts, for the spectral embedding.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

const MAX_ITERATIONS: usize = 300;

/// Clusters `n` rows of `dim` values (row-major `data`) into `k` groups, keeping the best of
/// `restarts` runs by inertia. Labels are renumbered by first appearance, so equal partitions
/// give equal labels.
pub fn kmeans(
    data: &[f64],
    dim: usize,
    k: usize,
    restarts: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<usize> {
    let n = data.len().checked_div(dim).unwrap_or(0);
    if n == 0 || k == 0 {
        return vec![0; n];
    }
    let k = k.min(n);
    // The seedings draw from one stream, one restart after another as before (how much each
    // draws depends on the data); the restarts' iterations, which draw nothing and are most
    // of the work, then run in parallel. The same labels whatever the number of threads.
    let seeds: Vec<Vec<f64>> = (0..restarts.max(1))
        .map(|_| plus_plus_init(data, dim, n, k, rng))
        .collect();
    let runs: Vec<(f64, Vec<usize>)> = seeds
        .into_par_iter()
        .map(|centers| lloyd(data, dim, n, k, centers))
        .collect();
    let mut best: Option<(f64, Vec<usize>)> = None;
    for (inertia, labels) in runs {
        if best.as_ref().is_none_or(|(b, _)| inertia < *b) {
            best = Some((inertia, labels));
        }
    }
    relabel_by_first_appearance(&best.map(|b| b.1).unwrap_or_default())
}

pub(crate) fn relabel_by_first_appearance(labels: &[usize]) -> Vec<usize> {
    let mut map = std::collections::HashMap::new();
    labels
        .iter()
        .map(|&l| {
            let next = map.len();
            *map.entry(l).or_insert(next)
        })
        .collect()
}

#[inline]
fn dist_sq(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

fn plus_plus_init(data: &[f64], dim: usize, n: usize, k: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centers = Vec::with_capacity(k * dim);
    centers.extend_from_slice(row(rng.random_range(0..n)));
    // `f64::min` with NaN is the other value: the first update sets every distance.
    let mut d2 = vec![f64::NAN; n];
    nearer(&mut d2, data, dim, &centers[..dim]);
    for _ in 1..k {
        let total: f64 = d2.iter().sum();
        let pick = if total > 0.0 {
            let mut target = rng.random::<f64>() * total;
            let mut chosen = n - 1;
            for (i, &w) in d2.iter().enumerate() {
                if target < w {
                    chosen = i;
                    break;
                }
                target -= w;
            }
            chosen
        } else {
            rng.random_range(0..n)
        };
        let start = centers.len();
        centers.extend_from_slice(row(pick));
        nearer(&mut d2, data, dim, &centers[start..start + dim]);
    }
    centers
}

/// Rows per parallel task of [`nearer`], and the values (rows x dim) below which it stays on
/// one thread: a task must outweigh its scheduling (a few microseconds).
const NEARER_ROWS: usize = 256;
const NEARER_SERIAL_VALUES: usize = 1 << 14;

/// Lowers each row's squared distance in `d2` to that to `center`. Why in parallel: the
/// seedings draw from one stream one after another (so that labels do not depend on the
/// thread count), which leaves these updates, most of a seeding's work, as the only part
/// that can spread; each row's value is the same however the rows are split.
fn nearer(d2: &mut [f64], data: &[f64], dim: usize, center: &[f64]) {
    let update = |(chunk, rows): (&mut [f64], &[f64])| {
        for (d, x) in chunk.iter_mut().zip(rows.chunks_exact(dim)) {
            *d = d.min(dist_sq(x, center));
        }
    };
    if d2.len() * dim < NEARER_SERIAL_VALUES {
        update((d2, data));
    } else {
        d2.par_chunks_mut(NEARER_ROWS)
            .zip(data.par_chunks(NEARER_ROWS * dim))
            .for_each(update);
    }
}

/// `centers` (`k` rows of `dim`) as `dim` rows of `k`: one value of every centre side by side.
fn transpose(centers: &[f64], dim: usize, k: usize, by_dim: &mut [f64]) {
    for c in 0..k {
        for d in 0..dim {
            by_dim[d * k + c] = centers[c * dim + d];
        }
    }
}

/// The centre nearest to `x` (the first on ties) and its squared distance, from the centres
/// laid out by [`transpose`]. Why this layout: the distances to all centres then accumulate
/// side by side, which vectorises, and each still sums its terms in [`dist_sq`]'s order, so
/// the labels and inertia are those of the plain loop bit for bit.
#[inline]
fn nearest_center(x: &[f64], by_dim: &[f64], dists: &mut [f64]) -> (usize, f64) {
    let k = dists.len();
    dists.fill(0.0);
    for (d, &v) in x.iter().enumerate() {
        for (acc, &c) in dists.iter_mut().zip(&by_dim[d * k..(d + 1) * k]) {
            let t = v - c;
            *acc += t * t;
        }
    }
    let (mut bl, mut bd) = (0, f64::INFINITY);
    for (c, &d) in dists.iter().enumerate() {
        if d < bd {
            (bl, bd) = (c, d);
        }
    }
    (bl, bd)
}

/// [`nearest_center`], and the least squared distance to any other centre (infinite with one
/// centre).
#[inline]
fn nearest_two(x: &[f64], by_dim: &[f64], dists: &mut [f64]) -> (usize, f64, f64) {
    let (bl, bd) = nearest_center(x, by_dim, dists);
    let second = dists
        .iter()
        .enumerate()
        .filter(|&(c, _)| c != bl)
        .fold(f64::INFINITY, |m, (_, &d)| m.min(d));
    (bl, bd, second)
}

/// Half the distance from each centre to the nearest other one.
fn half_gaps(centers: &[f64], dim: usize, k: usize, out: &mut [f64]) {
    out.fill(f64::INFINITY);
    for a in 0..k {
        for b in a + 1..k {
            let d = 0.5
                * dist_sq(
                    &centers[a * dim..(a + 1) * dim],
                    &centers[b * dim..(b + 1) * dim],
                )
                .sqrt();
            out[a] = out[a].min(d);
            out[b] = out[b].min(d);
        }
    }
}

/// Lloyd's iterations from a k-means++ start, with Hamerly's bounds: each point keeps an upper
/// bound on the distance to its centre and a lower bound on the distance to every other, moved
/// by how far the centres move; a point whose upper bound lies below both the lower bound and
/// half the gap from its centre to the next cannot change label, so its distances are not
/// computed. Why: in a spectral embedding the groups lie far apart, and after a few iterations
/// almost no point needs them. The labels, centres and iterations are the plain loop's
/// exactly: a skip needs the bounds apart by a margin far above their rounding, and every
/// point not skipped is assigned by [`nearest_center`]; the inertia is summed at the end as
/// the plain loop sums it.
fn lloyd(data: &[f64], dim: usize, n: usize, k: usize, mut centers: Vec<f64>) -> (f64, Vec<usize>) {
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut labels = vec![usize::MAX; n];
    let mut inertia = f64::INFINITY;
    let (mut by_dim, mut dists) = (vec![0.0; k * dim], vec![0.0; k]);
    let (mut upper, mut lower) = (vec![f64::INFINITY; n], vec![0.0; n]);
    let (mut gaps, mut moved, mut previous) = (vec![0.0; k], vec![0.0; k], vec![0.0; k * dim]);
    // Bounds count as apart only by more than their rounding (relative 1e-13 after hundreds
    // of updates), relative to their size and to the data's scale.
    let scale = data.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let apart = |u: f64, m: f64| u + 1e-9 * (u + m) + 1e-12 * scale < m;
    for iteration in 0..MAX_ITERATIONS {
        let mut changed = false;
        transpose(&centers, dim, k, &mut by_dim);
        half_gaps(&centers, dim, k, &mut gaps);
        for (i, label) in labels.iter_mut().enumerate() {
            if *label != usize::MAX {
                let bound = gaps[*label].max(lower[i]);
                if apart(upper[i], bound) {
                    continue;
                }
                upper[i] = dist_sq(row(i), &centers[*label * dim..(*label + 1) * dim]).sqrt();
                if apart(upper[i], bound) {
                    continue;
                }
            }
            let (bl, bd, second) = nearest_two(row(i), &by_dim, &mut dists);
            (upper[i], lower[i]) = (bd.sqrt(), second.sqrt());
            if *label != bl {
                *label = bl;
                changed = true;
            }
        }
        if !changed || iteration + 1 == MAX_ITERATIONS {
            // Every label is its nearest centre: the plain loop's sum of those distances.
            inertia = 0.0;
            for (i, &l) in labels.iter().enumerate() {
                inertia += dist_sq(row(i), &centers[l * dim..(l + 1) * dim]);
            }
        }
        if !changed {
            break;
        }
        previous.copy_from_slice(&centers);
        update_centers(data, dim, n, k, &labels, &mut centers);
        for (c, m) in moved.iter_mut().enumerate() {
            let span = c * dim..(c + 1) * dim;
            *m = dist_sq(&previous[span.clone()], &centers[span]).sqrt();
        }
        let (mut first, mut top, mut runner_up) = (0, 0.0f64, 0.0f64);
        for (c, &m) in moved.iter().enumerate() {
            if m > top {
                (first, top, runner_up) = (c, m, top);
            } else if m > runner_up {
                runner_up = m;
            }
        }
        for (i, &l) in labels.iter().enumerate() {
            upper[i] += moved[l];
            lower[i] -= if l == first { runner_up } else { top };
        }
    }
    (inertia, labels)
}

/// Each centre the mean of its points; an empty cluster takes the point farthest from its own
/// centre (centres updated in order, as they are read).
fn update_centers(
    data: &[f64],
    dim: usize,
    n: usize,
    k: usize,
    labels: &[usize],
    centers: &mut [f64],
) {
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut sums = vec![0.0; k * dim];
    let mut counts = vec![0usize; k];
    for (i, &l) in labels.iter().enumerate() {
        counts[l] += 1;
        for (s, v) in sums[l * dim..(l + 1) * dim].iter_mut().zip(row(i)) {
            *s += v;
        }
    }
    for c in 0..k {
        if counts[c] > 0 {
            for (dst, s) in centers[c * dim..(c + 1) * dim]
                .iter_mut()
                .zip(&sums[c * dim..(c + 1) * dim])
            {
                *dst = s / counts[c] as f64;
            }
        } else {
            let far = (0..n)
                .max_by(|&a, &b| {
                    let da = dist_sq(row(a), &centers[labels[a] * dim..(labels[a] + 1) * dim]);
                    let db = dist_sq(row(b), &centers[labels[b] * dim..(labels[b] + 1) * dim]);
                    da.total_cmp(&db)
                })
                .unwrap_or(0);
            centers[c * dim..(c + 1) * dim].copy_from_slice(row(far));
        }
    }
}

/// The plain Lloyd loop the bounded one must equal (tests only): every point's distances to
/// every centre in every iteration.
#[cfg(test)]
fn lloyd_plain(
    data: &[f64],
    dim: usize,
    n: usize,
    k: usize,
    rng: &mut ChaCha8Rng,
) -> (f64, Vec<usize>) {
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centers = plus_plus_init(data, dim, n, k, rng);
    let mut labels = vec![usize::MAX; n];
    let mut inertia = f64::INFINITY;
    let (mut by_dim, mut dists) = (vec![0.0; k * dim], vec![0.0; k]);
    for _ in 0..MAX_ITERATIONS {
        let mut changed = false;
        inertia = 0.0;
        transpose(&centers, dim, k, &mut by_dim);
        for (i, label) in labels.iter_mut().enumerate() {
            let (bl, bd) = nearest_center(row(i), &by_dim, &mut dists);
            inertia += bd;
            if *label != bl {
                *label = bl;
                changed = true;
            }
        }
        if !changed {
            break;
        }
        update_centers(data, dim, n, k, &labels, &mut centers);
    }
    (inertia, labels)
}

#[cfg(test)]
#[path = "tests/kmeans.rs"]
mod tests;
