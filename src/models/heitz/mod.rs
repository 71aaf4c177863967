//! `model="heitz"`: the stochastic random walk of Heitz et al. 2016 on the
//! Smith microsurface, with explicit heights (`src/walk/height.rs`, which holds
//! the algorithm and its reading of the supplement); it reports the random
//! walks' MIS density (`models/mis.rs`).

use super::mis::{walk_pdf, OrderOneExit};
use super::{Call, Sampled, ScatteringModel};
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use crate::walk::height;
use glam::DVec3;

/// `model="heitz"`.
#[derive(Clone, Copy, Debug)]
pub struct Heitz;

impl ScatteringModel for Heitz {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        let v = height::eval(&call.mf, &call.surf, wi, wo, &call.walk(), &mut call.rng());
        match call.surf {
            // The dielectric walk carries one value in every channel.
            Microsurface::Dielectric { .. } => Spectrum::splat(v.0[0]),
            _ => v,
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        walk_pdf(call, OrderOneExit::HeightCorrelated, false, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled> {
        let (wo, w, order) = height::sample(&call.mf, &call.surf, wi, first, &call.walk(), &mut call.rng())?;
        let weight = if let Microsurface::Dielectric { .. } = call.surf { Spectrum::splat(w.0[0]) } else { w };
        Some(Sampled { wo, weight, order, pdf: None })
    }
}
