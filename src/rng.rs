//! Reproducible random streams without global state (pbrt-v4's LayeredBxDF
//! habit): a stream is seeded by hashing the call's inputs, the BSDF's `seed`
//! and a caller-supplied key (a per-call counter in the plugin).

use rand::{Rng, RngCore};
use rand_pcg::Pcg64Mcg;

/// A uniform number made safe for a sampler: clamped into [0, 1) (its largest
/// value the largest f64 below 1), None when it is not finite (the caller
/// chooses the replacement).
#[inline]
pub fn unit_interval(u: f64) -> Option<f64> {
    u.is_finite().then(|| u.clamp(0.0, 1.0 - f64::EPSILON / 2.0))
}

/// SplitMix64 finaliser: a bijective 64-bit mixer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Hashes a sequence of 64-bit words into one.
#[inline]
pub fn hash_words(words: &[u64]) -> u64 {
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    for &w in words {
        h = mix64(h ^ w.wrapping_add(0x9e37_79b9_7f4a_7c15));
    }
    h
}

/// A small, fast, seedable generator for the random walks.
pub struct Sampler {
    rng: Pcg64Mcg,
}

impl Sampler {
    pub fn new(seed: u64) -> Self {
        let lo = mix64(seed);
        let hi = mix64(seed ^ 0xd1b5_4a32_d192_ed03);
        Sampler { rng: Pcg64Mcg::new(((hi as u128) << 64) | lo as u128 | 1) }
    }

    /// Uniform in [0, 1). (Not an `Iterator`: the walks draw one number at a time.)
    #[inline]
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> f64 {
        (self.rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    #[inline]
    pub fn next2(&mut self) -> (f64, f64) {
        (self.next(), self.next())
    }

    pub fn gen_range(&mut self, lo: f64, hi: f64) -> f64 {
        self.rng.gen_range(lo..hi)
    }
}
