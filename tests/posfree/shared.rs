//! Helpers shared by the position-free test modules.

use crate::common::{dir, Stat};
use glam::DVec3;
use msx::models::posfree::Segments;
use msx::rng::Sampler;
use msx::{Distribution, Spectrum};
use std::f64::consts::PI;
use std::time::Instant;

pub fn seg_name(s: Segments) -> &'static str {
    match s {
        Segments::Uncorrelated => "unc",
        Segments::Correlated => "cor",
    }
}

pub fn dist_name(d: Distribution) -> &'static str {
    match d {
        Distribution::Ggx => "ggx",
        Distribution::Beckmann => "beckmann",
    }
}

/// (name, ω_i, ω_o) on the upper side: mirror configuration, off-specular, grazing.
pub fn pairs() -> [(&'static str, DVec3, DVec3); 3] {
    [("mirror", dir(0.6, 0.0), dir(0.6, PI)), ("off-specular", dir(0.3, 0.0), dir(1.1, 2.0)), ("grazing", dir(1.45, 0.0), dir(1.3, PI - 0.4))]
}

/// Per-channel statistics of `n` calls of an estimator with its own stream,
/// and the time per call (ns).
pub fn run(n: usize, mut f: impl FnMut(&mut Sampler) -> Spectrum, seed: u64) -> ([Stat; 3], f64) {
    let mut rng = Sampler::new(seed);
    let mut st = [Stat::default(); 3];
    let t0 = Instant::now();
    for _ in 0..n {
        let v = f(&mut rng);
        for (c, s) in st.iter_mut().enumerate() {
            s.push(v.0[c]);
        }
    }
    (st, t0.elapsed().as_nanos() as f64 / n as f64)
}
