//! Registers a model in a scan of point clouds, end to end in Rust: every copy's pose.
//!
//! ```text
//! cargo run --release --example register_scan [MODEL.xyz SCAN.xyz [vx vy vz]]
//! ```
//!
//! Each file holds one point per line, `x y z` (whitespace- or comma-separated; `#` starts a
//! comment line); the optional three numbers are the position of the scan's sensor. Without
//! files: the committed bunny samples `tests/fixtures/bunny_surface.xyz` as the model, and a
//! scan of three copies of it placed and turned at known poses, which the example checks it
//! finds (exit status 1 if not).

mod common;
use common::read_points;
use std::path::PathBuf;
use std::time::Instant;

use nalgebra::{Rotation3, Vector3};
use pointclm::kabsch::RigidTransform;
use pointclm::scene::{register_point_clouds, SceneOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (model, scan, planted, viewpoint) = match args.as_slice() {
        [] => {
            let model = read_points(&root.join("tests/fixtures/bunny_surface.xyz"))?;
            let (scan, planted) = three_copies(&model);
            (model, scan, planted, None)
        }
        [m, s, rest @ ..] => {
            let view = match rest {
                [] => None,
                [x, y, z] => Some([x.parse()?, y.parse()?, z.parse()?]),
                _ => return Err("give MODEL SCAN, optionally followed by vx vy vz".into()),
            };
            let model = read_points(&PathBuf::from(m))?;
            (model, read_points(&PathBuf::from(s))?, Vec::new(), view)
        }
        _ => return Err("give MODEL SCAN [vx vy vz], or nothing for the built-in scene".into()),
    };
    let options = SceneOptions {
        viewpoint,
        ..SceneOptions::default()
    };
    let t0 = Instant::now();
    let found = register_point_clouds(&model, &scan, &options)?;
    println!(
        "{} copies in {} scan points at voxel {:.4} ({} passes, {:.0} ms)",
        found.candidates.len(),
        found.target.points.len(),
        found.voxel_size,
        found.passes.len(),
        t0.elapsed().as_secs_f64() * 1e3
    );
    for (k, c) in found.candidates.iter().enumerate() {
        let t = c.pose.translation;
        println!(
            "[{k}] confidence {:.3}  fitness {:.3}  t = ({:.3}, {:.3}, {:.3})",
            c.confidence, c.fitness, t[0], t[1], t[2]
        );
    }
    if planted.is_empty() {
        return Ok(());
    }
    let diagonal = pointclm::scene::voxel::diagonal(&model);
    let hits = planted
        .iter()
        .filter(|truth| {
            found.candidates.iter().any(|c| {
                let angle = (c.pose.rotation.transpose() * truth.rotation)
                    .trace()
                    .sub(1.0)
                    .mul(0.5)
                    .clamp(-1.0, 1.0)
                    .acos()
                    .to_degrees();
                angle < 15.0 && (c.pose.translation - truth.translation).norm() < 0.1 * diagonal
            })
        })
        .count();
    println!("{hits} of {} planted copies found", planted.len());
    if hits < planted.len() {
        std::process::exit(1);
    }
    Ok(())
}

use std::ops::{Mul, Sub};

/// Three copies of `model`, side by side, each turned about another axis.
fn three_copies(model: &[[f64; 3]]) -> (Vec<[f64; 3]>, Vec<RigidTransform>) {
    let size = pointclm::scene::voxel::diagonal(model);
    let poses: Vec<RigidTransform> = [(0.0, 0.4, 1.1), (1.0, -0.7, 0.2), (-0.5, 2.0, -0.9)]
        .iter()
        .enumerate()
        .map(|(k, &(a, b, c))| RigidTransform {
            rotation: *Rotation3::from_euler_angles(a, b, c).matrix(),
            translation: Vector3::new(1.5 * size * k as f64, 0.0, 0.0),
        })
        .collect();
    let scan = poses
        .iter()
        .flat_map(|pose| model.iter().map(move |&p| pose.apply(p)))
        .collect();
    (scan, poses)
}
