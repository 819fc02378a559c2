//! Registers a scene read from a text file with a trained embedding network (PointCLM with
//! the learned features), entirely in Rust.
//!
//! ```text
//! cargo run --release --example register_file [correspondences.txt [weights.safetensors]]
//! ```
//!
//! The file holds one correspondence per line, `sx sy sz tx ty tz` (whitespace- or
//! comma-separated; `#` starts a comment line). Defaults: the committed scene
//! `tests/fixtures/scene_seed0.txt` (its header lists the 5 true poses) and the shipped
//! weights `python/pointclm/weights/default.safetensors` (with the `.json` beside them).

mod common;
use common::read_rows;
use std::path::PathBuf;
use std::time::Instant;

use pointclm::network::Network;
use pointclm::{register_with_network, Correspondences};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut args = std::env::args().skip(1);
    let scene = args.next().map_or_else(
        || root.join("tests/fixtures/scene_seed0.txt"),
        PathBuf::from,
    );
    let weights = args.next().map_or_else(
        || root.join("python/pointclm/weights/default.safetensors"),
        PathBuf::from,
    );

    let scene = scene.canonicalize().unwrap_or(scene);
    let corr = Correspondences::from_rows(&read_rows(&scene)?)?;
    let network = Network::from_file(&weights)?;
    let config = network.recommended_config();
    let t0 = Instant::now();
    let result = register_with_network(&corr, &network, &config, 0)?;
    println!(
        "{}: {} correspondences, {} kept, {} instances in {:.1} ms (embedding {:.1} ms)",
        scene.display(),
        corr.len(),
        result.kept.len(),
        result.instances.len(),
        t0.elapsed().as_secs_f64() * 1e3,
        result.timings.embedding * 1e3,
    );
    for (k, inst) in result.instances.iter().enumerate() {
        let t = inst.pose.to_matrix();
        let angle = ((t[0][0] + t[1][1] + t[2][2] - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos();
        println!(
            "[{k}] inliers {:3}  rmse {:.4}  rotation {:6.2} deg  t = ({:.3}, {:.3}, {:.3})",
            inst.inliers.len(),
            inst.inlier_rmse,
            angle.to_degrees(),
            t[0][3],
            t[1][3],
            t[2][3]
        );
    }
    Ok(())
}
