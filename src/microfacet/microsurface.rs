//! The microsurface's material: what one facet does to light (specular
//! conductor with its per-channel Fresnel factor, specular dielectric,
//! Lambertian), shared by every model.

use crate::spectrum::{ChannelMask, Spectrum, MAX_CHANNELS};

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
    keep: ChannelMask,
}

impl ConductorFresnel {
    pub fn new(eta: Spectrum, k: Spectrum, channels: usize) -> Self {
        let channels = channels.clamp(1, MAX_CHANNELS);
        let mirror = (0..channels).all(|c| eta.0[c] == 0.0 && k.0[c] == 1.0);
        ConductorFresnel { eta, k, channels, mirror, keep: ChannelMask::first(channels) }
    }

    #[inline]
    pub fn eval(&self, cos_i: f64) -> Spectrum {
        if self.mirror {
            return Spectrum::ONE;
        }
        Spectrum(super::fresnel::conductor4(cos_i, &self.eta.0, &self.k.0)).masked(self.keep)
    }
}
