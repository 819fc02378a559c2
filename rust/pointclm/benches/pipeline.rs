//! Criterion benchmarks of the whole pipeline, of its O(N^2) pruning stage, of the
//! clustering of one kept set (the partial eigensolver alone, and with the Laplacian and
//! k-means), of the a-contrario test's null probability (one radius count per
//! correspondence and pose), and of the point-cloud kernels on a 20,000-point surface:
//! normals, FPFH, mutual descriptor matching and refinement's bounded nearest-point queries.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use pointclm::clustering::{partial_basis, settled_count, spectral_clustering_by, Count};
use pointclm::lowest_eigen::lowest_eigenpairs;
use pointclm::matching::{match_features, nearest_sources, MatchingConfig};
use pointclm::pointcloud::icp::icp;
use pointclm::pointcloud::{
    describe, estimate_normals, fpfh, DescribeParams, FpfhVariant, Orientation, PointIndex,
    PpfModel, PpfParams, FPFH_DIM,
};
use pointclm::pruning::{density_counts, select_kept};
use pointclm::spectral::{affinity, normalized_laplacian};
use pointclm::validation::NullModel;
use pointclm::{register, Config, Correspondences, Features, RigidTransform};

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

/// A bumpy sheet (two scales of waves, so that local shapes vary) sampled on a jittered grid: `side` x `side` points about 1 apart, like a
/// downsampled scan of a surface.
fn surface(side: usize) -> Vec<[f64; 3]> {
    let mut state = 11u64;
    let mut u = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    (0..side * side)
        .map(|k| {
            let (x, y) = ((k % side) as f64 + 0.3 * u(), (k / side) as f64 + 0.3 * u());
            let z = 4.0 * (x / 9.0).sin() * (y / 13.0).cos()
                + 1.5 * (x / 3.7 + y / 5.3).sin() * (x / 6.1 - y / 2.9).cos();
            [x, y, z + 0.05 * u()]
        })
        .collect()
}

fn bench_point_clouds(c: &mut Criterion) {
    let pool = pointclm::pipeline::thread_pool(1).expect("pool");
    let scan = surface(141);
    let index = PointIndex::new(&scan).expect("index");
    let towards = Orientation::Towards([70.0, 70.0, 100.0]);
    c.bench_function("normals_20k_points_1_thread", |b| {
        b.iter(|| pool.install(|| estimate_normals(&scan, &index, 2.0, 30, towards).expect("n")))
    });
    let normals = estimate_normals(&scan, &index, 2.0, 30, towards).expect("normals");
    c.bench_function("fpfh_neighbourhoods_20k_points_1_thread", |b| {
        b.iter(|| pool.install(|| index.neighbourhoods(&scan, 5.0, 100).expect("hoods")))
    });
    c.bench_function("fpfh_20k_points_1_thread", |b| {
        b.iter(|| {
            pool.install(|| fpfh(&scan, &normals, &index, 5.0, 100, FpfhVariant::Open3d))
                .expect("fpfh")
        })
    });
    // Both stages as `describe` runs them: one neighbour search serves normals and FPFH.
    let params = DescribeParams {
        voxel_size: None,
        orientation: towards,
        ..DescribeParams::for_voxel(1.0)
    };
    c.bench_function("describe_20k_points_1_thread", |b| {
        b.iter(|| pool.install(|| describe(&scan, None, &params).expect("describe")))
    });
    let desc = fpfh(&scan, &normals, &index, 5.0, 100, FpfhVariant::Open3d).expect("fpfh");
    let flat = |rows: &[[f64; FPFH_DIM]]| {
        Features::new(rows.iter().flatten().copied().collect(), FPFH_DIM).expect("features")
    };
    // A 2,000-point "model": a patch of the same surface.
    let model: Vec<[f64; FPFH_DIM]> = (0..scan.len())
        .filter(|k| k % 141 < 45 && k / 141 < 45)
        .map(|k| desc[k])
        .collect();
    let (model, scan_desc) = (flat(&model), flat(&desc));
    let mutual = MatchingConfig {
        mutual: true,
        ..MatchingConfig::default()
    };
    c.bench_function("mutual_matching_2k_x_20k_1_thread", |b| {
        b.iter(|| {
            pool.install(|| match_features(&model, &scan_desc, &mutual, 0))
                .expect("m")
        })
    });
    // A heap's ranked mutual check: every model point's 64 nearest scan descriptors.
    c.bench_function("nearest_64_descriptors_2k_of_20k_1_thread", |b| {
        b.iter(|| {
            pool.install(|| nearest_sources(&scan_desc, &model, 64))
                .expect("k")
        })
    });
    let grid = PointIndex::with_cells(&scan, 1.5).expect("grid");
    let queries: Vec<[f64; 3]> = scan
        .iter()
        .step_by(10)
        .map(|p| [p[0] + 0.4, p[1], p[2] + 0.7])
        .collect();
    c.bench_function("nearest_within_2k_queries", |b| {
        b.iter(|| {
            queries
                .iter()
                .filter_map(|q| grid.nearest_within(q, 1.5))
                .count()
        })
    });
    // ICP of a 2,000-point patch started 0.6 cells and 2 degrees off: three stages of at
    // most ten steps, each model point paired by a bounded nearest-point query.
    let patch: Vec<[f64; 3]> = (0..scan.len())
        .filter(|k| k % 141 < 45 && k / 141 < 45)
        .map(|k| scan[k])
        .collect();
    let start = RigidTransform {
        rotation: *nalgebra::Rotation3::from_euler_angles(0.02, -0.02, 0.03).matrix(),
        translation: nalgebra::Vector3::new(0.4, -0.3, 0.3),
    };
    // Point pair voting (a heap's other pose generator): the patch's pairs tabled, every
    // fifth scan point sampled at a twentieth of its diameter a reference.
    let patch_normals: Vec<[f64; 3]> = (0..scan.len())
        .filter(|k| k % 141 < 45 && k / 141 < 45)
        .map(|k| normals[k])
        .collect();
    let (lo, hi) = patch
        .iter()
        .fold(([f64::MAX; 3], [f64::MIN; 3]), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        });
    let diameter = ((0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>()).sqrt();
    let voter = PpfModel::new(&patch, &patch_normals, PpfParams::for_diameter(diameter))
        .expect("ppf model");
    let rows: Vec<usize> = (0..scan.len()).collect();
    c.bench_function("ppf_votes_2k_model_on_20k_scan_1_thread", |b| {
        b.iter(|| {
            pool.install(|| voter.poses(&scan, &normals, &rows, 0))
                .expect("poses")
        })
    });
    c.bench_function("icp_2k_model_on_20k_scan", |b| {
        b.iter(|| {
            icp(
                &patch,
                &scan,
                &normals,
                &grid,
                start,
                &[3.0, 2.0, 1.5],
                10,
                None,
            )
        })
    });
}

criterion_group!(benches, bench, bench_point_clouds);
criterion_main!(benches);
