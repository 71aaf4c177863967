//! The scattering models, each a small file to read beside its paper.

pub mod posfree;
pub mod single;

use crate::microfacet::fresnel;
use crate::spectrum::Spectrum;

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
        let mut out = Spectrum::ZERO;
        for c in 0..self.channels {
            out.0[c] = fresnel::conductor(cos_i, self.eta.0[c], self.k.0[c]);
        }
        out
    }
}
