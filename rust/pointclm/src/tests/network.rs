//! Unit tests of `network`: layers against direct f64 references, weight-file errors, and the
//! forward pass's invariances.

use std::collections::HashMap;
use std::path::PathBuf;

use faer::MatRef;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use safetensors::{serialize, Dtype};

use super::forward;
use super::layers::{
    attention_rows, exp_nonpositive, softmax_unnormalised, AttentionScratch, BatchNorm, Dense,
    Geometry, BN_EPS,
};
use super::*;
use crate::error::Error;
use crate::testing::{random_scene, with_normals};
use crate::MIN_CORRESPONDENCES;

fn shipped(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../python/pointclm/weights")
        .join(format!("{name}.safetensors"))
}

fn uniform(rng: &mut ChaCha8Rng, n: usize, lo: f64, hi: f64) -> Vec<f64> {
    (0..n)
        .map(|_| lo + (hi - lo) * rng.random::<f64>())
        .collect()
}

#[test]
fn folded_batch_norm_equals_conv_then_batch_norm() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let (rows, inp, out) = (37, 12, 9);
    let w = uniform(&mut rng, out * inp, -1.0, 1.0);
    let b = uniform(&mut rng, out, -1.0, 1.0);
    let bn = BatchNorm {
        weight: uniform(&mut rng, out, 0.5, 2.0),
        bias: uniform(&mut rng, out, -1.0, 1.0),
        mean: uniform(&mut rng, out, -0.5, 0.5),
        var: uniform(&mut rng, out, 0.01, 3.0),
    };
    let x32: Vec<f32> = uniform(&mut rng, rows * inp, -2.0, 2.0)
        .iter()
        .map(|&v| v as f32)
        .collect();
    for relu in [false, true] {
        let dense = Dense::new(&w, &b, Some(&bn));
        let mut y = vec![0.0f32; rows * out];
        dense.apply(rows, (&x32, inp), (&mut y, out), relu);
        for r in 0..rows {
            for o in 0..out {
                let z: f64 = b[o]
                    + (0..inp)
                        .map(|i| w[o * inp + i] * f64::from(x32[r * inp + i]))
                        .sum::<f64>();
                let mut want =
                    bn.weight[o] * (z - bn.mean[o]) / (bn.var[o] + BN_EPS).sqrt() + bn.bias[o];
                if relu {
                    want = want.max(0.0);
                }
                let got = f64::from(y[r * out + o]);
                assert!(
                    (got - want).abs() < 1e-5 * (1.0 + want.abs()),
                    "{got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn dense_reads_and_writes_strided_column_ranges() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let (rows, inp, out, stride) = (5, 4, 3, 10);
    let dense = Dense::new(
        &uniform(&mut rng, out * inp, -1.0, 1.0),
        &uniform(&mut rng, out, -1.0, 1.0),
        None,
    );
    let x: Vec<f32> = (0..rows * inp).map(|i| i as f32 * 0.1).collect();
    let mut dense_out = vec![0.0f32; rows * out];
    dense.apply(rows, (&x, inp), (&mut dense_out, out), false);
    // the same rows placed at column 3 of a wider matrix, output at column 6 of another
    let mut wide_x = vec![f32::NAN; rows * stride];
    for r in 0..rows {
        wide_x[r * stride + 3..r * stride + 3 + inp].copy_from_slice(&x[r * inp..(r + 1) * inp]);
    }
    let mut wide_y = vec![-7.0f32; rows * stride];
    dense.apply(
        rows,
        (&wide_x[3..], stride),
        (&mut wide_y[6..], stride),
        false,
    );
    for r in 0..rows {
        assert_eq!(
            &wide_y[r * stride + 6..r * stride + 6 + out],
            &dense_out[r * out..(r + 1) * out]
        );
        assert!(wide_y[r * stride..r * stride + 6]
            .iter()
            .all(|&v| v == -7.0));
    }
}

#[test]
fn exp_is_accurate_on_its_domain() {
    let mut worst = 0.0f64;
    for k in 0..=200_000 {
        let x = -90.0 * k as f64 / 200_000.0;
        let got = f64::from(exp_nonpositive(x as f32));
        let want = f64::from(x as f32).exp();
        if x >= -87.0 {
            worst = worst.max((got - want).abs() / want);
        } else {
            // clamped to exp(-87): negligible next to a softmax row's exp(0) = 1
            assert!(got < 1.7e-38);
        }
    }
    assert!(worst < 3e-7, "max relative error {worst}");
    assert_eq!(exp_nonpositive(0.0), 1.0);
}

#[test]
fn softmax_matches_a_direct_one() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for n in [1, 7, 8, 9, 100, 1001] {
        let z: Vec<f32> = uniform(&mut rng, n, -30.0, 30.0)
            .iter()
            .map(|&v| v as f32)
            .collect();
        let mut e = z.clone();
        let sum = softmax_unnormalised(&mut e);
        let max = z
            .iter()
            .fold(f64::NEG_INFINITY, |a, &b| a.max(f64::from(b)));
        let direct: Vec<f64> = z.iter().map(|&v| (f64::from(v) - max).exp()).collect();
        let total: f64 = direct.iter().sum();
        assert!((f64::from(sum) - total).abs() < 1e-5 * total);
        for (a, b) in e.iter().zip(&direct) {
            assert!((f64::from(*a) / f64::from(sum) - b / total).abs() < 1e-6);
        }
    }
}

/// The attention with the full N x N matrix in f64, as the torch code writes it.
fn dense_attention(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    geo: &Geometry,
    c: usize,
    scale: f64,
) -> Vec<f64> {
    let n = q.len() / c;
    let mut out = vec![0.0; n * c];
    for i in 0..n {
        let mut beta = vec![1.0f32; n];
        geo.scale_by_beta(i, &mut beta);
        let logits: Vec<f64> = (0..n)
            .map(|j| {
                let dot: f64 = (0..c)
                    .map(|t| f64::from(q[i * c + t]) * f64::from(k[j * c + t]))
                    .sum();
                f64::from(beta[j]) * dot * scale
            })
            .collect();
        let max = logits.iter().fold(f64::NEG_INFINITY, |a, &b| a.max(b));
        let e: Vec<f64> = logits.iter().map(|l| (l - max).exp()).collect();
        let s: f64 = e.iter().sum();
        for j in 0..n {
            for t in 0..c {
                out[i * c + t] += e[j] / s * f64::from(v[j * c + t]);
            }
        }
    }
    out
}

/// Queries, keys and values (`n x c` each, row-major), uniform in [-2, 2).
fn random_qkv(n: usize, c: usize, seed: u64) -> [Vec<f32>; 3] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    std::array::from_fn(|_| {
        uniform(&mut rng, n * c, -2.0, 2.0)
            .iter()
            .map(|&v| v as f32)
            .collect()
    })
}

/// The largest absolute difference between an f32 result and its f64 reference.
fn max_difference(got: &[f32], want: &[f64]) -> f64 {
    got.iter()
        .zip(want)
        .map(|(a, b)| (f64::from(*a) - b).abs())
        .fold(0.0, f64::max)
}

#[test]
fn blocked_attention_equals_the_dense_one() {
    let scene = random_scene(300, 3, 0.2, 5);
    let geo = Geometry::new(&scene.corr, 0.3);
    let n = scene.corr.len();
    let c = 16;
    let [q, k, v] = random_qkv(n, c, 4);
    let scale = 0.25;
    let want = dense_attention(&q, &k, &v, &geo, c, scale);
    for block in [1, 64, 128, 300, 512] {
        let mut got = vec![0.0f32; n * c];
        let mut scratch = AttentionScratch::default();
        for (b, out) in got.chunks_mut(block * c).enumerate() {
            let rows = out.len() / c;
            let first = b * block;
            attention_rows(
                MatRef::from_row_major_slice(&q[first * c..(first + rows) * c], rows, c),
                MatRef::from_row_major_slice(&k, n, c),
                MatRef::from_row_major_slice(&v, n, c),
                &geo,
                first,
                scale as f32,
                &mut scratch,
                out,
            );
        }
        let worst = max_difference(&got, &want);
        assert!(worst < 2e-5, "block {block}: max difference {worst}");
    }
}

#[test]
fn embeddings_are_unit_norm_and_independent_of_threads_and_blocking() {
    let net = Network::from_file(shipped("default")).unwrap();
    let scene = random_scene(700, 4, 0.1, 6);
    let par = net.embed(&scene.corr).unwrap();
    let seq = net.embed_sequential(&scene.corr).unwrap();
    assert_eq!(par, seq);
    let one = crate::pipeline::thread_pool(1)
        .unwrap()
        .install(|| net.embed(&scene.corr).unwrap());
    assert_eq!(one, par);
    assert_eq!(par.dim(), 64);
    for i in 0..par.len() {
        let norm: f64 = par.row(i).iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-9);
    }
    // other block sizes change only the rounding of the products
    let small = forward::embed(&net, &scene.corr, false, 50).unwrap();
    for i in 0..par.len() {
        for (a, b) in par.row(i).iter().zip(small.row(i)) {
            assert!((a - b).abs() < 1e-5);
        }
    }
}

#[test]
fn embedding_ignores_a_shift_of_both_clouds_through_beta_and_the_centring() {
    let net = Network::from_file(shipped("default")).unwrap();
    let scene = random_scene(200, 2, 0.3, 7);
    let shift = |p: [f64; 3], d: f64| [p[0] + d, p[1] - d, p[2] + 0.5 * d];
    let src: Vec<[f64; 3]> = (0..200)
        .map(|i| shift(scene.corr.source(i), 0.25))
        .collect();
    let dst: Vec<[f64; 3]> = (0..200)
        .map(|i| shift(scene.corr.target(i), 0.25))
        .collect();
    let moved = Correspondences::new(&src, &dst).unwrap();
    let (a, b) = (net.embed(&scene.corr).unwrap(), net.embed(&moved).unwrap());
    for i in 0..200 {
        for (x, y) in a.row(i).iter().zip(b.row(i)) {
            assert!((x - y).abs() < 1e-4);
        }
    }
}

#[test]
fn shipped_networks_load_with_their_recommended_config() {
    for (name, depth, width) in [("default", 6, 64), ("paper", 12, 128)] {
        let net = Network::from_file(shipped(name)).unwrap();
        assert_eq!(net.architecture(), Architecture::plain(depth, width, 0.05));
        let cfg = net.recommended_config();
        assert_eq!((cfg.tau_n, cfg.tau_s), (5, 0.85));
        assert_eq!(cfg.max_kept, Config::default().max_kept);
    }
}

#[test]
fn coordinates_beyond_f32_are_a_typed_error() {
    let net = Network::from_file(shipped("default")).unwrap();
    let src = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1e300, 0.0]];
    let c = Correspondences::new(&src, &src).unwrap();
    assert!(matches!(
        net.embed(&c),
        Err(Error::NonFinite { row: 2, .. })
    ));
}

/// `n` correspondences uniform in a cube of side `side` at both ends: at the network's
/// sigma_d and a side near 1, far more than 1/16 of the pairs are length-consistent.
fn uniform_correspondences(n: usize, side: f64, seed: u64) -> Correspondences {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let rows: Vec<[f64; 6]> = (0..n)
        .map(|_| std::array::from_fn(|_| rng.random_range(0.0..side)))
        .collect();
    Correspondences::from_rows(&rows).unwrap()
}

fn all_rows(f: &Features) -> Vec<f64> {
    (0..f.len()).flat_map(|i| f.row(i).to_vec()).collect()
}

#[test]
fn the_dense_attention_beyond_its_row_limit_is_refused_up_front() {
    let net = Network::from_file(shipped("default")).unwrap();
    let share = super::sparse_attention::MAX_SPARSE_SHARE;
    // many consistent pairs: only the dense attention can run, and 300 > 200 rows
    let dense = uniform_correspondences(300, 1.0, 1);
    assert!(super::sparse_attention::SparseBeta::new(
        &Geometry::new(&dense, net.architecture.sigma_d),
        false,
        share
    )
    .is_none());
    let err = forward::embed_limited(&net, &dense, true, 128, share, 200).unwrap_err();
    assert!(matches!(
        err,
        Error::TooManyForDenseAttention {
            n: 300,
            max: 200,
            share_denominator: 16,
            ..
        }
    ));
    let msg = err.to_string();
    assert!(msg.contains("at most 200 correspondences"), "{msg}");
    assert!(msg.contains("model=None"), "{msg}");
    // at the limit it runs, and gives what the unlimited pass gives
    let at_limit = forward::embed_limited(&net, &dense, true, 128, share, 300).unwrap();
    let plain = forward::embed(&net, &dense, true, 128).unwrap();
    assert_eq!(all_rows(&at_limit), all_rows(&plain));
    // few consistent pairs: the sparse attention runs whatever the row limit
    let sparse = random_scene(700, 4, 0.1, 6);
    let limited = forward::embed_limited(&net, &sparse.corr, true, 128, share, 200).unwrap();
    let plain = forward::embed(&net, &sparse.corr, true, 128).unwrap();
    assert_eq!(all_rows(&limited), all_rows(&plain));
    assert_eq!(MAX_DENSE_ATTENTION_ROWS, 32_768);
}

// ---- weight files ----

const META: &str = r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": 0.05}}"#;

/// The state dict of a depth-1, width-4 network with arbitrary values (as torch names it).
fn tiny_state() -> Vec<(String, Vec<usize>, Vec<f32>)> {
    tiny_state_for(6)
}

/// [`tiny_state`] with `channels` input channels.
fn tiny_state_for(channels: usize) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut t = Vec::new();
    let mut conv = |name: &str, out: usize, inp: usize| {
        t.push((
            format!("{name}.weight"),
            vec![out, inp, 1],
            vec![0.1; out * inp],
        ));
        t.push((format!("{name}.bias"), vec![out], vec![0.01; out]));
    };
    conv("lift", 4, channels);
    conv("pointcn.0.0", 4, 4);
    for p in ["q", "k", "v"] {
        conv(&format!("nonlocal_blocks.0.{p}"), 4, 4);
    }
    conv("nonlocal_blocks.0.message.0", 2, 4);
    conv("nonlocal_blocks.0.message.3", 2, 2);
    conv("nonlocal_blocks.0.message.6", 4, 2);
    for (bn, c) in [
        ("pointcn.0.1", 4),
        ("nonlocal_blocks.0.message.1", 2),
        ("nonlocal_blocks.0.message.4", 2),
    ] {
        t.push((format!("{bn}.weight"), vec![c], vec![1.0; c]));
        t.push((format!("{bn}.bias"), vec![c], vec![0.0; c]));
        t.push((format!("{bn}.running_mean"), vec![c], vec![0.0; c]));
        t.push((format!("{bn}.running_var"), vec![c], vec![1.0; c]));
    }
    t
}

fn to_bytes(state: &[(String, Vec<usize>, Vec<f32>)]) -> Vec<u8> {
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = state
        .iter()
        .map(|(n, s, v)| {
            (
                n.clone(),
                s.clone(),
                v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            )
        })
        .collect();
    let views: HashMap<String, safetensors::tensor::TensorView<'_>> = bytes
        .iter()
        .map(|(n, s, b)| {
            (
                n.clone(),
                safetensors::tensor::TensorView::new(Dtype::F32, s.clone(), b).unwrap(),
            )
        })
        .collect();
    serialize(&views, None).unwrap()
}

#[test]
fn a_tiny_network_loads_and_embeds() {
    let net = Network::from_bytes(&to_bytes(&tiny_state()), META, "tiny").unwrap();
    let scene = random_scene(50, 1, 0.5, 8);
    let f = net.embed(&scene.corr).unwrap();
    assert_eq!((f.len(), f.dim()), (50, 4));
    assert_eq!(net.recommended_config(), Config::default());
}

#[test]
fn missing_files_are_weights_not_found() {
    let dir = std::env::temp_dir().join(format!("pointclm-net-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let st = dir.join("m.safetensors");
    let err = Network::from_file(&st).unwrap_err();
    assert!(
        matches!(err, Error::WeightsNotFound { ref path, .. } if path.ends_with("m.safetensors"))
    );
    std::fs::write(&st, to_bytes(&tiny_state())).unwrap();
    let err = Network::from_file(&st).unwrap_err();
    assert!(matches!(err, Error::WeightsNotFound { ref path, .. } if path.ends_with("m.json")));
    std::fs::write(dir.join("m.json"), META).unwrap();
    assert!(Network::from_file(&st).is_ok());
    std::fs::write(&st, b"not a safetensors file").unwrap();
    assert!(matches!(
        Network::from_file(&st),
        Err(Error::WeightsMalformed { .. })
    ));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_metadata_is_malformed() {
    let bytes = to_bytes(&tiny_state());
    for meta in [
        "{",
        "{}",
        r#"{"architecture": {"depth": 1, "width": 5, "sigma_d": 0.05}}"#,
        r#"{"architecture": {"depth": 0, "width": 4, "sigma_d": 0.05}}"#,
        r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": -1}}"#,
        r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": 0.05, "heads": 2}}"#,
        r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": 0.05}, "recommended_config": {"tau_n": -1}}"#,
        r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": 0.05}, "recommended_config": {"tau_q": 1}}"#,
        r#"{"architecture": {"depth": 1, "width": 4, "sigma_d": 0.05}, "recommended_config": {"inlier_threshold": -1}}"#,
    ] {
        match Network::from_bytes(&bytes, meta, "x") {
            Err(Error::WeightsMalformed { .. }) => {}
            other => panic!("{meta}: {other:?}"),
        }
    }
}

#[test]
fn tensors_that_do_not_match_the_architecture_are_typed_errors() {
    let state = tiny_state();
    // missing
    let fewer: Vec<_> = state
        .iter()
        .filter(|(n, _, _)| n != "nonlocal_blocks.0.k.weight")
        .cloned()
        .collect();
    // The tensor count is checked against the architecture before any tensor is read.
    let err = Network::from_bytes(&to_bytes(&fewer), META, "x").unwrap_err();
    assert!(
        matches!(
            err,
            Error::WeightsMalformed { .. } | Error::TensorMissing { .. }
        ),
        "{err:?}"
    );
    // wrong shape: the metadata says width 6
    let meta6 = r#"{"architecture": {"depth": 1, "width": 6, "sigma_d": 0.05}}"#;
    let err = Network::from_bytes(&to_bytes(&state), meta6, "x").unwrap_err();
    assert_eq!(
        err,
        Error::TensorShape {
            path: "x".into(),
            name: "lift.weight".into(),
            expected: vec![6, 6, 1],
            got: vec![4, 6, 1]
        }
    );
    // an extra block the metadata does not declare
    let mut more = state.clone();
    more.push(("nonlocal_blocks.1.q.bias".into(), vec![4], vec![0.0; 4]));
    let err = Network::from_bytes(&to_bytes(&more), META, "x").unwrap_err();
    assert!(
        matches!(err, Error::WeightsMalformed { ref reason, .. } if reason.contains("nonlocal_blocks.1.q.bias"))
    );
    // non-finite values, negative variance
    let mut nan = state.clone();
    nan[0].2[0] = f32::NAN;
    let err = Network::from_bytes(&to_bytes(&nan), META, "x").unwrap_err();
    assert!(matches!(err, Error::WeightsMalformed { .. }));
    let mut neg = state.clone();
    let var = neg
        .iter_mut()
        .find(|(n, _, _)| n == "pointcn.0.1.running_var")
        .unwrap();
    var.2[1] = -1.0;
    let err = Network::from_bytes(&to_bytes(&neg), META, "x").unwrap_err();
    assert!(matches!(err, Error::WeightsMalformed { .. }));
    // a step counter of BatchNorm is allowed
    let mut counted = state;
    counted.push(("pointcn.0.1.num_batches_tracked".into(), vec![], vec![0.0]));
    assert!(Network::from_bytes(&to_bytes(&counted), META, "x").is_ok());
}

/// The committed scene of the `register_file` example: rows, and the true poses from its
/// header.
fn fixture_scene() -> (Correspondences, Vec<[f64; 12]>) {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/fixtures/scene_seed0.txt");
    let text = std::fs::read_to_string(path).unwrap();
    let mut rows = Vec::new();
    let mut poses = Vec::new();
    for line in text.lines() {
        let nums =
            |s: &str| -> Vec<f64> { s.split_whitespace().map(|v| v.parse().unwrap()).collect() };
        if let Some(rest) = line.strip_prefix("# pose ") {
            let v = nums(rest.split_once(':').unwrap().1);
            poses.push(<[f64; 12]>::try_from(v).unwrap());
        } else if !line.starts_with('#') {
            rows.push(<[f64; 6]>::try_from(nums(line)).unwrap());
        }
    }
    (Correspondences::from_rows(&rows).unwrap(), poses)
}

#[test]
fn the_shipped_network_registers_the_fixture_scene() {
    let (corr, truth) = fixture_scene();
    assert_eq!((corr.len(), truth.len()), (1000, 5));
    let net = Network::from_file(shipped("default")).unwrap();
    let reg = crate::register_with_network(&corr, &net, &net.recommended_config(), 0).unwrap();
    assert_eq!(reg.instances.len(), 5);
    assert!(reg.timings.embedding > 0.0);
    for t in &truth {
        let found = reg.instances.iter().any(|inst| {
            let m = inst.pose.to_matrix();
            let dt = (0..3)
                .map(|r| (m[r][3] - t[4 * r + 3]).powi(2))
                .sum::<f64>()
                .sqrt();
            let dr = (0..3)
                .flat_map(|r| (0..3).map(move |c| (r, c)))
                .map(|(r, c)| (m[r][c] - t[4 * r + c]).abs())
                .fold(0.0, f64::max);
            dt < 0.05 && dr < 0.1
        });
        assert!(found, "true pose {t:?} not found");
    }
    // the batch gives the same, whatever the threads
    let scenes = vec![corr.clone(), corr];
    for threads in [1, 2] {
        let batch = crate::register_batch_with_network(
            &scenes,
            &net,
            &net.recommended_config(),
            0,
            threads,
        )
        .unwrap();
        for r in batch {
            let r = r.unwrap();
            assert_eq!(r.instances, reg.instances);
            assert_eq!(r.labels, reg.labels);
        }
    }
}

#[test]
fn sparse_attention_equals_the_dense_one() {
    use super::sparse_attention::{attention_rows_sparse, SparseBeta, Strided};
    // A tight sigma_d, so that few pairs are consistent (the sparse path's use), and a
    // loose one with most pairs consistent (none at all outside S for some rows).
    for (sigma, seed) in [(0.05, 7), (0.3, 8), (50.0, 9)] {
        let scene = random_scene(300, 3, 0.2, seed);
        let geo = Geometry::new(&scene.corr, sigma);
        let n = scene.corr.len();
        let c = 16;
        let [q, k, v] = random_qkv(n, c, seed);
        let scale = 0.25;
        let want = dense_attention(&q, &k, &v, &geo, c, scale);
        // The share limit is the forward pass's choice: build the pairs at any share.
        let sparse = SparseBeta::new(&geo, false, 1.0).unwrap();
        let view = |data| Strided {
            data,
            offset: 0,
            stride: c,
            width: c,
        };
        let total = view(&v).column_sums(n);
        let mut got = vec![0.0f32; n * c];
        for (b, out) in got.chunks_mut(64 * c).enumerate() {
            let first = b * 64;
            let rows = out.len() / c;
            let qb = view(&q[first * c..(first + rows) * c]);
            attention_rows_sparse(
                qb,
                (view(&k), view(&v)),
                &total,
                &sparse,
                (first, n, scale as f32),
                out,
            );
        }
        let worst = max_difference(&got, &want);
        assert!(worst < 2e-5, "sigma {sigma}: max difference {worst}");
    }
}

#[test]
fn the_sparse_forward_pass_matches_the_dense_one() {
    let net = Network::from_file(shipped("default")).unwrap();
    // Few consistent pairs at the network's sigma_d: the sparse attention runs.
    let scene = random_scene(700, 4, 0.1, 6);
    let geo = Geometry::new(&scene.corr, net.architecture.sigma_d);
    let share = super::sparse_attention::MAX_SPARSE_SHARE;
    assert!(super::sparse_attention::SparseBeta::new(&geo, false, share).is_some());
    let sparse = forward::embed(&net, &scene.corr, false, 128).unwrap();
    let dense = forward::embed_with(&net, &scene.corr, false, 128, 0.0).unwrap();
    let mut worst = 0.0f64;
    for i in 0..sparse.len() {
        for (a, b) in sparse.row(i).iter().zip(dense.row(i)) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst < 1e-4, "max difference {worst}");
}

// ---- inputs beyond the coordinates ----

/// The metadata of the tiny network with `inputs` (a JSON list) and `normal_tolerance`.
fn meta_with(inputs: &str, tolerance: &str) -> String {
    format!(
        r#"{{"architecture": {{"depth": 1, "width": 4, "sigma_d": 0.05, "inputs": {inputs}, "normal_tolerance": {tolerance}}}}}"#
    )
}

/// [`tiny_state_for`] with the convolutions' weights and biases drawn uniformly in
/// [-1, 1), so that every input channel moves the embedding.
fn random_state(channels: usize, seed: u64) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut state = tiny_state_for(channels);
    for (name, _, values) in &mut state {
        if !name.contains(".1.") && !name.contains(".4.") {
            for v in values.iter_mut() {
                *v = rng.random_range(-1.0..1.0);
            }
        }
    }
    state
}

/// `c` with the descriptor similarities `0.1 + 0.9 (i mod 7) / 6`.
fn with_some_similarity(c: Correspondences) -> Correspondences {
    let values: Vec<f64> = (0..c.len()).map(|i| 0.1 + 0.15 * (i % 7) as f64).collect();
    c.with_similarity(&values).unwrap()
}

#[test]
fn inputs_are_read_from_the_metadata() {
    for (inputs, channels, want) in [
        (r#"["normals", "similarity"]"#, 13, (true, true)),
        (r#"["similarity", "normals"]"#, 13, (true, true)),
        (r#"["normals"]"#, 12, (true, false)),
        (r#"["similarity"]"#, 7, (false, true)),
        ("[]", 6, (false, false)),
    ] {
        let meta = meta_with(inputs, "0.25");
        let net = Network::from_bytes(&to_bytes(&tiny_state_for(channels)), &meta, "x").unwrap();
        let a = net.architecture();
        assert_eq!((a.inputs.normals, a.inputs.similarity), want, "{inputs}");
        assert_eq!((a.input_channels(), a.normal_tolerance), (channels, 0.25));
        // the lift must read exactly the declared channels
        let err = Network::from_bytes(&to_bytes(&tiny_state()), &meta, "x");
        if channels != 6 {
            assert!(
                matches!(err, Err(Error::TensorShape { ref name, ref expected, .. })
                    if name == "lift.weight" && expected == &[4, channels, 1]),
                "{err:?}"
            );
        }
    }
    assert_eq!(
        Inputs {
            normals: true,
            similarity: true
        }
        .names(),
        ["normals", "similarity"]
    );
    // a plain file (no inputs) has the default tolerance
    let plain = Network::from_bytes(&to_bytes(&tiny_state()), META, "x").unwrap();
    assert_eq!(plain.architecture(), Architecture::plain(1, 4, 0.05));
    assert_eq!(plain.architecture().normal_tolerance, 0.5);
}

#[test]
fn bad_inputs_in_the_metadata_are_malformed_and_named() {
    let bytes = to_bytes(&tiny_state_for(12));
    for (inputs, tolerance, named) in [
        (r#"["normals", "colour"]"#, "0.5", "colour"),
        (r#"["normals", "normals"]"#, "0.5", "twice"),
        (r#""normals""#, "0.5", "list"),
        (r#"[3]"#, "0.5", "3"),
        (r#"["normals"]"#, "0", "normal_tolerance"),
        (r#"["normals"]"#, "2.5", "normal_tolerance"),
        (r#"["normals"]"#, r#""wide""#, "normal_tolerance"),
    ] {
        match Network::from_bytes(&bytes, &meta_with(inputs, tolerance), "x") {
            Err(Error::WeightsMalformed { reason, .. }) => {
                assert!(reason.contains(named), "{inputs}: {reason}")
            }
            other => panic!("{inputs}, {tolerance}: {other:?}"),
        }
    }
}

#[test]
fn a_missing_input_is_a_typed_error_that_says_how_to_give_it() {
    let meta = meta_with(r#"["normals", "similarity"]"#, "0.5");
    let net = Network::from_bytes(&to_bytes(&random_state(13, 1)), &meta, "x").unwrap();
    let scene = random_scene(60, 2, 0.3, 11);
    let err = net.embed(&scene.corr).unwrap_err();
    assert!(matches!(
        err,
        Error::MissingInput {
            input: "normals",
            ..
        }
    ));
    assert!(err.to_string().contains("with_normals"), "{err}");
    let normals = with_normals(&scene, 12);
    let err = net.embed(&normals).unwrap_err();
    assert!(matches!(
        err,
        Error::MissingInput {
            input: "similarity",
            ..
        }
    ));
    assert!(err.to_string().contains("similarity="), "{err}");
    let err = net.embed(&with_some_similarity(scene.corr.clone()));
    assert!(matches!(
        err,
        Err(Error::MissingInput {
            input: "normals",
            ..
        })
    ));
    let both = with_some_similarity(normals);
    let f = net.embed(&both).unwrap();
    assert_eq!((f.len(), f.dim()), (60, 4));
    // every input moves the embedding
    let other = with_some_similarity(with_normals(&scene, 13));
    assert_ne!(net.embed(&other).unwrap(), f);
    let values: Vec<f64> = (0..60).map(|i| 1.0 - 0.01 * i as f64).collect();
    let resimilar = both.clone().with_similarity(&values).unwrap();
    assert_ne!(net.embed(&resimilar).unwrap(), f);
}

#[test]
fn inputs_a_network_does_not_read_are_ignored() {
    let net = Network::from_file(shipped("default")).unwrap();
    let scene = random_scene(300, 3, 0.2, 14);
    let extra = with_some_similarity(with_normals(&scene, 15));
    assert_eq!(net.embed(&extra).unwrap(), net.embed(&scene.corr).unwrap());
    let meta = meta_with(r#"["similarity"]"#, "0.5");
    let similar = Network::from_bytes(&to_bytes(&random_state(7, 2)), &meta, "x").unwrap();
    let no_normals = with_some_similarity(scene.corr.clone());
    assert_eq!(
        similar.embed(&extra).unwrap(),
        similar.embed(&no_normals).unwrap()
    );
}

/// `beta` of every pair from `geo`, row-major.
fn beta_matrix(geo: &Geometry) -> Vec<f32> {
    let n = geo.len();
    let mut beta = vec![1.0f32; n * n];
    for (i, row) in beta.chunks_exact_mut(n).enumerate() {
        geo.scale_by_beta(i, row);
    }
    beta
}

#[test]
fn the_normal_term_of_beta_is_symmetric_and_equals_the_core_one() {
    let scene = random_scene(240, 2, 0.3, 16);
    let c = with_normals(&scene, 17);
    let n = c.len();
    let (ns, nt): (Vec<_>, Vec<_>) = (0..n).map(|i| c.normals(i).unwrap()).unzip();
    for (sigma, tol) in [(0.05, 0.5), (0.3, 0.3), (0.3, 0.1)] {
        let geo = Geometry::new(&c, sigma).with_normals(c.pair_normals().unwrap(), sigma, tol);
        let got = beta_matrix(&geo);
        let core = scene.corr.clone().with_normals(&ns, &nt, tol).unwrap();
        let want = crate::consistency::spatial_consistency(&core, sigma).unwrap();
        let plain = beta_matrix(&Geometry::new(&c, sigma));
        let mut worst = 0.0f64;
        let mut cut = 0;
        for i in 0..n {
            for j in 0..n {
                assert_eq!(got[i * n + j], got[j * n + i], "({i}, {j})");
                worst = worst.max((f64::from(got[i * n + j]) - want[i * n + j]).abs());
                cut += usize::from(got[i * n + j] < 0.5 * plain[i * n + j]);
            }
        }
        // f32 coordinates (up to ~6, rounded by 3e-7) move a length difference by ~1e-6 and
        // the length term by up to 2 / sigma times that: 4e-5 at sigma = 0.05 (measured 6e-6)
        assert!(
            worst < 4e-5,
            "sigma {sigma}, tol {tol}: max difference {worst}"
        );
        assert!(
            cut > 100,
            "sigma {sigma}, tol {tol}: the normal term cut {cut} pairs"
        );
    }
}

#[test]
fn the_sparse_forward_pass_with_normals_matches_the_dense_one() {
    let meta = meta_with(r#"["normals", "similarity"]"#, "0.5");
    let net = Network::from_bytes(&to_bytes(&random_state(13, 3)), &meta, "x").unwrap();
    let scene = random_scene(500, 3, 0.15, 18);
    let c = with_some_similarity(with_normals(&scene, 19));
    let sparse = forward::embed(&net, &c, false, 128).unwrap();
    let dense = forward::embed_with(&net, &c, false, 128, 0.0).unwrap();
    let parallel = net.embed(&c).unwrap();
    assert_eq!(parallel, sparse);
    let mut worst = 0.0f64;
    for i in 0..sparse.len() {
        for (a, b) in sparse.row(i).iter().zip(dense.row(i)) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(worst < 1e-4, "max difference {worst}");
}

// ---- per-scene normalization ----

/// The metadata of the tiny network with `"normalization": <value>`.
fn meta_normalized(value: &str) -> String {
    format!(
        r#"{{"architecture": {{"depth": 1, "width": 4, "sigma_d": 0.05, "normalization": {value}}}}}"#
    )
}

/// [`random_state`] with the BatchNorms' weights, biases and running statistics random too
/// (`stats_seed` draws the running statistics alone).
fn random_bn_state(seed: u64, stats_seed: u64) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut stats = ChaCha8Rng::seed_from_u64(stats_seed);
    let mut state = random_state(6, seed);
    for (name, _, values) in &mut state {
        for v in values.iter_mut() {
            if name.ends_with(".1.weight") || name.ends_with(".4.weight") {
                *v = rng.random_range(0.5..1.5);
            } else if name.ends_with(".1.bias") || name.ends_with(".4.bias") {
                *v = rng.random_range(-0.5..0.5);
            } else if name.ends_with("running_mean") {
                *v = stats.random_range(-1.0..1.0);
            } else if name.ends_with("running_var") {
                *v = stats.random_range(0.2..2.0);
            }
        }
    }
    state
}

fn scene_net(state: &[(String, Vec<usize>, Vec<f32>)]) -> Network {
    Network::from_bytes(&to_bytes(state), &meta_normalized(r#""scene""#), "x").unwrap()
}

fn max_feature_difference(a: &Features, b: &Features) -> f64 {
    (0..a.len())
        .flat_map(|i| a.row(i).iter().zip(b.row(i)).map(|(x, y)| (x - y).abs()))
        .fold(0.0, f64::max)
}

#[test]
fn normalization_is_read_from_the_metadata() {
    let bytes = to_bytes(&tiny_state());
    for (value, want) in [
        (r#""scene""#, Normalization::Scene),
        (r#""running""#, Normalization::Running),
    ] {
        let net = Network::from_bytes(&bytes, &meta_normalized(value), "x").unwrap();
        assert_eq!(net.architecture().normalization, want);
    }
    let plain = Network::from_bytes(&bytes, META, "x").unwrap();
    assert_eq!(plain.architecture().normalization, Normalization::Running);
    assert_eq!(
        Architecture::plain(1, 4, 0.05).normalization,
        Normalization::Running
    );
    assert_eq!(
        (Normalization::Running.name(), Normalization::Scene.name()),
        ("running", "scene")
    );
    for (value, named) in [
        (r#""batch""#, "batch"),
        ("3", "normalization"),
        ("null", "null"),
    ] {
        match Network::from_bytes(&bytes, &meta_normalized(value), "x") {
            Err(Error::WeightsMalformed { reason, .. }) => {
                assert!(reason.contains(named), "{value}: {reason}")
            }
            other => panic!("{value}: {other:?}"),
        }
    }
}

#[test]
fn scene_normalization_ignores_running_statistics_and_shifts_before_each_batch_norm() {
    let scene = random_scene(300, 3, 0.3, 21);
    let state = random_bn_state(3, 4);
    let net = scene_net(&state);
    let f = net.embed(&scene.corr).unwrap();
    // other running statistics: unused, so bit-identical
    assert_eq!(
        scene_net(&random_bn_state(3, 5))
            .embed(&scene.corr)
            .unwrap(),
        f
    );
    // Each BatchNorm subtracts its input's mean, so shifting the bias of the convolution
    // before it changes nothing but rounding. (Scaling that convolution would change the
    // output through eps, noticeably in channels of small variance.)
    let mut moved = state.clone();
    for (name, _, values) in &mut moved {
        let before_bn = ["pointcn.0.0.", "message.0.", "message.3."];
        if before_bn.iter().any(|p| name.contains(p)) && name.ends_with("bias") {
            values.iter_mut().for_each(|v| *v += 0.7);
        }
    }
    let shifted = scene_net(&moved).embed(&scene.corr).unwrap();
    let worst = max_feature_difference(&f, &shifted);
    assert!(worst < 1e-4, "max difference {worst}");
    // with running statistics the same change moves the embedding
    let running = |s: &[_]| {
        let net = Network::from_bytes(&to_bytes(s), META, "x").unwrap();
        net.embed(&scene.corr).unwrap()
    };
    let moved_running = max_feature_difference(&running(&state), &running(&moved));
    assert!(moved_running > 1e-2, "{moved_running}");
    assert!(max_feature_difference(&running(&state), &f) > 1e-2);
}

#[test]
fn scene_normalization_is_independent_of_threads_and_of_the_attention_kind() {
    let net = scene_net(&random_bn_state(6, 7));
    // more rows than one block, and few consistent pairs: the sparse attention runs
    let scene = random_scene(700, 4, 0.1, 6);
    let par = net.embed(&scene.corr).unwrap();
    assert_eq!(net.embed_sequential(&scene.corr).unwrap(), par);
    for threads in [1, 3] {
        let pool = crate::pipeline::thread_pool(threads).unwrap();
        assert_eq!(pool.install(|| net.embed(&scene.corr).unwrap()), par);
    }
    let dense = forward::embed_with(&net, &scene.corr, true, 128, 0.0).unwrap();
    let worst = max_feature_difference(&par, &dense);
    assert!(worst < 1e-4, "max difference {worst}");
    for i in 0..par.len() {
        let norm: f64 = par.row(i).iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-9, "row {i}: {norm}");
    }
    // the smallest scene embeds
    let small = random_scene(MIN_CORRESPONDENCES, 1, 1.0, 8);
    let f = net.embed(&small.corr).unwrap();
    assert!((0..f.len()).all(|i| f.row(i).iter().all(|v| v.is_finite())));
}

#[test]
fn channel_statistics_of_no_row_one_row_and_many() {
    use super::scene_norm::channel_stats;
    let (stride, cols) = (10, (3, 4, 10));
    assert_eq!(
        channel_stats(&[], cols, 128, true),
        (vec![0.0; 4], vec![0.0; 4])
    );
    // one row: its values, variance 0, and the BatchNorm gives its bias
    let row: Vec<f32> = (0..stride).map(|k| k as f32 * 0.37 - 1.0).collect();
    let (mean, var) = channel_stats(&row, cols, 128, true);
    assert_eq!(
        mean,
        row[3..7].iter().map(|&v| f64::from(v)).collect::<Vec<_>>()
    );
    assert_eq!(var, vec![0.0; 4]);
    let norm = layers::SceneNorm {
        gamma: vec![1.5, 0.5, 2.0, 1.0],
        beta: vec![0.25, -0.5, 1.0, 0.0],
    };
    let mut y = [9.0f32; 4];
    norm.with_stats(&mean, &var)
        .relu(1, (&row[3..], stride), (&mut y, 4));
    assert_eq!(y, [0.25, 0.0, 1.0, 0.0]);
    // many rows: the direct two-pass statistics, whatever the threads
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let n = 1000;
    let m: Vec<f32> = uniform(&mut rng, n * stride, 50.0, 51.0)
        .iter()
        .map(|&v| v as f32)
        .collect();
    let stats = channel_stats(&m, cols, 128, true);
    assert_eq!(channel_stats(&m, cols, 128, false), stats);
    let one = crate::pipeline::thread_pool(1).unwrap();
    assert_eq!(one.install(|| channel_stats(&m, cols, 128, true)), stats);
    for c in 0..4 {
        let x: Vec<f64> = m
            .chunks_exact(stride)
            .map(|r| f64::from(r[3 + c]))
            .collect();
        let mu = x.iter().sum::<f64>() / n as f64;
        let var = x.iter().map(|v| (v - mu) * (v - mu)).sum::<f64>() / n as f64;
        assert!((stats.0[c] - mu).abs() < 1e-12 && (stats.1[c] - var).abs() < 1e-12);
        assert!((var - 1.0 / 12.0).abs() < 0.01, "{var}");
    }
    // normalised to f32 precision although the mean is ~175 standard deviations
    let norm = layers::SceneNorm {
        gamma: vec![1.0; 4],
        beta: vec![4.0; 4],
    };
    let mut y = vec![0.0f32; n * 4];
    norm.with_stats(&stats.0, &stats.1)
        .relu(n, (&m[3..], stride), (&mut y, 4));
    for (r, got) in y.chunks_exact(4).enumerate() {
        for (c, &g) in got.iter().enumerate() {
            let x = f64::from(m[r * stride + 3 + c]);
            let want = (x - stats.0[c]) / (stats.1[c] + BN_EPS).sqrt() + 4.0;
            assert!((f64::from(g) - want).abs() < 2e-6, "{g} {want}");
        }
    }
}
