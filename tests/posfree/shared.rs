//! Helpers shared by the position-free test modules.

use crate::common::{dir, Checker, Stat};
use glam::DVec3;
use msx::models::posfree::Segments;
use msx::rng::Sampler;
use msx::{Distribution, Microfacet, Spectrum};
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

/// The surfaces of the conductor and diffuse BDPT checks, in their order:
/// (segment model, distribution, α, the microsurface) for both segment models
/// × GGX, Beckmann × α ∈ {0.5, 1}.
pub fn bdpt_surfaces() -> Vec<(Segments, Distribution, f64, Microfacet)> {
    let mut v = Vec::new();
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        for dist in [Distribution::Ggx, Distribution::Beckmann] {
            for alpha in [0.5, 1.0] {
                v.push((seg, dist, alpha, Microfacet::new(dist, alpha, alpha)));
            }
        }
    }
    v
}

/// (name, ω_i, ω_o) on the upper side: mirror configuration, off-specular, grazing.
pub fn pairs() -> [(&'static str, DVec3, DVec3); 3] {
    [("mirror", dir(0.6, 0.0), dir(0.6, PI)), ("off-specular", dir(0.3, 0.0), dir(1.1, 2.0)), ("grazing", dir(1.45, 0.0), dir(1.3, PI - 0.4))]
}

/// Per-channel statistics of `n` calls of an estimator with its own stream,
/// and the time per call (ns).
pub fn run(n: usize, mut f: impl FnMut(&mut Sampler) -> Spectrum, seed: u64) -> ([Stat; 3], f64) {
    let mut st = [Stat::default(); 3];
    let ns = timed(n, seed, |rng| {
        let v = f(rng);
        for (c, s) in st.iter_mut().enumerate() {
            s.push(v.0[c]);
        }
    });
    (st, ns)
}

/// bdpt against pt at one configuration: `n` calls of each on its own stream
/// (seeds `seed` and `seed + 1`), equal per channel in `channels` (labelled
/// `label` ch c).
pub fn check_bdpt_equals_pt(
    ck: &mut Checker,
    label: &str,
    channels: &[usize],
    n: usize,
    seed: u64,
    pt: impl FnMut(&mut Sampler) -> Spectrum,
    bdpt: impl FnMut(&mut Sampler) -> Spectrum,
) {
    let (pt, _) = run(n, pt, seed);
    let (bd, _) = run(n, bdpt, seed + 1);
    for &c in channels {
        ck.close(&format!("{label} ch{c}"), bd[c].est(), pt[c].est(), 0.0, 1e-12);
    }
}

/// [`run`] for an estimator of one value (the dielectric's).
pub fn run_scalar(n: usize, mut f: impl FnMut(&mut Sampler) -> f64, seed: u64) -> (Stat, f64) {
    let mut st = Stat::default();
    let ns = timed(n, seed, |rng| st.push(f(rng)));
    (st, ns)
}

/// `n` calls of `call` on the stream of `seed`; the time per call (ns).
fn timed(n: usize, seed: u64, mut call: impl FnMut(&mut Sampler)) -> f64 {
    let mut rng = Sampler::new(seed);
    let t0 = Instant::now();
    for _ in 0..n {
        call(&mut rng);
    }
    t0.elapsed().as_nanos() as f64 / n as f64
}

/// The columns of a row of the variance-and-time tables of pt against bdpt:
/// variance per call of each (`var`), ns per call of each (`ns`), the variance
/// ratio pt/bdpt and the efficiency ratio (var·time) pt/bdpt.
pub fn cost_columns(var: (f64, f64), ns: (f64, f64)) -> String {
    let ((vp, vb), (t_pt, t_bd)) = (var, ns);
    format!("{vp:>11.3e} {vb:>11.3e} {t_pt:>7.0} {t_bd:>7.0} {:>6.2} {:>6.2}", vp / vb, (vp * t_pt) / (vb * t_bd))
}
