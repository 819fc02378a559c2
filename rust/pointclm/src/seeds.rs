//! Independent random streams derived from one user seed, so that every parallel task draws
//! the same numbers whatever thread runs it.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Stage tags, so that streams of different stages never coincide.
pub(crate) const STAGE_CLUSTERING: u64 = 1;
pub(crate) const STAGE_RANSAC: u64 = 2;
pub(crate) const STAGE_MATCHING: u64 = 3;
pub(crate) const STAGE_EIGEN: u64 = 4;

/// A generator for `(seed, stage, index)`; splitmix64 decorrelates nearby seeds.
pub(crate) fn stream(seed: u64, stage: u64, index: u64) -> ChaCha8Rng {
    let mut z = seed
        ^ stage.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ index.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    ChaCha8Rng::seed_from_u64(z)
}
