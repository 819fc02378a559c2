//! Unit tests of `ransac`.

use super::*;
use crate::testing::random_scene;
use rand::SeedableRng;

#[test]
fn finds_planted_pose_at_five_percent_inliers() {
    // 5% inliers: 1 - (1 - 0.05^3)^N needs ~37,000 hypotheses for 99%; plausibility
    // rejection skips the SVD for almost all of them.
    let scene = random_scene(400, 1, 0.05, 21);
    let members: Vec<usize> = (0..400).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let fit = ransac(&scene.corr, &members, 40_000, 1.0, 0.05, true, &mut rng).unwrap();
    let truth = &scene.poses[0];
    assert!((fit.pose.rotation - truth.rotation).abs().max() < 1e-6);
    assert!((fit.pose.translation - truth.translation).abs().max() < 1e-6);
    let planted: Vec<usize> = (0..20).collect();
    assert!(planted.iter().all(|i| fit.inliers.contains(i)));
}

#[test]
fn sampling_draws_distinct_members() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let members = [4, 8, 15];
    for _ in 0..100 {
        let mut t = sample_three(&members, &mut rng);
        t.sort();
        assert_eq!(t, [4, 8, 15]);
    }
}
