//! The scattering models, each a small file to read beside its paper.

pub mod analytic;
pub mod auto;
pub mod heitz;
pub mod invariance;
pub mod posfree;
pub mod single;

use crate::microfacet::fresnel;
use crate::spectrum::Spectrum;

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
