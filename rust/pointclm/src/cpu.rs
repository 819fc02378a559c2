//! What the CPU offers beyond the baseline a wheel is built for (x86-64 with SSE2).

/// Whether the CPU runs 8-lane f32 vectors (AVX2). The hot loops that profit (pruning's row
/// test, descriptor matching's nearest-row sweep) have an AVX2 build chosen by this at run
/// time; without FMA, so both builds compute the same values.
pub(crate) fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}
