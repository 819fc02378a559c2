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
