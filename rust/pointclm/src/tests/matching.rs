use super::*;

fn features(rows: &[Vec<f64>]) -> Features {
    let dim = rows[0].len();
    Features::new(rows.iter().flatten().copied().collect(), dim).unwrap()
}

fn pseudo_random(n: usize, dim: usize, salt: u64) -> Vec<Vec<f64>> {
    (0..n)
        .map(|i| {
            (0..dim)
                .map(|j| {
                    let x = (i as u64 * 2654435761 + j as u64 * 40503 + salt) % 10007;
                    x as f64 / 100.0
                })
                .collect()
        })
        .collect()
}

#[test]
fn nearest_rows_equal_brute_force() {
    let src = pseudo_random(300, 33, 1);
    let tgt = pseudo_random(517, 33, 2);
    let (idx, d2) = nearest_rows(&features(&tgt), &features(&src), 1);
    for (t, row) in tgt.iter().enumerate() {
        let dist = |s: &Vec<f64>| {
            row.iter()
                .zip(s)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
        };
        let best = src.iter().map(dist).fold(f64::INFINITY, f64::min);
        assert!((d2[t] - best).abs() <= 1e-9 * best.max(1.0));
        assert!((dist(&src[idx[t]]) - best).abs() <= 1e-9 * best.max(1.0));
    }
}

#[test]
fn exact_copies_match_themselves_most_salient_first() {
    let src = pseudo_random(100, 8, 3);
    let mut tgt = pseudo_random(50, 8, 4);
    tgt.extend(src[..20].iter().cloned());
    let cfg = MatchingConfig {
        top_k: 20,
        mutual: false,
        k: 1,
        n_samples: None,
    };
    let m = match_features(&features(&src), &features(&tgt), &cfg, 0).unwrap();
    assert_eq!(m.len(), 20);
    for k in 0..20 {
        assert_eq!(m.distance[k], 0.0);
        assert_eq!(m.source[k], m.target[k] - 50);
    }
}

#[test]
fn mutual_filter_and_sampling() {
    let src = pseudo_random(200, 33, 5);
    let tgt = pseudo_random(400, 33, 6);
    let (s, t) = (features(&src), features(&tgt));
    let all = MatchingConfig {
        top_k: usize::MAX,
        mutual: false,
        k: 1,
        n_samples: None,
    };
    let m = match_features(&s, &t, &all, 0).unwrap();
    assert_eq!(m.len(), 400);
    assert!(m.distance.windows(2).all(|w| w[0] <= w[1]));
    let mutual = match_features(
        &s,
        &t,
        &MatchingConfig {
            mutual: true,
            ..all
        },
        0,
    )
    .unwrap();
    assert!(mutual.len() < 400 && !mutual.is_empty());
    let (tgt_of_src, _) = nearest_rows(&s, &t, 1);
    for k in 0..mutual.len() {
        assert_eq!(tgt_of_src[mutual.source[k]], mutual.target[k]);
    }
    let cfg = MatchingConfig {
        top_k: 300,
        mutual: false,
        k: 1,
        n_samples: Some(100),
    };
    let a = match_features(&s, &t, &cfg, 7).unwrap();
    let b = match_features(&s, &t, &cfg, 7).unwrap();
    let c = match_features(&s, &t, &cfg, 8).unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert_eq!(a.len(), 100);
    // Sampled from the 300 most salient.
    let cut = m.distance[299];
    assert!(a.distance.iter().all(|&d| d <= cut));
}

#[test]
fn same_result_on_any_pool() {
    let src = pseudo_random(300, 33, 9);
    let tgt = pseudo_random(1000, 33, 10);
    let (s, t) = (features(&src), features(&tgt));
    let cfg = MatchingConfig::default();
    let one = crate::pipeline::thread_pool(1)
        .unwrap()
        .install(|| match_features(&s, &t, &cfg, 3).unwrap());
    let two = crate::pipeline::thread_pool(2)
        .unwrap()
        .install(|| match_features(&s, &t, &cfg, 3).unwrap());
    assert_eq!(one, two);
}

#[test]
fn bad_inputs_are_typed_errors() {
    let a = features(&pseudo_random(10, 4, 1));
    let b = features(&pseudo_random(10, 5, 1));
    let cfg = MatchingConfig::default();
    assert!(matches!(
        match_features(&a, &b, &cfg, 0),
        Err(Error::LengthMismatch { .. })
    ));
    let empty = Features::new(vec![], 4).unwrap();
    assert!(matches!(
        match_features(&empty, &a, &cfg, 0),
        Err(Error::TooFewPoints { .. })
    ));
    for bad in [
        MatchingConfig { top_k: 0, ..cfg },
        MatchingConfig {
            n_samples: Some(0),
            ..cfg
        },
    ] {
        assert!(matches!(
            match_features(&a, &a, &bad, 0),
            Err(Error::InvalidParameter { .. })
        ));
    }
}

#[test]
fn k_nearest_rows_equal_brute_force() {
    let src = pseudo_random(200, 33, 12);
    let tgt = pseudo_random(150, 33, 13);
    let k = 4;
    let (idx, d2) = nearest_rows(&features(&tgt), &features(&src), k);
    assert_eq!(idx.len(), 150 * k);
    for (t, row) in tgt.iter().enumerate() {
        let mut all: Vec<(f64, usize)> = src
            .iter()
            .enumerate()
            .map(|(j, s)| (row.iter().zip(s).map(|(a, b)| (a - b) * (a - b)).sum(), j))
            .collect();
        all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        for r in 0..k {
            let (want, _) = all[r];
            assert!((d2[t * k + r] - want).abs() <= 1e-9 * want.max(1.0));
        }
        assert!(d2[t * k..(t + 1) * k].windows(2).all(|w| w[0] <= w[1]));
    }
}

#[test]
fn k_one_is_nearest_matching_and_k_adds_candidates() {
    let src = pseudo_random(120, 33, 14);
    let tgt = pseudo_random(300, 33, 15);
    let (s, t) = (features(&src), features(&tgt));
    let base = MatchingConfig {
        top_k: usize::MAX,
        mutual: false,
        k: 1,
        n_samples: None,
    };
    let one = match_features(&s, &t, &base, 0).unwrap();
    let three = match_features(&s, &t, &MatchingConfig { k: 3, ..base }, 0).unwrap();
    assert_eq!(one.len(), 300);
    assert_eq!(three.len(), 900);
    assert!(three.distance.windows(2).all(|w| w[0] <= w[1]));
    // Every nearest match is among the k = 3 candidates, and each target has 3 distinct ones.
    let pairs: std::collections::HashSet<(usize, usize)> = three
        .source
        .iter()
        .copied()
        .zip(three.target.iter().copied())
        .collect();
    assert_eq!(pairs.len(), 900);
    for m in 0..one.len() {
        assert!(pairs.contains(&(one.source[m], one.target[m])));
    }
    // k larger than the source set is clamped.
    let all = match_features(&s, &t, &MatchingConfig { k: 1000, ..base }, 0).unwrap();
    assert_eq!(all.len(), 120 * 300);
    // Mutual with k: each kept pair is in both k-nearest lists.
    let mutual = match_features(
        &s,
        &t,
        &MatchingConfig {
            k: 3,
            mutual: true,
            ..base
        },
        0,
    )
    .unwrap();
    let (tgt_of_src, _) = nearest_rows(&s, &t, 3);
    assert!(!mutual.is_empty() && mutual.len() < 900);
    for m in 0..mutual.len() {
        let sr = mutual.source[m];
        assert!(tgt_of_src[sr * 3..sr * 3 + 3].contains(&mutual.target[m]));
    }
    let bad = MatchingConfig { k: 0, ..base };
    assert!(matches!(
        match_features(&s, &t, &bad, 0),
        Err(Error::InvalidParameter { .. })
    ));
}

#[test]
fn near_ties_below_f32_resolution_are_ranked_exactly() {
    // Base rows that differ from the query by less than f32 can tell at this magnitude: the
    // f32 screen keeps them all and the f64 distances order them.
    let dim = 33;
    let query: Vec<f64> = (0..dim).map(|j| 50.0 + j as f64).collect();
    let base: Vec<Vec<f64>> = [3e-6, 1e-6, 2e-6, 0.0, 1e-6]
        .iter()
        .map(|&off| query.iter().map(|v| v + off).collect())
        .collect();
    let (idx, d2) = nearest_rows(&features(&[query]), &features(&base), 5);
    assert_eq!(idx, vec![3, 1, 4, 2, 0]);
    assert!(d2.windows(2).all(|w| w[0] <= w[1]));
}

#[test]
fn identical_rows_rank_by_index_and_huge_descriptors_still_match() {
    let flat = vec![vec![10.0; 4]; 50];
    let (idx, _) = nearest_rows(&features(&[vec![10.0; 4]]), &features(&flat), 3);
    assert_eq!(idx, vec![0, 1, 2]);
    // Entries beyond f32's range take the f64 path.
    let huge = vec![vec![1e30, 0.0], vec![2e30, 0.0], vec![-1e30, 0.0]];
    let (idx, d2) = nearest_rows(&features(&[vec![1.9e30, 0.0]]), &features(&huge), 3);
    assert_eq!(idx, vec![1, 0, 2]);
    assert!(d2[0] < d2[1] && d2[1] < d2[2]);
}

#[test]
fn given_nearest_sources_give_the_same_matches_on_any_subset() {
    let src = features(&pseudo_random(120, 33, 5));
    let all = pseudo_random(300, 33, 6);
    let nearest = nearest_sources(&src, &features(&all), 2).unwrap();
    let rows: Vec<usize> = (0..300).filter(|r| r % 3 != 1).collect();
    let subset = features(&rows.iter().map(|&r| all[r].clone()).collect::<Vec<_>>());
    let given = NearestSources {
        k: nearest.k,
        source: rows
            .iter()
            .flat_map(|&r| nearest.source[2 * r..2 * r + 2].to_vec())
            .collect(),
        dist2: rows
            .iter()
            .flat_map(|&r| nearest.dist2[2 * r..2 * r + 2].to_vec())
            .collect(),
    };
    for mutual in [false, true] {
        let cfg = MatchingConfig {
            top_k: 150,
            mutual,
            k: 2,
            n_samples: Some(60),
        };
        let direct = match_features(&src, &subset, &cfg, 7).unwrap();
        let reused = match_features_given(&src, &subset, &given, &cfg, 7).unwrap();
        assert_eq!(direct, reused);
    }
}

#[test]
fn given_nearest_sources_are_checked() {
    let src = features(&pseudo_random(10, 4, 1));
    let tgt = features(&pseudo_random(6, 4, 2));
    let cfg = MatchingConfig {
        k: 1,
        ..MatchingConfig::default()
    };
    let good = nearest_sources(&src, &tgt, 1).unwrap();
    assert!(match_features_given(&src, &tgt, &good, &cfg, 0).is_ok());
    let wrong_k = nearest_sources(&src, &tgt, 2).unwrap();
    assert!(matches!(
        match_features_given(&src, &tgt, &wrong_k, &cfg, 0),
        Err(Error::InvalidParameter {
            name: "nearest",
            ..
        })
    ));
    let mut short = good.clone();
    short.source.pop();
    assert!(matches!(
        match_features_given(&src, &tgt, &short, &cfg, 0),
        Err(Error::LengthMismatch { .. })
    ));
    let mut outside = good.clone();
    outside.source[3] = 10;
    assert!(matches!(
        match_features_given(&src, &tgt, &outside, &cfg, 0),
        Err(Error::InvalidParameter {
            name: "nearest",
            ..
        })
    ));
    let mut nan = good;
    nan.dist2[4] = f64::NAN;
    assert!(matches!(
        match_features_given(&src, &tgt, &nan, &cfg, 0),
        Err(Error::NonFinite { row: 4, .. })
    ));
}

#[test]
fn the_nearest_row_fast_path_equals_the_general_ranking() {
    // k = 1 takes `nearest_one`; the first of k = 2 comes from `nearest_k`.
    let (base, queries) = tied_rows(700, 50, 30, 400, 40, 9);
    let (b, q) = (features(&base), features(&queries));
    let (one, d_one) = nearest_rows(&q, &b, 1);
    let (two, d_two) = nearest_rows(&q, &b, 2);
    for i in 0..queries.len() {
        assert_eq!(one[i], two[2 * i], "query {i}");
        assert_eq!(d_one[i], d_two[2 * i], "query {i}");
    }
}

/// `n` base rows with the first `copies` duplicated and the first `nudged` nearly duplicated
/// (ties, lowest row first), and `m` queries followed by the first `own` base rows.
fn tied_rows(
    n: usize,
    copies: usize,
    nudged: usize,
    m: usize,
    own: usize,
    salt: u64,
) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
    let mut base = pseudo_random(n, 33, salt);
    let copied: Vec<Vec<f64>> = base[..copies].to_vec();
    base.extend(copied);
    let near: Vec<Vec<f64>> = base[..nudged]
        .iter()
        .map(|r| r.iter().map(|v| v * (1.0 + 1e-12)).collect())
        .collect();
    base.extend(near);
    let mut queries = pseudo_random(m, 33, salt + 1);
    queries.extend(base[..own].iter().cloned());
    (base, queries)
}

#[test]
fn the_k_nearest_fast_path_equals_the_general_ranking() {
    // k from 2 to all rows; the general sweep is `rank_query` over the f64 screen.
    let (base, queries) = tied_rows(500, 40, 25, 300, 30, 21);
    let (b, q) = (features(&base), features(&queries));
    for k in [2, 5, 64, base.len()] {
        let (fast, d_fast) = nearest_rows(&q, &b, k);
        let (general, d_general) = screened_rows::<f64>(&q, &b, k);
        assert_eq!(fast, general, "k {k}");
        assert_eq!(d_fast, d_general, "k {k}");
    }
}

#[test]
fn mutual_nearest_equals_both_searches_with_ties() {
    // Small integer descriptors: many exactly equal distances and duplicate rows, so every
    // tie rule of the two-way search is exercised.
    let rows = |n: usize, salt: u64| -> Vec<Vec<f64>> {
        (0..n)
            .map(|i| {
                (0..4)
                    .map(|j| ((i as u64 * 7919 + j as u64 * 104729 + salt) % 5) as f64)
                    .collect()
            })
            .collect()
    };
    type Rows = Vec<Vec<f64>>;
    let mut cases: Vec<(Rows, Rows)> = [
        (40, 300, 1),
        (300, 40, 2),
        (64, 64, 3),
        (1, 9, 4),
        (9, 1, 5),
    ]
    .into_iter()
    .map(|(ns, nt, salt)| (rows(ns, salt), rows(nt, salt + 10)))
    .collect();
    // Target row 1 is the closest of the rows that chose source row 1, but the lower target row 0 (which
    // chose source row 0 at a tie) is as near to it, so source row 1's nearest is row 0.
    cases.push((vec![vec![0.0], vec![2.0]], vec![vec![1.0], vec![3.0]]));
    for (src, tgt) in cases {
        let (ns, nt) = (src.len(), tgt.len());
        let (src, tgt) = (features(&src), features(&tgt));
        let (s_of_t, d2) = nearest_rows(&tgt, &src, 1);
        let (t_of_s, _) = nearest_rows(&src, &tgt, 1);
        let fast = mutual_nearest(&src, &tgt, &s_of_t, &d2);
        for p in 0..nt {
            assert_eq!(fast[p], t_of_s[s_of_t[p]] == p, "row {p} of {ns} x {nt}");
        }
        let cfg = MatchingConfig {
            top_k: usize::MAX,
            mutual: true,
            k: 1,
            n_samples: None,
        };
        let m = match_features(&src, &tgt, &cfg, 0).unwrap();
        assert_eq!(m.len(), fast.iter().filter(|&&b| b).count());
    }
}
