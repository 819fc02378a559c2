use std::collections::HashMap;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use safetensors::{serialize, Dtype};

use super::LearnedDescriptor;
use crate::error::Error;
use crate::pointcloud::{estimate_normals, Orientation, PointIndex};
use crate::testing::random_rotation;

const WIDTHS: [usize; 4] = [8, 16, 12, 6];

fn metadata(neighbours: usize) -> String {
    format!(
        r#"{{"descriptor": {{"neighbours": {neighbours}, "radius_voxels": 5.0, "widths": [8, 16, 12, 6]}}}}"#
    )
}

/// Random weights of the test shape, as a safetensors file.
fn weights(seed: u64, skip: Option<&str>) -> Vec<u8> {
    let [h1, h2, h3, out] = WIDTHS;
    let shapes = [
        ("point.0", h1, 5),
        ("point.2", h2, h1),
        ("head.0", h3, 2 * h2 + 1),
        ("head.2", out, h3),
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut state: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    for (name, o, i) in shapes {
        for (part, shape) in [("weight", vec![o, i]), ("bias", vec![o])] {
            let n: usize = shape.iter().product();
            let bytes = (0..n)
                .flat_map(|_| rng.random_range(-0.5f32..0.5).to_le_bytes())
                .collect();
            state.push((format!("{name}.{part}"), shape, bytes));
        }
    }
    state.retain(|(n, _, _)| Some(n.as_str()) != skip);
    let views: HashMap<String, safetensors::tensor::TensorView<'_>> = state
        .iter()
        .map(|(n, s, b)| {
            let view = safetensors::tensor::TensorView::new(Dtype::F32, s.clone(), b).unwrap();
            (n.clone(), view)
        })
        .collect();
    serialize(&views, None).unwrap()
}

/// A bumpy sheet sampled on a jittered grid, with normals facing +z.
fn sheet(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n * n)
        .map(|k| {
            let x = (k % n) as f64 * 0.01 + rng.random_range(-0.002..0.002);
            let y = (k / n) as f64 * 0.01 + rng.random_range(-0.002..0.002);
            [x, y, 0.02 * (20.0 * x).sin() * (13.0 * y).cos()]
        })
        .collect()
}

fn described(net: &LearnedDescriptor, points: &[[f64; 3]], up: [f64; 3]) -> Vec<f64> {
    let index = PointIndex::new(points).unwrap();
    let far = [up[0] * 10.0, up[1] * 10.0, up[2] * 10.0];
    let normals = estimate_normals(points, &index, 0.02, 30, Orientation::Towards(far)).unwrap();
    let f = net.describe(points, &normals, &index, 0.01).unwrap();
    assert_eq!(f.dim(), WIDTHS[3]);
    (0..f.len()).flat_map(|i| f.row(i).to_vec()).collect()
}

#[test]
fn descriptors_are_unit_length_and_the_same_after_a_rotation() {
    let net = LearnedDescriptor::from_bytes(&weights(1, None), &metadata(16), "test").unwrap();
    let points = sheet(30, 2);
    let plain = described(&net, &points, [0.0, 0.0, 1.0]);
    for row in plain.chunks(WIDTHS[3]) {
        let norm: f64 = row.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!((norm - 1.0).abs() < 1e-5, "norm {norm}");
    }
    let r = random_rotation(&mut ChaCha8Rng::seed_from_u64(3));
    let turned: Vec<[f64; 3]> = points
        .iter()
        .map(|p| {
            let q = r * Vector3::from(*p) + Vector3::new(0.3, -1.0, 2.0);
            [q.x, q.y, q.z]
        })
        .collect();
    let up = r * Vector3::new(0.0, 0.0, 1.0);
    let rotated = described(&net, &turned, [up.x, up.y, up.z]);
    let worst = plain
        .iter()
        .zip(&rotated)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "largest change {worst}");
}

#[test]
fn descriptors_do_not_depend_on_the_number_of_threads() {
    let net = LearnedDescriptor::from_bytes(&weights(4, None), &metadata(32), "test").unwrap();
    let points = sheet(40, 5);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| described(&net, &points, [0.0, 0.0, 1.0]))
    };
    assert_eq!(run(1), run(3));
}

#[test]
fn a_bad_file_is_refused_with_the_reason() {
    let err =
        |bytes: &[u8], meta: &str| LearnedDescriptor::from_bytes(bytes, meta, "d").unwrap_err();
    assert!(matches!(
        err(&weights(1, Some("head.2.bias")), &metadata(16)),
        Error::TensorMissing { .. }
    ));
    assert!(matches!(
        err(b"junk", &metadata(16)),
        Error::WeightsMalformed { .. }
    ));
    for meta in ["{}", "not json", &metadata(0), &metadata(100_000)] {
        match err(&weights(1, None), meta) {
            Error::WeightsMalformed { reason, .. } => assert!(
                reason.contains("descriptor") || reason.contains("JSON"),
                "{reason}"
            ),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn points_without_normals_or_with_bad_values_are_refused() {
    let net = LearnedDescriptor::from_bytes(&weights(1, None), &metadata(16), "test").unwrap();
    let points = sheet(10, 1);
    let index = PointIndex::new(&points).unwrap();
    let normals = vec![[0.0, 0.0, 1.0]; points.len()];
    assert!(net.describe(&points, &normals[1..], &index, 0.01).is_err());
    assert!(net.describe(&points, &normals, &index, 0.0).is_err());
    assert!(net.describe(&points, &normals, &index, f64::NAN).is_err());
}

#[test]
fn auto_is_fpfh_for_a_mostly_planar_model_and_both_for_any_other() {
    use crate::scene::Descriptor;
    use std::sync::Arc;

    let net =
        Arc::new(LearnedDescriptor::from_bytes(&weights(6, None), &metadata(8), "test").unwrap());
    let auto = Descriptor::Auto(Arc::clone(&net));
    assert!(auto.by_shape() && auto.name() == "auto");
    assert_eq!(auto.for_model(0.9, 0.5), Descriptor::Fpfh);
    assert_eq!(auto.for_model(0.5, 0.5), Descriptor::Fpfh);
    let both = Descriptor::FpfhAndLearned(Arc::clone(&net));
    assert_eq!(auto.for_model(0.2, 0.5), both);
    // An unmeasured share is not a planar model.
    assert_eq!(auto.for_model(f64::NAN, 0.5), both);
    let learned = Descriptor::Learned(Arc::clone(&net));
    assert_eq!(learned.for_model(0.9, 0.5), learned);
    assert!(!learned.by_shape() && both.name() == "fpfh+learned");
}
