//! Unit tests of `clustering`.

use super::*;
use crate::pruning::{density_counts, select_kept};
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
