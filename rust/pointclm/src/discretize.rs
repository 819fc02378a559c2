//! Yu and Shi's discretisation ("Multiclass spectral clustering", ICCV 2003): find the
//! rotation of the eigenvector basis closest to a partition matrix. This is what
//! scikit-learn's `assign_labels="discretize"` does, used by the authors' code.

use faer::MatRef;
use nalgebra::DMatrix;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::kmeans::relabel_by_first_appearance;

const MAX_ITERATIONS: usize = 20;

/// Labels for the rows of the first `m` columns of `vectors` (eigenvectors of the normalised
/// Laplacian), best of `restarts` rotations by the normalised-cut objective.
pub fn discretize(
    vectors: MatRef<'_, f64>,
    m: usize,
    restarts: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<usize> {
    let n = vectors.nrows();
    if n == 0 || m == 0 {
        return vec![0; n];
    }
    let m = m.min(vectors.ncols()).max(1);
    // Unit columns scaled by sqrt(n), sign fixed by the first row, then unit rows.
    let mut v = DMatrix::<f64>::from_fn(n, m, |i, j| vectors[(i, j)]);
    for j in 0..m {
        let norm = v.column(j).norm();
        if norm > 0.0 {
            let sign = if v[(0, j)] < 0.0 { -1.0 } else { 1.0 };
            v.column_mut(j).scale_mut(sign * (n as f64).sqrt() / norm);
        }
    }
    for i in 0..n {
        let norm = v.row(i).norm();
        if norm > 0.0 {
            v.row_mut(i).scale_mut(1.0 / norm);
        }
    }
    let mut best: Option<(f64, Vec<usize>)> = None;
    for _ in 0..restarts.max(1) {
        let (ncut, labels) = one_restart(&v, rng);
        if best.as_ref().is_none_or(|(b, _)| ncut < *b) {
            best = Some((ncut, labels));
        }
    }
    relabel_by_first_appearance(&best.map(|b| b.1).unwrap_or_default())
}

fn one_restart(v: &DMatrix<f64>, rng: &mut ChaCha8Rng) -> (f64, Vec<usize>) {
    let (n, m) = v.shape();
    // Initial rotation: mutually most orthogonal rows.
    let mut rotation = DMatrix::<f64>::zeros(m, m);
    rotation.set_column(0, &v.row(rng.random_range(0..n)).transpose());
    let mut c = vec![0.0; n];
    for j in 1..m {
        let proj = v * rotation.column(j - 1);
        for (ci, p) in c.iter_mut().zip(proj.iter()) {
            *ci += p.abs();
        }
        let arg = (0..n).min_by(|&a, &b| c[a].total_cmp(&c[b])).unwrap_or(0);
        rotation.set_column(j, &v.row(arg).transpose());
    }
    let mut last = f64::INFINITY;
    let mut labels = vec![0; n];
    for _ in 0..MAX_ITERATIONS {
        let t = v * &rotation;
        for (i, l) in labels.iter_mut().enumerate() {
            *l = (0..m)
                .max_by(|&a, &b| t[(i, a)].total_cmp(&t[(i, b)]))
                .unwrap_or(0);
        }
        // t_svd = (one-hot labels)^T * v
        let mut t_svd = DMatrix::<f64>::zeros(m, m);
        for (i, &l) in labels.iter().enumerate() {
            for j in 0..m {
                t_svd[(l, j)] += v[(i, j)];
            }
        }
        let svd = t_svd.svd(true, true);
        let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
            break;
        };
        let ncut = 2.0 * (n as f64 - svd.singular_values.sum());
        if (ncut - last).abs() < f64::EPSILON {
            last = ncut;
            break;
        }
        last = ncut;
        rotation = v_t.transpose() * u.transpose();
    }
    (last, labels)
}
