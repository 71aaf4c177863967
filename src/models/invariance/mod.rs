//! The invariance principle, Cui et al. 2023 (with Bitterli & d'Eon 2022's
//! exit probability): Heitz's random walk with the microsurface heights
//! integrated out exactly by the segment term S_k.
//!
//! | file | what |
//! |---|---|
//! | `recursion.rs` | the complete S_k recursion, p_exit and its stability study, the incremental exit table of monotone (conductor) paths |
//! | `conductor.rs` | eval and sample on conductor facets |
//! | `general.rs` | the complete recursion for non-monotone paths (the diffuse microsurface) |
//! | `dielectric.rs` | heights integrated exactly up to the first refraction, Heitz's walk after it |

pub mod conductor;
pub mod dielectric;
pub mod general;
pub mod recursion;

pub use recursion::{p_exit, p_exit_error_study, p_exit_with_bound, segment_term, segment_term_monotone, MonotoneExit};

use super::mis::{walk_pdf, OrderOneExit};
use super::{Call, Sampled, ScatteringModel};
use crate::config::Estimator;
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// `model="invariance"`, with `estimator` PT or (conductors) BDPT.
#[derive(Clone, Copy, Debug)]
pub struct Invariance {
    pub estimator: Estimator,
}

impl ScatteringModel for Invariance {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        let (opts, mf, rng) = (&call.walk(), &call.mf, &mut call.rng());
        match &call.surf {
            Microsurface::Conductor(fresnel) if self.estimator == Estimator::Bdpt => conductor::eval_bdpt(mf, fresnel, wi, wo, opts, rng),
            Microsurface::Conductor(fresnel) => conductor::eval(mf, fresnel, wi, wo, opts, rng),
            &Microsurface::Dielectric { eta, radiance } => Spectrum::splat(dielectric::eval(mf, eta, radiance, wi, wo, opts, rng)),
            &Microsurface::Diffuse { .. } => general::eval(mf, &call.surf, wi, wo, opts, rng),
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        walk_pdf(call, OrderOneExit::HeightCorrelated, false, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled> {
        let (opts, mf, rng) = (&call.walk(), &call.mf, &mut call.rng());
        let (wo, weight, order) = match &call.surf {
            Microsurface::Conductor(fresnel) => conductor::sample(mf, fresnel, wi, first, opts, rng)?,
            &Microsurface::Dielectric { eta, radiance } => {
                let (wo, w, order) = dielectric::sample(mf, eta, radiance, wi, first, opts, rng)?;
                (wo, Spectrum::splat(w), order)
            }
            &Microsurface::Diffuse { .. } => general::sample(mf, &call.surf, wi, first, opts, rng)?,
        };
        Some(Sampled { wo, weight, order, pdf: None })
    }
}
