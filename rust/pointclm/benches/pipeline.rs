//! Criterion benchmarks of the whole pipeline, of its O(N^2) pruning stage, of the
//! clustering of one kept set (the partial eigensolver alone, and with the Laplacian and
//! k-means) and of the a-contrario test's null probability (one radius count per
//! correspondence and pose).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use pointclm::clustering::{partial_basis, settled_count, spectral_clustering_by, Count};
use pointclm::lowest_eigen::lowest_eigenpairs;
use pointclm::pruning::{density_counts, select_kept};
use pointclm::spectral::{affinity, normalized_laplacian};
use pointclm::validation::NullModel;
use pointclm::{register, Config, Correspondences, RigidTransform};

/// `instances` copies with `per` noise-free inliers each, the rest uniform outliers in
/// [0, 6)^3, from a fixed linear congruential sequence.
fn scene(n: usize, instances: usize, per: usize) -> Correspondences {
    let mut state = 7u64;
    let mut u = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut src, mut dst) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for k in 0..instances {
        let (c, s) = ((k as f64 * 0.7).cos(), (k as f64 * 0.7).sin());
        let t = [u() * 5.0, u() * 5.0, u() * 5.0];
        for _ in 0..per {
            let p = [u() * 2.0 - 1.0, u() * 2.0 - 1.0, u() * 2.0 - 1.0];
            src.push(p);
            dst.push([
                c * p[0] - s * p[1] + t[0],
                s * p[0] + c * p[1] + t[1],
                p[2] + t[2],
            ]);
        }
    }
    while src.len() < n {
        src.push([u() * 2.0 - 1.0, u() * 2.0 - 1.0, u() * 2.0 - 1.0]);
        dst.push([u() * 6.0, u() * 6.0, u() * 6.0]);
    }
    Correspondences::new(&src, &dst).expect("finite planted scene")
}

fn bench(c: &mut Criterion) {
    let config = Config::default();
    let pool = pointclm::pipeline::thread_pool(1).expect("pool");
    let mut g = c.benchmark_group("register_1_thread");
    for n in [1000usize, 4000] {
        let corr = scene(n, 7, n / 50);
        g.bench_with_input(BenchmarkId::from_parameter(n), &corr, |b, corr| {
            b.iter(|| pool.install(|| register(corr, None, &config, 0).expect("register")))
        });
    }
    g.finish();
    let corr = scene(1000, 7, 20);
    c.bench_function("density_counts_1000_1_thread", |b| {
        b.iter(|| pool.install(|| density_counts(&corr, None, &config).expect("counts")))
    });
    let kept = select_kept(
        &density_counts(&corr, None, &config).expect("counts"),
        &config,
    );
    let a = affinity(&corr, None, &kept, config.affinity_sigma).expect("affinity");
    let l = normalized_laplacian(a.as_ref()).expect("laplacian");
    let (rows, assignment) = (kept.len(), config.assignment);
    let count = Count::Eigengap {
        cap: Some(rows / 3),
        level: None,
    };
    c.bench_function("lowest_eigenpairs_kept_set_1000", |b| {
        b.iter(|| {
            lowest_eigenpairs(l.as_ref(), partial_basis(rows), 0, |e| {
                settled_count(e, rows, count)
            })
        })
    });
    c.bench_function("spectral_clustering_kept_set_1000", |b| {
        b.iter(|| spectral_clustering_by(a.as_ref(), count, assignment, 10, 0).expect("clusters"))
    });
    let null = NullModel::new(&corr, config.inlier_threshold);
    let pose = RigidTransform::identity();
    c.bench_function("null_probability_1000", |b| {
        b.iter(|| null.null_probability(&corr, &pose))
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
