//! Unit tests of `pruning`.

use super::*;
use crate::consistency::spatial_consistency;
use crate::testing::random_scene;

fn features_for(n: usize, seed: u64) -> Features {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut data = Vec::with_capacity(n * 8);
    for _ in 0..n {
        let v: Vec<f64> = (0..8).map(|_| rng.random::<f64>() - 0.3).collect();
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        data.extend(v.iter().map(|x| x / norm));
    }
    Features::new(data, 8).unwrap()
}

#[test]
fn blocked_and_dense_counts_agree_exactly() {
    // 301 rows: not a multiple of the block size
    let scene = random_scene(301, 3, 0.2, 5);
    let n = scene.corr.len();
    let feats = features_for(n, 1);
    for pruning in [Pruning::Paper, Pruning::AuthorsCode, Pruning::Disabled] {
        let config = Config {
            pruning,
            ..Config::default()
        };
        let beta = spatial_consistency(&scene.corr, config.sigma_d).unwrap();
        for f in [None, Some(&feats)] {
            let blocked = density_counts(&scene.corr, f, &config).unwrap();
            let dense = density_counts_dense(&beta, n, f, &config);
            assert_eq!(blocked, dense, "{pruning:?} features={}", f.is_some());
        }
    }
}

#[test]
fn inliers_survive_and_outliers_go() {
    let scene = random_scene(1000, 4, 0.04, 9);
    let config = Config::default();
    let counts = density_counts(&scene.corr, None, &config).unwrap();
    let kept = select_kept(&counts, &config);
    let kept_inliers = kept.iter().filter(|&&i| scene.labels[i] >= 0).count();
    let inliers = scene.labels.iter().filter(|&&l| l >= 0).count();
    assert!(kept_inliers as f64 >= 0.9 * inliers as f64);
    assert!(
        kept.len() - kept_inliers <= 20,
        "{} outliers kept",
        kept.len() - kept_inliers
    );
}

#[test]
fn cap_keeps_the_densest() {
    let counts = vec![50, 12, 40, 11, 30];
    let config = Config {
        max_kept: 10.max(Config::default().min_cluster_size),
        ..Config::default()
    };
    assert_eq!(select_kept(&counts, &config), vec![0, 1, 2, 3, 4]);
    let config = Config {
        max_kept: 10,
        min_cluster_size: 3,
        ..Config::default()
    };
    let many: Vec<u32> = (0..20).map(|i| 11 + i).collect();
    let kept = select_kept(&many, &config);
    assert_eq!(kept, (10..20).collect::<Vec<_>>());
}

#[test]
fn f32_paper_counts_equal_f64_counts_near_the_threshold_and_far_from_the_origin() {
    let scene = random_scene(400, 4, 0.1, 9);
    let n = scene.corr.len();
    for offset in [0.0, 1e4] {
        let rows: Vec<[f64; 6]> = (0..n)
            .map(|i| {
                let (s, t) = (scene.corr.source(i), scene.corr.target(i));
                [
                    s[0] + offset,
                    s[1],
                    s[2] - offset,
                    t[0] - 0.5 * offset,
                    t[1] + offset,
                    t[2],
                ]
            })
            .collect();
        let corr = Correspondences::from_rows(&rows).unwrap();
        for tau_s in [0.0, 0.5, 0.85, 0.99, 1.0] {
            let config = Config {
                tau_s,
                ..Config::default()
            };
            let beta = spatial_consistency(&corr, config.sigma_d).unwrap();
            let dense = density_counts_dense(&beta, n, None, &config);
            let fast = density_counts(&corr, None, &config).unwrap();
            assert_eq!(fast, dense, "offset {offset} tau_s {tau_s}");
            // Both builds of the row loop, whichever the CPU picks above.
            let inv = inv_sigma_sq(config.sigma_d).unwrap();
            let narrow = paper_counts_f32(&corr, tau_s, inv, false);
            assert_eq!(
                narrow, dense,
                "baseline build, offset {offset} tau_s {tau_s}"
            );
            if has_avx2() {
                let wide = paper_counts_f32(&corr, tau_s, inv, true);
                assert_eq!(wide, dense, "AVX2 build, offset {offset} tau_s {tau_s}");
            }
        }
    }
    // Points on a line whose pairs k apart differ in length by exactly D = sigma sqrt(1 - tau).
    let config = Config::default();
    let d = config.sigma_d * (1.0 - config.tau_s).sqrt();
    for k in [1.0, 3.0, 7.0] {
        let h = 0.01;
        let r = d / (k * h);
        let rows: Vec<[f64; 6]> = (0..200)
            .map(|j| {
                let x = j as f64 * h;
                [x, 0.0, 0.0, x * (1.0 + r), 0.0, 0.0]
            })
            .collect();
        let corr = Correspondences::from_rows(&rows).unwrap();
        let beta = spatial_consistency(&corr, config.sigma_d).unwrap();
        let dense = density_counts_dense(&beta, rows.len(), None, &config);
        assert_eq!(
            density_counts(&corr, None, &config).unwrap(),
            dense,
            "k {k}"
        );
    }
}

#[test]
fn f32_paper_counts_span_column_tiles() {
    // More rows than one column tile, and a ragged last tile.
    let n = COLUMN_TILE + 77;
    let scene = random_scene(n, 5, 0.05, 11);
    let config = Config::default();
    let beta = spatial_consistency(&scene.corr, config.sigma_d).unwrap();
    let dense = density_counts_dense(&beta, n, None, &config);
    let inv = inv_sigma_sq(config.sigma_d).unwrap();
    assert_eq!(
        paper_counts_f32(&scene.corr, config.tau_s, inv, false),
        dense
    );
    assert_eq!(density_counts(&scene.corr, None, &config).unwrap(), dense);
    // Each pair is tested once and added to both rows, in per-task counts summed at the end:
    // the same whatever the pool splits the row blocks into.
    for threads in [1, 2, 3] {
        let pool = crate::pipeline::thread_pool(threads).unwrap();
        let counts = pool.install(|| paper_counts_f32(&scene.corr, config.tau_s, inv, has_avx2()));
        assert_eq!(counts, dense, "{threads} threads");
    }
}

#[test]
fn f32_feature_counts_equal_f64_counts_for_every_threshold() {
    // Over a column tile, at several thresholds (negative ones take the f64 path), in both
    // builds of the row loop.
    let n = COLUMN_TILE + 31;
    let scene = random_scene(n, 4, 0.05, 13);
    let feats = features_for(n, 2);
    for (pruning, tau_s, beta_threshold) in [
        (Pruning::Paper, 0.0, 0.9),
        (Pruning::Paper, 0.5, 0.9),
        (Pruning::Paper, -0.1, 0.9),
        (Pruning::AuthorsCode, 0.85, 0.0),
        (Pruning::AuthorsCode, 0.85, 0.9),
        (Pruning::AuthorsCode, 0.85, -0.5),
    ] {
        let config = Config {
            pruning,
            tau_s,
            beta_threshold,
            sigma_d: 0.3,
            ..Config::default()
        };
        let beta = spatial_consistency(&scene.corr, config.sigma_d).unwrap();
        let dense = density_counts_dense(&beta, n, Some(&feats), &config);
        let label = format!("{pruning:?} tau_s {tau_s} beta_threshold {beta_threshold}");
        assert_eq!(
            density_counts(&scene.corr, Some(&feats), &config).unwrap(),
            dense,
            "{label}"
        );
        if let Some(rule) = FeatureRule::of(&config) {
            let inv = inv_sigma_sq(config.sigma_d).unwrap();
            for wide in [false, has_avx2()] {
                let got = feature_counts_f32(&scene.corr, &feats, rule, inv, wide);
                assert_eq!(got, dense, "{label} wide {wide}");
            }
        }
    }
}

#[test]
fn coordinates_beyond_the_f32_range_are_counted_in_f64() {
    // Lengths near 1e22: their f32 squares would overflow; the counts must still be exact.
    let scene = random_scene(300, 3, 0.1, 17);
    let scale = 1e22;
    let rows: Vec<[f64; 6]> = (0..scene.corr.len())
        .map(|i| {
            let (s, t) = (scene.corr.source(i), scene.corr.target(i));
            [s[0], s[1], s[2], t[0], t[1], t[2]].map(|v| v * scale)
        })
        .collect();
    let corr = Correspondences::from_rows(&rows).unwrap();
    assert!(!f32_fits(&corr));
    let n = corr.len();
    let feats = features_for(n, 3);
    for pruning in [Pruning::Paper, Pruning::AuthorsCode] {
        let config = Config {
            pruning,
            sigma_d: Config::default().sigma_d * scale,
            ..Config::default()
        };
        let beta = spatial_consistency(&corr, config.sigma_d).unwrap();
        for f in [None, Some(&feats)] {
            let dense = density_counts_dense(&beta, n, f, &config);
            assert_eq!(
                density_counts(&corr, f, &config).unwrap(),
                dense,
                "{pruning:?}"
            );
        }
    }
}
