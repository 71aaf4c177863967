//! The scattering models, each a small file to read beside its paper.

pub mod albedo;
pub mod auto;
pub mod compensated;
pub mod compensated_dielectric;
pub mod fastmsx;
pub mod heitz;
pub mod invariance;
pub mod invariance_dielectric;
pub mod invariance_general;
pub mod posfree;
pub mod posfree_dielectric;
pub mod posfree_bdpt;
pub mod posfree_bdpt_dielectric;
pub mod posfree_bdpt_diffuse;
pub mod posfree_diffuse;
pub mod single;
pub mod single_dielectric;

use crate::microfacet::fresnel;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;

/// Russian roulette on the largest channel of a throughput that is ≤ 1 per
/// channel: returns false when the path ends, otherwise divides the
/// throughput by the survival probability (unbiased).
#[inline]
pub fn russian_roulette(throughput: &mut Spectrum, rng: &mut Sampler) -> bool {
    russian_roulette_keep(throughput, rng, 1.0)
}

/// Russian roulette that keeps a path surely while its largest channel is
/// ≥ `keep` and otherwise survives with probability max/keep (unbiased: the
/// throughput is divided by it).
#[inline]
pub fn russian_roulette_keep(throughput: &mut Spectrum, rng: &mut Sampler, keep: f64) -> bool {
    match survival(throughput.max_value() / keep, rng) {
        Some(q) => {
            *throughput *= 1.0 / q;
            true
        }
        None => false,
    }
}

/// [`russian_roulette_keep`] for a scalar throughput (≥ 0).
#[inline]
pub fn roulette_scalar(throughput: &mut f64, rng: &mut Sampler, keep: f64) -> bool {
    match survival(*throughput / keep, rng) {
        Some(q) => {
            *throughput /= q;
            true
        }
        None => false,
    }
}

/// Plays the roulette with survival probability min(1, `ratio`): the
/// probability the throughput must be divided by, or None when the path ends
/// (always for a ratio ≤ 0 or NaN).
#[inline]
fn survival(ratio: f64, rng: &mut Sampler) -> Option<f64> {
    let q = ratio.min(1.0);
    if !(q > 0.0) {
        return None;
    }
    if q < 1.0 && rng.next() >= q {
        return None;
    }
    Some(q)
}

/// The three uniform numbers (u_choice, u1, u2) of vertex `j` of a sampled
/// walk: the caller's (from Mitsuba's sample1/sample2) at the first vertex,
/// the walk's own stream after it.
#[inline]
pub fn vertex_numbers(j: u32, first: (f64, f64, f64), rng: &mut Sampler) -> (f64, f64, f64) {
    if j == 0 {
        first
    } else {
        let (a, b) = rng.next2();
        (rng.next(), a, b)
    }
}

/// Options of one evaluation.
#[derive(Clone, Copy, Debug)]
pub struct WalkOptions {
    pub segments: posfree::Segments,
    /// Maximum number of scattering events (vertices).
    pub max_bounces: u32,
    /// Scattering orders counted, 1-based inclusive (k = 1 is single scattering).
    pub orders: (u32, u32),
}


/// What a microfacet does to light (Heitz 2016 §3.2–3.4): the microsurface's
/// material, shared by every multiple-scattering model.
#[derive(Clone, Copy, Debug)]
pub enum Microsurface {
    /// Specular conductor facets, complex Fresnel per channel.
    Conductor(ConductorFresnel),
    /// Specular dielectric facets. `eta` = η_int/η_ext (> 0) of the interface;
    /// directions with z < 0 are inside (Mitsuba's roughdielectric convention).
    /// `radiance`: scale transmission by 1/η² as Mitsuba's Radiance mode does.
    Dielectric { eta: f64, radiance: bool },
    /// Lambertian facets with the given albedo (Heitz 2016 §3.3).
    Diffuse { albedo: Spectrum },
}

/// Per-channel Fresnel factor of a conductor (F = 1 fast path for the
/// perfect mirror, Mitsuba's `material="none"`).
#[derive(Clone, Copy, Debug)]
pub struct ConductorFresnel {
    pub eta: Spectrum,
    pub k: Spectrum,
    pub channels: usize,
    pub mirror: bool,
}

impl ConductorFresnel {
    pub fn new(eta: Spectrum, k: Spectrum, channels: usize) -> Self {
        let channels = channels.clamp(1, crate::spectrum::MAX_CHANNELS);
        let mirror = (0..channels).all(|c| eta.0[c] == 0.0 && k.0[c] == 1.0);
        ConductorFresnel { eta, k, channels, mirror }
    }

    #[inline]
    pub fn eval(&self, cos_i: f64) -> Spectrum {
        if self.mirror {
            return Spectrum::ONE;
        }
        let f = fresnel::conductor4(cos_i, &self.eta.0, &self.k.0);
        Spectrum(std::array::from_fn(|c| if c < self.channels { f[c] } else { 0.0 }))
    }
}
