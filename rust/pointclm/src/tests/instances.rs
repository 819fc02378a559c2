//! Unit tests of `instances`: each stage of `finalize` on a few hand-made rows with a known
//! answer, then the whole of it.

use nalgebra::Vector3;

use super::*;

/// Source points that no three of them are collinear (Kabsch needs a non-degenerate set).
const BASE: [[f64; 3]; 6] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 1.0],
];

/// A translation by `x` along the x axis.
fn shift(x: f64) -> RigidTransform {
    RigidTransform {
        translation: Vector3::new(x, 0.0, 0.0),
        ..RigidTransform::identity()
    }
}

/// Rows `(p, p + (dx, 0, 0))`: for each `(count, dx)`, `count` rows from the first base
/// points, all moved by `dx`.
fn rows(groups: &[(usize, f64)]) -> Correspondences {
    let (mut src, mut dst) = (Vec::new(), Vec::new());
    for &(count, dx) in groups {
        for p in BASE.iter().cycle().take(count) {
            src.push(*p);
            dst.push([p[0] + dx, p[1], p[2]]);
        }
    }
    Correspondences::new(&src, &dst).unwrap()
}

fn instance(inliers: Vec<usize>) -> Instance {
    Instance {
        pose: RigidTransform::identity(),
        inliers,
        inlier_rmse: 0.0,
        fitness: 0.0,
    }
}

fn sizes(instances: &[Instance]) -> Vec<usize> {
    instances.iter().map(|i| i.inliers.len()).collect()
}

#[test]
fn rescore_counts_inliers_over_all_rows_largest_first() {
    // Rows 0-2 fit the identity, rows 3-7 a shift by 10; the fits saw only part of theirs.
    let c = rows(&[(3, 0.0), (5, 10.0)]);
    let fits = [
        RansacFit {
            pose: shift(0.0),
            inliers: vec![0],
        },
        RansacFit {
            pose: shift(10.0),
            inliers: vec![],
        },
    ];
    let candidates = rescore(&c, &fits, false, 0.01);
    assert_eq!(candidates.len(), 2);
    assert_eq!(candidates[0].0, shift(10.0));
    assert_eq!(candidates[0].1, vec![3, 4, 5, 6, 7]);
    assert_eq!(candidates[1].0, shift(0.0));
    assert_eq!(candidates[1].1, vec![0, 1, 2]);
}

#[test]
fn rescore_keeps_the_least_squares_refit_when_it_loses_no_inlier() {
    // A fit 0.05 off the rows' shift of 1: the refit lands on the shift itself.
    let c = rows(&[(6, 1.0)]);
    let fits = [RansacFit {
        pose: shift(1.05),
        inliers: vec![0, 1, 2],
    }];
    let refined = rescore(&c, &fits, true, 0.01);
    assert_eq!(refined[0].1, (0..6).collect::<Vec<_>>());
    assert!((refined[0].0.translation - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
    assert!((refined[0].0.rotation - RigidTransform::identity().rotation).norm() < 1e-12);
    // Without `refine` the fit's pose stays as it was.
    assert_eq!(rescore(&c, &fits, false, 0.01)[0].0, shift(1.05));
}

#[test]
fn merge_keeps_the_first_of_two_candidates_with_the_same_placement() {
    let c = rows(&[(6, 0.0), (6, 5.0)]);
    let candidates = vec![
        (shift(0.0), vec![0, 1, 2, 3, 4, 5]),
        (shift(0.02), vec![0, 1, 2]), // the same copy, 0.02 away: a duplicate
        (shift(5.0), vec![6, 7, 8, 9, 10, 11]),
    ];
    let kept = merge_duplicates(&c, candidates.clone(), 0.1);
    assert_eq!(kept, vec![candidates[0].clone(), candidates[2].clone()]);
    // 0.2 apart is another placement at this threshold.
    let apart = vec![candidates[0].clone(), (shift(0.2), vec![0, 1])];
    assert_eq!(merge_duplicates(&c, apart.clone(), 0.1), apart);
}

#[test]
fn assign_gives_each_row_the_pose_it_fits_best() {
    // Poses shift by 0 and by 0.15; threshold 0.1.
    let poses = vec![(shift(0.0), vec![]), (shift(0.15), vec![])];
    let c = rows(&[(1, 0.07), (1, 0.12), (1, 0.5), (1, 0.0), (1, 0.15)]);
    // 0.07: 0.07 from the first, 0.08 from the second; 0.12: only the second is within
    // 0.1; 0.5: neither.
    assert_eq!(assign(&c, &poses, 0.01), vec![0, 1, -1, 0, 1]);
    // Equally near both (0.075 = 0.15 / 2 exactly at the origin): the first pose.
    let tie = rows(&[(1, 0.075), (1, 9.0), (1, 9.0)]);
    assert_eq!(assign(&tie, &poses, 0.01), vec![0, -1, -1]);
}

#[test]
fn the_weakest_small_pose_is_dropped_first_and_its_rows_reassigned() {
    // A (shift 0) fits 5 rows; B (1.0) and C (1.05) fit 2 each best and each other's 2
    // within the threshold. With at least 3 rows per pose, the later of the two equally
    // weak, C, goes first; its rows then go to B, which keeps it.
    let c = rows(&[(5, 0.0), (2, 1.0), (2, 1.05)]);
    let mut poses = vec![
        (shift(0.0), vec![]),
        (shift(1.0), vec![]),
        (shift(1.05), vec![]),
    ];
    let labels = assign_dropping_small(&c, &mut poses, 0.01, 3);
    assert_eq!(poses.len(), 2);
    assert_eq!(poses[1].0, shift(1.0));
    assert_eq!(labels, vec![0, 0, 0, 0, 0, 1, 1, 1, 1]);
    // A pose nothing else can take over leaves its rows outliers.
    let mut poses = vec![(shift(0.0), vec![]), (shift(1.0), vec![])];
    let labels = assign_dropping_small(&c, &mut poses, 0.01, 6);
    assert!(poses.is_empty());
    assert_eq!(labels, vec![-1; 9]);
}

#[test]
fn refit_instances_report_inliers_rmse_and_fitness_of_their_pose() {
    // Rows 0-2 exact for the identity, row 3 off by 0.05, row 4 by 0.09 but labelled
    // elsewhere, row 5 an outlier.
    let c = rows(&[(3, 0.0), (1, 0.05), (1, 0.09), (1, 3.0)]);
    let poses = vec![(shift(0.0), vec![])];
    let labels = [0, 0, 0, 0, -1, -1];
    let config = Config {
        refine: false,
        inlier_threshold: 0.1,
        ..Config::default()
    };
    let instances = refit_instances(&c, &poses, &labels, &config);
    assert_eq!(instances.len(), 1);
    let inst = &instances[0];
    assert_eq!(inst.pose, shift(0.0));
    assert_eq!(inst.inliers, vec![0, 1, 2, 3]);
    let r3 = shift(0.0).residual_sq(c.source(3), c.target(3));
    assert_eq!(inst.inlier_rmse, (r3 / 4.0).sqrt());
    assert_eq!(inst.fitness, 4.0 / 6.0);
}

#[test]
fn refit_instances_move_the_pose_onto_its_rows() {
    // The pose is 0.03 off the rows' shift of 2; the least-squares and robust refit put it
    // on them, with zero residual.
    let c = rows(&[(6, 2.0), (2, 7.0)]);
    let poses = vec![(shift(2.03), vec![])];
    let labels = [0, 0, 0, 0, 0, 0, -1, -1];
    let config = Config {
        refine: true,
        inlier_threshold: 0.1,
        ..Config::default()
    };
    let inst = &refit_instances(&c, &poses, &labels, &config)[0];
    assert!((inst.pose.translation - Vector3::new(2.0, 0.0, 0.0)).norm() < 1e-12);
    assert_eq!(inst.inliers, (0..6).collect::<Vec<_>>());
    assert!(inst.inlier_rmse < 1e-12);
    assert_eq!(inst.fitness, 6.0 / 8.0);
}

#[test]
fn relabel_drops_instances_left_below_three_rows() {
    let instances = vec![
        instance(vec![0, 1, 2]),
        instance(vec![3, 4]),
        instance(vec![5, 6, 7]),
    ];
    let (instances, labels) = relabel_refit(instances, 9);
    assert_eq!(sizes(&instances), vec![3, 3]);
    assert_eq!(instances[1].inliers, vec![5, 6, 7]);
    assert_eq!(labels, vec![0, 0, 0, -1, -1, 1, 1, 1, -1]);
}

#[test]
fn renumbering_puts_the_largest_first_and_follows_with_the_labels() {
    let instances = vec![
        instance(vec![0, 1]),
        instance(vec![2, 3, 4, 5]),
        instance(vec![6, 7, 8, 9]),
    ];
    let labels = vec![0, 0, 1, 1, 1, 1, 2, 2, 2, 2, -1];
    let (instances, labels) = renumber_largest_first(instances, labels);
    // Equal sizes keep their order.
    assert_eq!(instances[0].inliers, vec![2, 3, 4, 5]);
    assert_eq!(instances[1].inliers, vec![6, 7, 8, 9]);
    assert_eq!(instances[2].inliers, vec![0, 1]);
    assert_eq!(labels, vec![2, 2, 0, 0, 0, 0, 1, 1, 1, 1, -1]);
}

#[test]
fn renumbering_after_a_drop_leaves_no_gap() {
    // The middle instance is dropped for having two rows; the others become 0 and 1.
    let instances = vec![
        instance(vec![0, 1, 2]),
        instance(vec![3, 4]),
        instance(vec![5, 6, 7, 8]),
    ];
    let (instances, labels) = relabel_refit(instances, 9);
    let (instances, labels) = renumber_largest_first(instances, labels);
    assert_eq!(sizes(&instances), vec![4, 3]);
    assert_eq!(labels, vec![1, 1, 1, -1, -1, 0, 0, 0, 0]);
}

#[test]
fn finalize_merges_assigns_and_orders_instances() {
    // Copy A (shift 0) holds 4 rows, copy B (shift 5) 6, then 2 outliers. The fits: A, B
    // and a near-duplicate of B that saw only part of it.
    let c = rows(&[(4, 0.0), (6, 5.0), (1, 20.0), (1, -20.0)]);
    let fit = |x: f64, inliers: Vec<usize>| RansacFit {
        pose: shift(x),
        inliers,
    };
    let fits = [
        fit(0.0, vec![0, 1, 2]),
        fit(5.01, vec![4, 5, 6]),
        fit(5.0, vec![4, 5, 6, 7, 8, 9]),
    ];
    let config = Config {
        inlier_threshold: 0.1,
        min_cluster_size: 3,
        max_nfa: None,
        ..Config::default()
    };
    let (instances, labels) = finalize(&c, &fits, &config, None);
    assert_eq!(sizes(&instances), vec![6, 4]);
    assert!((instances[0].pose.translation - Vector3::new(5.0, 0.0, 0.0)).norm() < 1e-12);
    assert!(instances[1].pose.translation.norm() < 1e-12);
    assert_eq!(instances[0].fitness, 6.0 / 12.0);
    assert_eq!(labels, vec![1, 1, 1, 1, 0, 0, 0, 0, 0, 0, -1, -1]);
    // Without merging (and refits), the duplicate loses every row to the exact pose, which
    // fits them better, and is dropped as too small.
    let keep_all = Config {
        merge_duplicates: false,
        refine: false,
        ..config
    };
    let (instances, labels2) = finalize(&c, &fits, &keep_all, None);
    assert_eq!(sizes(&instances), vec![6, 4]);
    assert_eq!(instances[0].pose, shift(5.0));
    assert_eq!(labels2, labels);
}

#[test]
fn instances_left_too_small_by_the_refit_are_dropped() {
    // A fit at shift 0 explains 9 rows within the threshold of 0.1: 3 at shift -0.09 and 6
    // at +0.09. The refit moves it towards the 6 and out of reach of the 3, which leaves 6
    // rows. Another copy (shift 5) holds 8 exact rows.
    let c = rows(&[(3, -0.09), (6, 0.09), (8, 5.0)]);
    let fit = |x: f64| RansacFit {
        pose: shift(x),
        inliers: vec![],
    };
    let fits = [fit(0.0), fit(5.0)];
    let config = Config {
        inlier_threshold: 0.1,
        min_cluster_size: 8,
        max_nfa: None,
        refine: true,
        ..Config::default()
    };
    let (instances, labels) = finalize(&c, &fits, &config, None);
    assert_eq!(sizes(&instances), vec![8]);
    assert!((instances[0].pose.translation - Vector3::new(5.0, 0.0, 0.0)).norm() < 1e-12);
    assert_eq!(labels[..9], [-1; 9]);
    assert_eq!(labels[9..], [0; 8]);
    // With a floor of 6 the moved pose stays, with the 6 rows it still explains.
    let six = Config {
        min_cluster_size: 6,
        ..config
    };
    let (instances, labels) = finalize(&c, &fits, &six, None);
    assert_eq!(sizes(&instances), vec![8, 6]);
    assert_eq!(labels[..3], [-1; 3]);
    assert_eq!(labels[3..9], [1; 6]);
}
