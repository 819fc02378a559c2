use super::*;
use crate::error::Error;

fn grid() -> Vec<[f64; 3]> {
    let mut pts = Vec::new();
    for i in 0..10 {
        for j in 0..10 {
            for k in 0..5 {
                pts.push([i as f64 * 0.1, j as f64 * 0.1, k as f64 * 0.1]);
            }
        }
    }
    pts
}

#[test]
fn hybrid_matches_brute_force() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    for (q, radius, max_nn) in [(0usize, 0.25, 100usize), (137, 0.15, 5), (499, 0.31, 1000)] {
        let got = index.hybrid(&pts[q], radius, max_nn);
        let mut want: Vec<(usize, f64)> = pts
            .iter()
            .enumerate()
            .map(|(j, p)| (j, (0..3).map(|k| (p[k] - pts[q][k]).powi(2)).sum::<f64>()))
            .filter(|&(_, d)| d <= radius * radius)
            .collect();
        want.sort_by(|a, b| a.1.total_cmp(&b.1));
        want.truncate(max_nn);
        assert_eq!(got.len(), want.len());
        assert_eq!(got[0].0, q, "a point finds itself first");
        for (g, w) in got.iter().zip(&want) {
            assert!((g.1 - w.1).abs() < 1e-12);
        }
    }
    let (j, d) = index.nearest(&[0.51, 0.49, 0.2]);
    assert!(d < 0.0003);
    assert_eq!(pts[j], [0.5, 0.5, 0.2]);
}

#[test]
fn neighbourhoods_agree_with_single_queries() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    let hoods = index.neighbourhoods(&pts, 0.2, 12).unwrap();
    assert_eq!(hoods.len(), pts.len());
    for i in [0, 55, 321] {
        let (idx, d2) = hoods.of(i);
        let single = index.hybrid(&pts[i], 0.2, 12);
        assert_eq!(idx.len(), single.len());
        for ((a, b), s) in idx.iter().zip(d2).zip(&single) {
            assert!((*b - s.1).abs() < 1e-15);
            let _ = a;
        }
    }
    assert!(matches!(
        index.neighbourhoods(&pts, -1.0, 12),
        Err(Error::InvalidParameter { .. })
    ));
    assert!(matches!(
        index.neighbourhoods(&pts, 0.1, 0),
        Err(Error::InvalidParameter { .. })
    ));
    assert!(matches!(
        PointIndex::new(&[]),
        Err(Error::TooFewPoints { .. })
    ));
}

#[test]
fn nearest_within_is_the_nearest_point_closer_than_the_radius() {
    let pts = grid();
    let index = PointIndex::new(&pts).unwrap();
    for q in [
        [0.31, 0.47, 0.05],
        [0.5, 0.5, 0.5],
        [3.0, 3.0, 3.0],
        [-0.2, 0.1, 0.0],
    ] {
        let (j, d2) = index.nearest(&q);
        for radius in [0.01, 0.1, 0.3, 10.0] {
            let within = index.nearest_within(&q, radius);
            if d2 < radius * radius {
                let (k, e2) = within.expect("a point lies within the radius");
                assert_eq!(e2, d2);
                assert_eq!(pts[k], pts[j]);
            } else {
                assert_eq!(within, None);
            }
        }
    }
}

#[test]
fn grid_nearest_within_equals_the_trees() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut pts: Vec<[f64; 3]> = (0..2000)
        .map(|_| {
            [
                rng.random::<f64>(),
                rng.random::<f64>(),
                rng.random::<f64>() * 0.2,
            ]
        })
        .collect();
    // Duplicates: the grid answers with the lowest index among equally near points.
    pts.extend_from_within(..50);
    let tree = PointIndex::new(&pts).unwrap();
    for cell in [0.01, 0.03, 0.1] {
        let grid = PointIndex::with_cells(&pts, cell).unwrap();
        for k in 0..1000 {
            // Half the queries near a point (the small first box of the grid's search holds
            // the answer), half anywhere.
            let q = if k % 2 == 0 {
                let p = pts[rng.random_range(0..pts.len())];
                [0, 1, 2].map(|a| p[a] + (rng.random::<f64>() - 0.5) * 0.02)
            } else {
                [
                    rng.random::<f64>() * 1.2 - 0.1,
                    rng.random::<f64>() * 1.2 - 0.1,
                    rng.random::<f64>() * 0.4 - 0.1,
                ]
            };
            for radius in [0.005, 0.02, 0.045, 0.3] {
                let (a, b) = (
                    tree.nearest_within(&q, radius),
                    grid.nearest_within(&q, radius),
                );
                assert_eq!(grid.any_within(&q, radius), a.is_some());
                assert_eq!(tree.any_within(&q, radius), a.is_some());
                match (a, b) {
                    (Some((i, d)), Some((j, e))) => {
                        assert_eq!(d, e, "cell {cell} radius {radius}");
                        assert_eq!(pts[i], pts[j]);
                        assert!(j < 2000, "the first of duplicates");
                    }
                    (None, None) => {}
                    _ => panic!("cell {cell} radius {radius}: {a:?} against {b:?}"),
                }
            }
        }
    }
    assert!(PointIndex::with_cells(&pts, 0.0).is_err());
}

/// `n` points of the surface z = 0.1 sin(6 x) over the unit square, each moved by up to
/// `noise` in z (no draw for the noise when it is 0).
fn wavy_surface(rng: &mut impl rand::Rng, n: usize, noise: f64) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| {
            let (x, y): (f64, f64) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
            let jitter = if noise > 0.0 {
                noise * rng.random_range(-1.0..1.0)
            } else {
                0.0
            };
            [x, y, 0.1 * (6.0 * x).sin() + jitter]
        })
        .collect()
}

#[test]
fn grid_neighbourhoods_equal_the_trees() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    // A noisy surface patch (FPFH's case) and a volume; radius and max_nn such that some
    // lists are cut at max_nn and others are not.
    let surface = wavy_surface(&mut rng, 3000, 0.002);
    let volume: Vec<[f64; 3]> = (0..2000)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-1.0..1.0)))
        .collect();
    for (points, radius, max_nn) in [
        (&surface, 0.05, 30),
        (&surface, 0.05, 1000),
        (&volume, 0.2, 16),
    ] {
        assert_lists_are_the_trees(points, radius, max_nn, 1);
    }
}

/// Asserts that the grid's neighbour lists of every `step`-th point equal the tree's hybrid
/// search; how many of them hold 32 points or more.
fn assert_lists_are_the_trees(
    points: &[[f64; 3]],
    radius: f64,
    max_nn: usize,
    step: usize,
) -> usize {
    let index = PointIndex::new(points).unwrap();
    let grid = grid_neighbourhoods(points, radius, max_nn).unwrap();
    let mut long = 0;
    for (i, p) in points.iter().enumerate().step_by(step) {
        let (idx, d2) = grid.of(i);
        long += usize::from(idx.len() >= 32);
        let list: Vec<(usize, f64)> = idx.iter().map(|&j| j as usize).zip(d2.to_vec()).collect();
        assert_eq!(list, index.hybrid(p, radius, max_nn), "point {i}");
    }
    long
}

#[test]
fn a_point_comes_first_in_its_own_neighbourhood_among_duplicates() {
    let points = vec![
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0],
        [0.1, 0.0, 0.0],
        [0.0, 0.0, 0.0],
    ];
    let lists = grid_neighbourhoods(&points, 0.5, 10).unwrap();
    assert_eq!(lists.len(), 4);
    for i in 0..4 {
        assert_eq!(lists.of(i).0[0] as usize, i);
    }
}

#[test]
fn a_radius_large_against_the_cloud_takes_the_tree() {
    // Every point in one cell: a query would scan the whole cloud for 10 neighbours.
    let points: Vec<[f64; 3]> = (0..2000).map(|i| [i as f64 * 1e-3, 0.0, 0.0]).collect();
    assert!(grid_neighbourhoods(&points, 10.0, 10).is_none());
    let index = PointIndex::new(&points).unwrap();
    let hoods = index.neighbourhoods(&points, 10.0, 10).unwrap();
    assert_eq!(hoods.of(5).0.len(), 10);
}

#[test]
fn lists_span_several_chunks() {
    // More points than one chunk holds, on both paths (grid and tree).
    let points: Vec<[f64; 3]> = (0..3 * CHUNK + 7)
        .map(|i| [(i % 40) as f64 * 0.1, (i / 40) as f64 * 0.1, 0.0])
        .collect();
    let index = PointIndex::new(&points).unwrap();
    for radius in [0.15, 100.0] {
        let hoods = index.neighbourhoods(&points, radius, 9).unwrap();
        assert_eq!(hoods.len(), points.len());
        for (i, p) in points.iter().enumerate() {
            let (idx, d2) = hoods.of(i);
            let want = index.hybrid(p, radius, 9);
            assert_eq!(idx.len(), want.len(), "point {i}");
            assert_eq!(idx[0] as usize, i);
            for (k, &(j, d)) in want.iter().enumerate() {
                assert_eq!(d2[k], d);
                assert_eq!(dist_sq(p, &points[idx[k] as usize]), dist_sq(p, &points[j]));
            }
        }
    }
}

#[test]
fn grid_nearest_within_equals_the_trees_far_from_the_origin() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(22);
    // Coordinates 1e7 cells from the origin, where the cell coordinates round most, and
    // points on cell boundaries.
    let offset = [3.0e5, -2.0e5, 1.0e5];
    let cell = 0.03;
    let mut pts: Vec<[f64; 3]> = (0..3000)
        .map(|_| [0, 1, 2].map(|a| offset[a] + rng.random_range(0.0..1.0)))
        .collect();
    pts.extend((0..200).map(|i| [0, 1, 2].map(|a| offset[a] + cell * (i % 30) as f64)));
    let tree = PointIndex::new(&pts).unwrap();
    let grid = PointIndex::with_cells(&pts, cell).unwrap();
    for k in 0..3000 {
        let q = if k % 3 == 0 {
            pts[k].map(|v| v + cell * 0.5)
        } else {
            [0, 1, 2].map(|a| offset[a] + rng.random_range(-0.1..1.1))
        };
        for radius in [0.01, cell, 0.05, 0.2] {
            // Duplicates: the tree may name another copy of the same point.
            let (a, b) = (
                tree.nearest_within(&q, radius),
                grid.nearest_within(&q, radius),
            );
            assert_eq!(a.map(|(i, d)| (pts[i], d)), b.map(|(i, d)| (pts[i], d)));
        }
    }
}

#[test]
fn isolated_points_are_those_with_too_few_neighbours() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let mut pts = grid();
    let n_surface = pts.len();
    pts.extend((0..40).map(|_| [rng.random::<f64>() * 5.0 + 2.0, rng.random::<f64>(), 3.0]));
    let radius = 0.25;
    for min in [0, 1, 3, 8] {
        let got = isolated_points(&pts, radius, min).unwrap();
        for (i, p) in pts.iter().enumerate() {
            let others = pts
                .iter()
                .enumerate()
                .filter(|&(j, q)| j != i && dist_sq(p, q) <= radius * radius)
                .count();
            assert_eq!(got[i], others < min, "point {i}, min {min}");
        }
        if min == 3 {
            assert!(got[..n_surface].iter().all(|&g| !g));
        }
    }
    assert!(isolated_points(&[], 0.1, 3).is_err());
    assert!(isolated_points(&pts, 0.0, 3).is_err());
}

#[test]
fn bucket_sort_orders_as_the_comparison_sort() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    let r_sq = 2.5;
    for n in [1, 5, 31, 32, 33, 64, 100, 257] {
        for trial in 0..20 {
            let mut keys: Vec<u128> = (0..n)
                .map(|j| {
                    // Even spread, a cluster of equal distances, zero and the radius itself.
                    let d: f64 = match (trial + j) % 7 {
                        0 => 0.0,
                        1 => r_sq,
                        2 => 0.5,
                        _ => rng.random_range(0.0..r_sq) * if trial % 2 == 0 { 1.0 } else { 0.01 },
                    };
                    let other = u128::from(j != 0);
                    u128::from(d.to_bits()) << 64 | other << 32 | j as u128
                })
                .collect();
            let mut expected = keys.clone();
            expected.sort_unstable();
            assert_eq!(
                sort_by_distance(&mut keys, r_sq),
                &expected[..],
                "n {n} trial {trial}"
            );
        }
    }
}

#[test]
fn large_neighbourhoods_equal_the_trees() {
    // Lists of 40-100 points, which the bucket sort orders.
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
    let surface = wavy_surface(&mut rng, 4000, 0.0);
    for max_nn in [40, 100] {
        let long = assert_lists_are_the_trees(&surface, 0.08, max_nn, 7);
        assert!(long > 400, "{long} lists of 32 or more");
    }
}

#[test]
fn a_near_point_bounds_the_search_without_changing_its_answer() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    // A surface patch on a lattice (exact ties between lattice points) with duplicates.
    let mut pts: Vec<[f64; 3]> = (0..40)
        .flat_map(|i| (0..40).map(move |j| [i as f64 * 0.025, j as f64 * 0.025, 0.0]))
        .collect();
    pts.extend_from_within(..100);
    for cell in [0.01, 0.03, 0.1] {
        let grid = PointIndex::with_cells(&pts, cell).unwrap();
        for k in 0..2000 {
            let p = pts[rng.random_range(0..pts.len())];
            // Lattice midpoints (ties) and random offsets, on and off the patch.
            let q = if k % 3 == 0 {
                [p[0] + 0.0125, p[1] + 0.0125, 0.0]
            } else {
                [0, 1, 2].map(|a| p[a] + (rng.random::<f64>() - 0.5) * 0.08)
            };
            for radius in [0.02, 0.045, 0.1] {
                let plain = grid.nearest_within(&q, radius);
                // Any point as the one known near, within the radius or not, and none.
                let j = rng.random_range(0..pts.len());
                for near in [Some((j, dist_sq(&pts[j], &q))), plain, None] {
                    assert_eq!(grid.nearest_within_near(&q, radius, near), plain);
                }
            }
        }
    }
}
