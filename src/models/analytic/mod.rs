//! Closed-form approximations of multiple scattering (no random walk): what
//! production renderers ship, compared against the walks in the evaluation.
//!
//! | file | what |
//! |---|---|
//! | `fastmsx.rs` | Fast-MSX (Rosales et al. 2023): an analytic second-bounce lobe for GGX conductors |
//! | `compensated.rs` | Turquin 2019 / Kulla & Conty 2017 energy compensation of conductors |
//! | `compensated_dielectric.rs` | the same scaling for rough dielectrics (both sides of the interface) |
//! | `dielectric_albedo.rs` | its table: E_r + E_t of `single` on a dielectric over (α, η, μ), both sides |

pub mod compensated;
pub mod compensated_dielectric;
pub mod dielectric_albedo;
pub mod fastmsx;

use super::single::{conductor as single, Single};
use super::{Call, Sampled, ScatteringModel};
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// `model="fastmsx"`: GGX conductors only (checked at construction).
#[derive(Clone, Copy, Debug)]
pub struct FastMsx;

impl ScatteringModel for FastMsx {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        match &call.surf {
            Microsurface::Conductor(fresnel) if call.includes_order_one() => fastmsx::eval(&call.mf, fresnel, wi, wo),
            _ => Spectrum::ZERO,
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        single::pdf_with(&call.mf, call.sampling, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, (_, u1, u2): (f64, f64, f64)) -> Option<Sampled> {
        let Microsurface::Conductor(fresnel) = call.surf else { return None };
        let (wo, pdf, weight) = fastmsx::sample(&call.mf, &fresnel, call.sampling, wi, u1, u2)?;
        Some(Sampled { wo, weight, order: 1, pdf: Some(pdf) })
    }
}

/// `model="compensated"`.
#[derive(Clone, Copy, Debug)]
pub struct Compensated;

impl ScatteringModel for Compensated {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        if !call.includes_order_one() {
            return Spectrum::ZERO;
        }
        match &call.surf {
            Microsurface::Conductor(fresnel) => compensated::eval(&call.mf, fresnel, wi, wo),
            &Microsurface::Dielectric { eta, radiance } => Spectrum::splat(compensated_dielectric::eval(&call.mf, eta, wi, wo, radiance)),
            &Microsurface::Diffuse { .. } => Spectrum::ZERO,
        }
    }

    /// `single`'s density: the compensation scales `single`'s value and keeps its sampler.
    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        Single.pdf(call, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, (s1, u1, u2): (f64, f64, f64)) -> Option<Sampled> {
        let (wo, pdf, weight) = match &call.surf {
            Microsurface::Conductor(fresnel) => compensated::sample(&call.mf, fresnel, call.sampling, wi, u1, u2)?,
            &Microsurface::Dielectric { eta, radiance } => {
                let (wo, pdf, w) = compensated_dielectric::sample(&call.mf, eta, call.sampling, wi, (s1, u1, u2), radiance)?;
                (wo, pdf, Spectrum::splat(w))
            }
            &Microsurface::Diffuse { .. } => return None,
        };
        Some(Sampled { wo, weight, order: 1, pdf: Some(pdf) })
    }
}
