//! Single scattering, Walter et al. 2007, exactly as Mitsuba 3's built-in
//! `roughconductor` (`conductor.rs`) and `roughdielectric` (`dielectric.rs`)
//! compute it: the reference every multiple-scattering model reduces to at
//! order 1, and `model="single"`.

pub mod conductor;
pub mod dielectric;

use super::{Call, Sampled, ScatteringModel};
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// `model="single"`.
#[derive(Clone, Copy, Debug)]
pub struct Single;

impl ScatteringModel for Single {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        if !call.includes_order_one() {
            return Spectrum::ZERO;
        }
        match &call.surf {
            Microsurface::Conductor(fresnel) => conductor::eval(&call.mf, fresnel, wi, wo),
            &Microsurface::Dielectric { eta, radiance } => Spectrum::splat(dielectric::eval(&call.mf, eta, wi, wo, radiance).0),
            &Microsurface::Diffuse { .. } => Spectrum::ZERO,
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        match &call.surf {
            Microsurface::Conductor(_) => conductor::pdf_with(&call.mf, call.sampling, wi, wo),
            &Microsurface::Dielectric { eta, .. } => dielectric::pdf_with(&call.mf, call.sampling, eta, wi, wo),
            &Microsurface::Diffuse { .. } => 0.0,
        }
    }

    fn eval_pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> (Spectrum, f64) {
        match &call.surf {
            // The conductor shares the half vector, D and G1(ω_i) between the two.
            Microsurface::Conductor(fresnel) if call.includes_order_one() => conductor::eval_pdf(&call.mf, fresnel, call.sampling, wi, wo),
            _ => (self.eval(call, wi, wo), self.pdf(call, wi, wo)),
        }
    }

    fn sample(&self, call: &Call, wi: DVec3, (s1, u1, u2): (f64, f64, f64)) -> Option<Sampled> {
        let (wo, pdf, weight) = match &call.surf {
            Microsurface::Conductor(fresnel) => conductor::sample(&call.mf, fresnel, call.sampling, wi, u1, u2)?,
            &Microsurface::Dielectric { eta, radiance } => {
                let (wo, pdf, w, _) = dielectric::sample(&call.mf, eta, call.sampling, wi, (s1, u1, u2), radiance)?;
                (wo, pdf, Spectrum::splat(w))
            }
            &Microsurface::Diffuse { .. } => return None,
        };
        Some(Sampled { wo, weight, order: 1, pdf: Some(pdf) })
    }
}
