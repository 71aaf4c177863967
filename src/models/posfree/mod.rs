//! Position-free multiple scattering, Wang et al. 2022: the microsurface seen
//! as a sequence of directions, heights integrated out by the segment terms.
//!
//! | file | what |
//! |---|---|
//! | `conductor.rs` | specular conductor facets: PT with next-event estimation (eqs. 24–26), the random-walk sampler (§4.3) |
//! | `dielectric.rs` | a rough dielectric interface (vertex terms eqs. 2–3, segment terms eqs. 12–23) |
//! | `diffuse.rs` | Lambertian facets (Fig. 6 "rough diffuse") |
//!
//!
//! A path is d_0 = −ω_i, b_0, d_1, …, b_{k−1}, d_k = ω_o (eq. 1): vertex terms
//! v_j = F·D(h)/(4|cos d_j|) (eq. 2) and segment terms s_j = e_j·p_j.
//! Writing L_j = |Λ(d_j)| (so that p_j = G1_dist(−d_j) = 1/L_j), the pair
//! "p_j · e_{j+1}" of the segment model reads
//!
//! | pair p_j·e_{j+1}            | uncorrelated (eqs. 7, 8, 11) | correlated (eqs. 17, 18, 22, 23) |
//! |-----------------------------|------------------------------|----------------------------------|
//! | middle, d_{j+1} upward      | (1/L_j)·Λ/(1+Λ)              | 1/L_j − 1/(L_j+Λ)                |
//! | middle, d_{j+1} downward    | 1/L_j                        | 1/L_j                            |
//! | last (ω_o upward)           | (1/L_j)·1/(1+Λ_o)            | 1/(L_j + Λ_o)  (eq. 17 read with |Λ|) |
//!
//! with Λ = Λ(d_{j+1}). For j = 0, L_0 = |Λ(−ω_i)| = 1 + Λ(ω_i), so the first
//! order is Walter 2007 with G1·G1 (uncorrelated) or G2 = 1/(1+Λ_i+Λ_o)
//! (correlated). Sampling d_{j+1} from the visible normals of −d_j has density
//! v_j·p_j/F, so f/pdf of a path prefix is Π F_j·L_j·(p_j e_{j+1}), i.e. a
//! product of Fresnel terms and the "continue" factors of the table times L_j.
//!
//! The segment factors below are shared by every surface (a dielectric adds
//! the refraction rows of `dielectric.rs`), and so is the Russian roulette of
//! the walks (`roulette_importance`, docs/estimators.md).

pub mod conductor;
pub mod dielectric;
pub mod diffuse;

/// Height-uncorrelated (§3.3) or height-correlated (§3.4) segment terms.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Segments {
    Uncorrelated,
    Correlated,
}

impl Segments {
    /// L_j·(p_j e_{j+1}) for a middle segment going upward with Λ = Λ(d_{j+1}):
    /// the probability that the walk continues (hits the surface again).
    #[inline]
    pub fn continue_up(self, l: f64, lambda: f64) -> f64 {
        if !lambda.is_finite() {
            return 1.0;
        }
        match self {
            Segments::Uncorrelated => lambda / (1.0 + lambda),
            Segments::Correlated => lambda / (l + lambda),
        }
    }

    /// p_j·e_k for the last segment towards ω_o (upward), Λ_o = Λ(ω_o).
    #[inline]
    pub fn last(self, l: f64, lambda_o: f64) -> f64 {
        match self {
            Segments::Uncorrelated => 1.0 / (l * (1.0 + lambda_o)),
            Segments::Correlated => 1.0 / (l + lambda_o),
        }
    }
}

/// Russian roulette of the position-free walks (docs/estimators.md,
/// "Roulette and the next event"): importance, per unit throughput, of a walk
/// that has just reached a vertex whose next-event value is `nee` (without the
/// throughput) and whose last-segment factor is `last` = p_j·e_k. The walk is
/// kept with probability min(1, throughput·importance), importance =
/// max(1, gain·nee, RR_LAST_WEIGHT·last):
/// - 1: the plain roulette on the throughput, for the vertices after this one;
/// - gain·nee: the walk is kept surely while its next event would add at
///   least 1/gain, and a walk the roulette renormalises adds at most 1/gain
///   at that next event;
/// - RR_LAST_WEIGHT·last: keeps throughput·last ≤ 1/RR_LAST_WEIGHT at every
///   later vertex (for conductors), so that no next event exceeds its vertex
///   term / RR_LAST_WEIGHT whatever the roulette did before.
///
/// On the throughput alone, a steep upward continuation (Λ → 0) leaves a
/// throughput ≈ Λ/L that the roulette keeps with that probability, and the
/// survivor's next event multiplies the renormalised throughput by
/// last ≈ 1/Λ: rare calls of size ∝ 1/Λ near ω_o = n (fireflies).
#[inline]
pub(crate) fn roulette_importance(nee: f64, last: f64, gain: f64) -> f64 {
    (gain * nee).max(RR_LAST_WEIGHT * last).max(1.0)
}

/// Weight of the last-segment factor in [`roulette_importance`]: a bound for
/// the vertices the next-event term does not see; at 0.05 it changed no
/// measured variance (a safety net, not a tuning knob).
pub(crate) const RR_LAST_WEIGHT: f64 = 0.05;

use super::mis::{walk_pdf, OrderOneExit};
use super::{Call, Sampled, ScatteringModel};
use crate::config::Estimator;
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use glam::DVec3;

/// Options of one position-free walk: its segment terms and the walk's bounds.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    pub segments: Segments,
    pub walk: WalkOptions,
}

/// `model="uncorrelated"` / `"correlated"` with `estimator` PT or BDPT.
#[derive(Clone, Copy, Debug)]
pub struct PosFree {
    pub segments: Segments,
    pub estimator: Estimator,
}

impl ScatteringModel for PosFree {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        let (opts, mf, rng) = (&Options { segments: self.segments, walk: call.walk() }, &call.mf, &mut call.rng());
        match (&call.surf, self.estimator) {
            (Microsurface::Conductor(fresnel), Estimator::Pt) => conductor::eval_pt(mf, fresnel, wi, wo, opts, rng),
            (Microsurface::Conductor(fresnel), Estimator::Bdpt) => conductor::eval_bdpt(mf, fresnel, wi, wo, opts, rng),
            (&Microsurface::Dielectric { eta, radiance }, Estimator::Pt) => {
                Spectrum::splat(dielectric::eval_pt(mf, eta, radiance, wi, wo, opts, rng))
            }
            (&Microsurface::Dielectric { eta, radiance }, Estimator::Bdpt) => {
                Spectrum::splat(dielectric::eval_bdpt(mf, eta, radiance, wi, wo, opts, rng))
            }
            (&Microsurface::Diffuse { albedo }, Estimator::Pt) => diffuse::eval_pt(mf, albedo, wi, wo, opts, rng),
            (&Microsurface::Diffuse { albedo }, Estimator::Bdpt) => diffuse::eval_bdpt(mf, albedo, wi, wo, opts, rng),
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        let exit = match self.segments {
            Segments::Uncorrelated => OrderOneExit::Separable,
            Segments::Correlated => OrderOneExit::HeightCorrelated,
        };
        // The position-free walks also start below the macro surface (normal mapping).
        walk_pdf(call, exit, true, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled> {
        let (opts, mf, rng) = (&Options { segments: self.segments, walk: call.walk() }, &call.mf, &mut call.rng());
        let (wo, weight, order) = match &call.surf {
            Microsurface::Conductor(fresnel) => conductor::sample_walk(mf, fresnel, wi, first, opts, rng)?,
            &Microsurface::Dielectric { eta, radiance } => {
                let (wo, w, order) = dielectric::sample_walk(mf, eta, radiance, wi, first, opts, rng)?;
                (wo, Spectrum::splat(w), order)
            }
            &Microsurface::Diffuse { albedo } => diffuse::sample_walk(mf, albedo, wi, first, opts, rng)?,
        };
        Some(Sampled { wo, weight, order, pdf: None })
    }
}
