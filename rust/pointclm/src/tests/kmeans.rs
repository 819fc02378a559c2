//! Unit tests of `kmeans`.

use super::*;
use rand::SeedableRng;

#[test]
fn separates_well_spaced_groups() {
    let mut data = vec![];
    let mut truth = vec![];
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for g in 0..4 {
        for _ in 0..25 {
            data.push(g as f64 * 10.0 + rng.random::<f64>());
            data.push(-(g as f64) * 10.0 + rng.random::<f64>());
            truth.push(g);
        }
    }
    let labels = kmeans(&data, 2, 4, 5, &mut ChaCha8Rng::seed_from_u64(0));
    assert_eq!(labels, relabel_by_first_appearance(&truth));
}

#[test]
fn nearest_center_is_the_plain_loop_bit_for_bit() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for (dim, k) in [(1, 1), (3, 2), (8, 8), (13, 5), (32, 31)] {
        let centers: Vec<f64> = (0..k * dim).map(|_| rng.random::<f64>() - 0.5).collect();
        let mut by_dim = vec![0.0; k * dim];
        transpose(&centers, dim, k, &mut by_dim);
        let mut dists = vec![0.0; k];
        for trial in 0..200 {
            let mut x: Vec<f64> = (0..dim).map(|_| rng.random::<f64>() - 0.5).collect();
            if trial % 7 == 0 {
                // on a centre: a zero distance and (for repeated centres) ties
                x.copy_from_slice(&centers[(trial % k) * dim..(trial % k + 1) * dim]);
            }
            let (mut bl, mut bd) = (0, f64::INFINITY);
            for c in 0..k {
                let d = dist_sq(&x, &centers[c * dim..(c + 1) * dim]);
                if d < bd {
                    (bl, bd) = (c, d);
                }
            }
            let (l, d) = nearest_center(&x, &by_dim, &mut dists);
            assert_eq!((l, d.to_bits()), (bl, bd.to_bits()), "dim {dim}, k {k}");
        }
    }
}

#[test]
fn bounded_lloyd_is_the_plain_loop_exactly() {
    // Well-separated groups (where the bounds skip most points), overlapping ones, points on
    // a grid with exact ties and duplicates, and one group split into many centres.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for case in 0..48 {
        let (dim, k, groups, spread) = match case % 6 {
            0 => (3, 4, 4, 0.05),
            1 => (8, 12, 12, 0.3),
            2 => (25, 30, 25, 0.1),
            3 => (5, 9, 3, 1.0),
            4 => (2, 16, 1, 1.0),
            _ => (40, 64, 60, 0.02),
        };
        let n = 30 + (case * 37) % 400;
        let means: Vec<f64> = (0..groups * dim)
            .map(|_| rng.random::<f64>() * 2.0 - 1.0)
            .collect();
        let mut data = Vec::with_capacity(n * dim);
        for i in 0..n {
            let g = i % groups;
            for d in 0..dim {
                let v = means[g * dim + d] + spread * (rng.random::<f64>() - 0.5);
                // Every third case on a coarse grid: many equal points and exact ties.
                data.push(if case % 3 == 0 {
                    (v * 4.0).round() / 4.0
                } else {
                    v
                });
            }
        }
        let k = k.min(n);
        let seed = 100 + case as u64;
        let seeded = plus_plus_init(&data, dim, n, k, &mut ChaCha8Rng::seed_from_u64(seed));
        let bounded = lloyd(&data, dim, n, k, seeded);
        let plain = lloyd_plain(&data, dim, n, k, &mut ChaCha8Rng::seed_from_u64(seed));
        assert_eq!(bounded.1, plain.1, "labels, case {case}");
        assert_eq!(
            bounded.0.to_bits(),
            plain.0.to_bits(),
            "inertia, case {case}"
        );
    }
}

#[test]
fn restarts_in_parallel_give_the_sequential_labels_whatever_the_threads() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    // 18,000 values: the seedings' distance updates run in parallel.
    let (n, dim, k, restarts) = (3000, 6, 7, 5);
    let data: Vec<f64> = (0..n * dim).map(|_| rng.random::<f64>()).collect();
    // The definition: seed and iterate one restart after another, keep the first best.
    let mut seq = ChaCha8Rng::seed_from_u64(5);
    let mut best: Option<(f64, Vec<usize>)> = None;
    for _ in 0..restarts {
        let seeded = plus_plus_init(&data, dim, n, k, &mut seq);
        let (inertia, labels) = lloyd(&data, dim, n, k, seeded);
        if best.as_ref().is_none_or(|(b, _)| inertia < *b) {
            best = Some((inertia, labels));
        }
    }
    let expected = relabel_by_first_appearance(&best.unwrap().1);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let got =
            pool.install(|| kmeans(&data, dim, k, restarts, &mut ChaCha8Rng::seed_from_u64(5)));
        assert_eq!(got, expected, "{threads} threads");
    }
}

#[test]
fn seeding_updates_are_the_plain_loop_whatever_the_threads() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    // Below and above the size from which the updates run in parallel, with repeated rows
    // (zero distances) and a ragged last task; from the NaN start (the first centre) and
    // from distances already lowered.
    for (n, dim) in [(40, 3), (3001, 12), (2000, 40)] {
        let mut data: Vec<f64> = (0..n * dim).map(|_| rng.random::<f64>() - 0.5).collect();
        data.copy_within(0..dim * 10, dim * 20);
        let center: Vec<f64> = data[dim * 5..dim * 6].to_vec();
        let lowered: Vec<f64> = (0..n).map(|_| rng.random::<f64>() * 0.5).collect();
        for start in [vec![f64::NAN; n], lowered] {
            let expected: Vec<f64> = start
                .iter()
                .zip(data.chunks_exact(dim))
                .map(|(d, x)| d.min(dist_sq(x, &center)))
                .collect();
            assert!(expected.iter().all(|d| d.is_finite()));
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut got = start.clone();
                pool.install(|| nearer(&mut got, &data, dim, &center));
                assert_eq!(got, expected, "n = {n}, dim = {dim}, {threads} threads");
            }
        }
    }
}
