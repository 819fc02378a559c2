use super::*;

fn tail_direct(n: usize, k: usize, p: f64) -> f64 {
    // Exact sum with f64 binomial coefficients, for small n.
    let mut total = 0.0;
    for j in k..=n {
        let mut choose = 1.0;
        for i in 0..j {
            choose *= (n - i) as f64 / (i + 1) as f64;
        }
        total += choose * p.powi(j as i32) * (1.0 - p).powi((n - j) as i32);
    }
    total
}

#[test]
fn binomial_tail_matches_direct_sum() {
    for &(n, k, p) in &[
        (10, 3, 0.2),
        (50, 10, 0.05),
        (200, 3, 0.001),
        (30, 30, 0.5),
        (40, 1, 0.3),
    ] {
        let got = 10f64.powf(log10_binomial_tail(n, k, p));
        let want = tail_direct(n, k, p);
        assert!(
            (got - want).abs() <= 1e-10 * want.max(1e-300),
            "{n} {k} {p}: {got} vs {want}"
        );
    }
}

#[test]
fn binomial_tail_edges() {
    assert_eq!(log10_binomial_tail(10, 0, 0.1), 0.0);
    assert_eq!(log10_binomial_tail(10, 11, 0.1), f64::NEG_INFINITY);
    assert_eq!(log10_binomial_tail(10, 3, 0.0), f64::NEG_INFINITY);
    // Far tails stay finite and ordered where f64 probabilities would underflow.
    let a = log10_binomial_tail(5000, 400, 1e-4);
    let b = log10_binomial_tail(5000, 500, 1e-4);
    assert!(a.is_finite() && b.is_finite() && b < a && a < -300.0);
}

#[test]
fn a_true_pose_is_significant_and_a_random_one_is_not() {
    // 1000 rows, 3 copies of 2 % each (20 inliers), the rest uniform in [0, 6)^3.
    let scene = crate::testing::random_scene(1000, 3, 0.02, 7);
    let model = NullModel::new(&scene.corr, 0.1);
    assert!(model.log10_nfa(&scene.corr, &scene.poses[0], 10) < -10.0);
    let mut nowhere = RigidTransform::identity();
    nowhere.translation.x = 100.0;
    assert!(model.log10_nfa(&scene.corr, &nowhere, 10) >= 0.0);
    // The identity puts the unit-ball sources among the targets: a few chance inliers at
    // most, never a detection.
    assert!(model.log10_nfa(&scene.corr, &RigidTransform::identity(), 10) > -1.0);
}

#[test]
fn grid_counts_equal_brute_force() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    // A spread cloud, a flat one, a single repeated point and an empty one: cells from the
    // radius, coarsened cells (tiny radius) and degenerate extents.
    let spread: Vec<[f64; 3]> = (0..500)
        .map(|_| [0, 1, 2].map(|_| rng.random_range(-2.0..3.0)))
        .collect();
    let flat: Vec<[f64; 3]> = spread.iter().map(|p| [p[0], p[1], 0.5]).collect();
    let same = vec![[1.0, 1.0, 1.0]; 50];
    let huge: Vec<[f64; 3]> = spread
        .iter()
        .map(|p| [p[0] * 6e307, p[1], -p[2] * 1e307])
        .collect();
    for (points, radius) in [
        (&spread, 0.3),
        (&spread, 1e-4),
        (&spread, 10.0),
        (&flat, 0.2),
        (&same, 0.1),
        (&vec![], 0.1),
        (&huge, 0.5),
    ] {
        let grid = UniformGrid::new(points, 2.0 * radius);
        for _ in 0..300 {
            let q = [0, 1, 2].map(|_| rng.random_range(-3.0..4.0));
            let q = if rng.random_bool(0.2) && !points.is_empty() {
                points[rng.random_range(0..points.len())]
            } else {
                q
            };
            let want = points
                .iter()
                .filter(|p| {
                    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                    d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < radius * radius
                })
                .count();
            assert_eq!(count_within(&grid, q, radius, radius * radius), want);
        }
    }
}
