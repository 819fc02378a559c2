//! Registers a scene of correspondences: from a text file of `N` rows
//! `sx sy sz tx ty tz` when a path is given, else a built-in planted scene.
//!
//! ```text
//! cargo run --release --example planted [correspondences.txt]
//! ```

mod common;
use common::read_rows;
use pointclm::{register, Config, Correspondences};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let rows = match std::env::args().nth(1) {
        Some(path) => read_rows(std::path::Path::new(&path))?,
        None => planted_rows(),
    };
    let corr = Correspondences::from_rows(&rows)?;
    let result = register(&corr, None, &Config::default(), 0)?;
    println!(
        "{} correspondences, {} kept after pruning, {} instances",
        corr.len(),
        result.kept.len(),
        result.instances.len()
    );
    for (k, inst) in result.instances.iter().enumerate() {
        let t = inst.pose.to_matrix();
        println!(
            "[{k}] inliers {:4}  rmse {:.4}  t = ({:.3}, {:.3}, {:.3})",
            inst.inliers.len(),
            inst.inlier_rmse,
            t[0][3],
            t[1][3],
            t[2][3]
        );
    }
    Ok(())
}

/// Three translated and rotated copies of a small point set among uniform outliers, from a
/// fixed linear congruential sequence (no extra dependencies).
fn planted_rows() -> Vec<[f64; 6]> {
    let mut state = 12345u64;
    let mut uniform = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut rows = Vec::new();
    for k in 0..3 {
        let (c, s) = ((k as f64).cos(), (k as f64).sin());
        for _ in 0..40 {
            let p = [uniform() - 0.5, uniform() - 0.5, uniform() - 0.5];
            let q = [
                c * p[0] - s * p[1] + 1.5 * k as f64,
                s * p[0] + c * p[1],
                p[2] + 1.0,
            ];
            rows.push([p[0], p[1], p[2], q[0], q[1], q[2]]);
        }
    }
    for _ in 0..880 {
        let p = [uniform() - 0.5, uniform() - 0.5, uniform() - 0.5];
        rows.push([
            p[0],
            p[1],
            p[2],
            6.0 * uniform(),
            6.0 * uniform(),
            6.0 * uniform(),
        ]);
    }
    rows
}
