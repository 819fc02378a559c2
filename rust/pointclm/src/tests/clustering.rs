//! Unit tests of `clustering`.

use super::*;
use crate::pruning::{density_counts, select_kept};
use crate::spectral::{eigengap, normalized_laplacian, symmetric_eigen};
use crate::testing::random_scene;

#[test]
fn planted_instances_become_clusters() {
    let scene = random_scene(1000, 5, 0.03, 17);
    let config = Config::default();
    let counts = density_counts(&scene.corr, None, &config).unwrap();
    let kept = select_kept(&counts, &config);
    let (groups, _) = cluster_kept(&scene.corr, None, &kept, &config, 0).unwrap();
    assert_eq!(groups.len(), 5);
    for g in &groups {
        let l = scene.labels[g[0]];
        assert!(l >= 0);
        let pure = g.iter().filter(|&&i| scene.labels[i] == l).count();
        assert!(pure as f64 >= 0.95 * g.len() as f64);
    }
}

#[test]
fn groups_below_the_instance_floor_still_seed_poses() {
    // Two copies keep 30 rows each, a third only 5 (fewer than `min_cluster_size`, 10): its
    // group is kept, since the pose it fits may explain more rows than pruning kept.
    let scene = random_scene(300, 3, 0.1, 2);
    let kept: Vec<usize> = (0..65).collect();
    let config = Config::default();
    assert!(5 < config.min_cluster_size);
    let (groups, _) = cluster_kept(&scene.corr, None, &kept, &config, 0).unwrap();
    let sizes: Vec<usize> = groups.iter().map(Vec::len).collect();
    assert_eq!(sizes, vec![30, 30, 5]);
    assert!(groups[2].iter().all(|&i| scene.labels[i] == 2));
    // Fewer rows than a pose needs: nothing to cluster.
    let (none, _) = cluster_kept(&scene.corr, None, &kept[..2], &config, 0).unwrap();
    assert!(none.is_empty());
}

#[test]
fn both_assignments_agree_on_clean_blocks() {
    let scene = random_scene(300, 3, 0.1, 2);
    let kept: Vec<usize> = (0..90).collect();
    let a = affinity(&scene.corr, None, &kept, 0.1).unwrap();
    let k = spectral_clustering(a.as_ref(), None, None, Assignment::KMeans, 5, 0).unwrap();
    let d = spectral_clustering(a.as_ref(), None, None, Assignment::Discretize, 5, 0).unwrap();
    assert_eq!(k.n_clusters, 3);
    assert_eq!(k.labels, d.labels);
    let truth: Vec<usize> = scene.labels[..90].iter().map(|&l| l as usize).collect();
    assert_eq!(k.labels, crate::kmeans::relabel_by_first_appearance(&truth));
}

#[test]
fn level_count_never_lowers_the_eigengap_and_counts_low_eigenvalues() {
    let scene = random_scene(300, 3, 0.1, 2);
    let kept: Vec<usize> = (0..90).collect();
    let a = affinity(&scene.corr, None, &kept, 0.1).unwrap();
    let gap = spectral_clustering(a.as_ref(), None, None, Assignment::KMeans, 5, 0).unwrap();
    for level in [1e-9, 0.5, 1.5] {
        let count = Count::Eigengap {
            cap: None,
            level: Some(level),
        };
        let r = spectral_clustering_by(a.as_ref(), count, Assignment::KMeans, 5, 0).unwrap();
        let below = r.eigenvalues.iter().filter(|&&v| v < level).count();
        assert_eq!(r.n_clusters, gap.n_clusters.max(below), "level {level}");
    }
    // The cap bounds the level's count too.
    let capped = Count::Eigengap {
        cap: Some(4),
        level: Some(1.5),
    };
    let r = spectral_clustering_by(a.as_ref(), capped, Assignment::KMeans, 5, 0).unwrap();
    assert_eq!(r.n_clusters, 4);
}

#[test]
fn cluster_level_is_validated() {
    for bad in [0.0, 2.0, f64::NAN, -1.0] {
        let c = Config {
            cluster_level: Some(bad),
            ..Config::default()
        };
        assert!(c.validate().is_err(), "{bad}");
    }
    let ok = Config {
        cluster_level: Some(0.7),
        ..Config::default()
    };
    assert!(ok.validate().is_ok());
}

#[test]
fn partial_spectrum_gives_the_dense_count_and_groups() {
    use crate::spectral::tests::block_affinity;
    let sizes = [150, 120, 100, 90, 80, 60];
    let a = block_affinity(&sizes);
    let n = a.nrows();
    assert!(n >= PARTIAL_ROWS);
    let l = normalized_laplacian(a.as_ref()).unwrap();
    let (dense, _) = symmetric_eigen(l.as_ref(), false).unwrap();
    let r = spectral_clustering(a.as_ref(), None, None, Assignment::KMeans, 5, 0).unwrap();
    assert!(r.eigenvalues.len() < n, "the partial path ran");
    assert_eq!(r.n_clusters, eigengap(&dense, None));
    let mut truth = Vec::new();
    for (b, &s) in sizes.iter().enumerate() {
        truth.extend(std::iter::repeat_n(b, s));
    }
    assert_eq!(r.labels, crate::kmeans::relabel_by_first_appearance(&truth));
    for level in [0.5, 1.2] {
        let count = Count::Eigengap {
            cap: None,
            level: Some(level),
        };
        let r = spectral_clustering_by(a.as_ref(), count, Assignment::KMeans, 5, 0).unwrap();
        let below = dense.iter().filter(|&&v| v < level).count();
        assert_eq!(
            r.n_clusters,
            eigengap(&dense, None).max(below),
            "level {level}"
        );
    }
}

#[test]
fn partial_spectrum_on_planted_scenes_matches_the_dense_count() {
    for seed in 0..3 {
        let scene = random_scene(2500, 8, 0.04, seed);
        let kept: Vec<usize> = (0..scene.corr.len())
            .filter(|&i| scene.labels[i] >= 0 || i % 5 == 0)
            .collect();
        assert!(kept.len() >= PARTIAL_ROWS);
        let a = affinity(&scene.corr, None, &kept, 0.1).unwrap();
        let l = normalized_laplacian(a.as_ref()).unwrap();
        let (dense, _) = symmetric_eigen(l.as_ref(), false).unwrap();
        // Capped as `cluster_kept` caps it: at most one group per `MIN_SEED_ROWS` rows.
        let cap = Some(kept.len() / MIN_SEED_ROWS);
        let r = spectral_clustering(a.as_ref(), None, cap, Assignment::KMeans, 5, 0).unwrap();
        assert!(r.eigenvalues.len() < kept.len(), "the partial path ran");
        assert_eq!(r.n_clusters, eigengap(&dense, cap), "seed {seed}");
    }
}

/// Estimates with every value converged and exact (zero residuals).
fn exact(values: &[f64]) -> Estimates<'_> {
    Estimates {
        values,
        residuals: &[0.0; 64][..values.len()],
        converged: values.len(),
    }
}

#[test]
fn settled_count_needs_every_gap_it_may_pick() {
    let count = Count::Eigengap {
        cap: None,
        level: None,
    };
    // The largest gap in the lower half of the prefix settles it; in the upper half, not yet.
    assert_eq!(
        settled_count(&exact(&[0.0, 0.01, 0.5, 0.55, 0.6]), 100, count),
        Some(2)
    );
    assert_eq!(
        settled_count(&exact(&[0.0, 0.01, 0.02, 0.03, 0.6]), 100, count),
        None
    );
    // A level needs the prefix to reach it, unless the cap is already within it.
    let level = Count::Eigengap {
        cap: None,
        level: Some(0.7),
    };
    assert_eq!(
        settled_count(&exact(&[0.0, 0.01, 0.5, 0.55, 0.6]), 100, level),
        None
    );
    let capped = Count::Eigengap {
        cap: Some(3),
        level: Some(0.7),
    };
    assert_eq!(
        settled_count(&exact(&[0.0, 0.01, 0.02, 0.03, 0.6]), 100, capped),
        Some(3)
    );
    assert_eq!(settled_count(&exact(&[0.1; 4]), 4, count), Some(1));
    assert_eq!(
        settled_count(&exact(&[0.1; 3]), 100, Count::Fixed(3)),
        Some(3)
    );
    assert_eq!(settled_count(&exact(&[0.1; 2]), 100, Count::Fixed(3)), None);
}

#[test]
fn ritz_bounds_settle_the_gap_before_the_rest_converges() {
    let count = Count::Eigengap {
        cap: Some(5),
        level: None,
    };
    // Three groups, then the rest near 0.9: converged through rank 3, the fourth value within
    // 0.05, the upper bounds up to rank cap + 1 = 6 unconverged. The gap at 3 is at least
    // 0.85 - 0.02 = 0.83; all later gaps together span at most 1.0 - 0.85.
    let values = [0.0, 0.01, 0.02, 0.9, 0.95, 1.0, 1.1, 1.2];
    let est = Estimates {
        values: &values,
        residuals: &[0.0, 0.0, 0.0, 0.05, 0.3],
        converged: 3,
    };
    assert_eq!(gap_by_bounds(&est, 5), Some(3));
    assert_eq!(settled_count(&est, 100, count), Some(3));
    // Without the bound of rank cap + 1, or with a span after the gap that could hold a
    // larger one, nothing is settled.
    assert_eq!(
        gap_by_bounds(
            &Estimates {
                values: &values[..5],
                ..est
            },
            5
        ),
        None
    );
    let wide = [0.0, 0.01, 0.02, 0.9, 0.95, 1.9, 1.95, 2.0];
    assert_eq!(
        gap_by_bounds(
            &Estimates {
                values: &wide,
                ..est
            },
            5
        ),
        None
    );
    // A residual that leaves the gap's lower end unsure: not settled either.
    let unsure = Estimates {
        residuals: &[0.0, 0.0, 0.0, 0.6],
        ..est
    };
    assert_eq!(gap_by_bounds(&unsure, 5), None);
}
