//! The windowed mutual check of [`super::MutualWindow`]: which scan points keep a mutual pair
//! when the check is made within overlapping cubes of the scan instead of scene-wide.

use crate::matching::NearestSources;
use std::collections::HashSet;

/// The scan rows of `rows` whose pair with their nearest model row is mutual within some cube
/// of side `side`, ascending. The cubes overlap: a grid of stride `side / 2` from the scan's
/// lowest corner, each cube two cells wide, so a point lies in 8 of them. A model row's pair
/// in a cube is its first scan row of `rows` in that cube among `candidates` (each model
/// row's nearest scan rows of the whole scan, nearest first); it is mutual when the model row
/// is that scan row's nearest (`nearest`, each scan row's nearest model rows).
pub(crate) fn windowed_mutual(
    points: &[[f64; 3]],
    rows: &[usize],
    candidates: &NearestSources,
    nearest: &NearestSources,
    side: f64,
) -> Vec<usize> {
    let mut lo = [f64::INFINITY; 3];
    for p in points {
        for (l, &v) in lo.iter_mut().zip(p) {
            *l = l.min(v);
        }
    }
    let half = side / 2.0;
    // One cell further from the lowest corner: every cube's corner cell stays at 0 or above.
    let cell =
        |p: [f64; 3]| -> [i64; 3] { [0, 1, 2].map(|d| ((p[d] - lo[d]) / half).floor() as i64 + 1) };
    let mut taking_part = vec![false; points.len()];
    for &r in rows {
        taking_part[r] = true;
    }
    let mut kept = Vec::new();
    let mut seen: HashSet<[i64; 3]> = HashSet::new();
    let k = candidates.k;
    for s in 0..candidates.source.len() / k.max(1) {
        seen.clear();
        let list = &candidates.source[s * k..(s + 1) * k];
        for &t in list.iter().filter(|&&t| taking_part[t]) {
            let c = cell(points[t]);
            let mut first = false;
            for corner in CUBE_CORNERS {
                first |= seen.insert([c[0] - corner[0], c[1] - corner[1], c[2] - corner[2]]);
            }
            if first && nearest.source[t * nearest.k] == s {
                kept.push(t);
            }
        }
    }
    kept.sort_unstable();
    kept.dedup();
    kept
}

/// The corner offsets (in cells) of the 8 cubes holding a cell.
const CUBE_CORNERS: [[i64; 3]; 8] = [
    [0, 0, 0],
    [0, 0, 1],
    [0, 1, 0],
    [0, 1, 1],
    [1, 0, 0],
    [1, 0, 1],
    [1, 1, 0],
    [1, 1, 1],
];
