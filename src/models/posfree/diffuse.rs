//! Position-free multiple scattering on a rough *diffuse* microsurface
//! (Wang et al. 2022 Fig. 6 "rough diffuse"): Lambertian microfacets of albedo
//! a (Heitz 2016 §3.3) with the segment terms of Wang §3.3/§3.4.
//!
//! # Vertex term
//! Heitz's diffuse phase function (incident ω seen from the vertex, i.e. −d_j):
//!   p(−d_j → d_{j+1}) = (a/π) ∫ ⟨d_{j+1}, m⟩⁺ D_{−d_j}(m) dm,
//!   D_{−d_j}(m) = ⟨−d_j, m⟩⁺ D(m) / A(−d_j),   A(−d_j) = |cos d_j|·L_j,
//! L_j = |Λ(d_j)|. For specular facets Wang's vertex term times the incident
//! masking p_j = G1_dist(−d_j) = 1/L_j is exactly Heitz's phase function
//! (docs/paper-notes.md); the diffuse vertex term is defined the same way,
//!   v_j = L_j · p(−d_j → d_{j+1})
//!       = (a/π) ∫ ⟨d_{j+1}, m⟩⁺ ⟨−d_j, m⟩⁺ D(m) dm / |cos d_j|,
//! the diffuse microfacet BRDF·cos θ_o without shadowing–masking, carrying
//! 1/|cos| of the incident side only, like eq. 2. Both local masking terms
//! χ⁺(−d_j·m) (the facet is seen from where light arrives) and χ⁺(d_{j+1}·m)
//! (light leaves on the facet's front side) sit inside the m-integral.
//!
//! # Segment terms
//! Wang's e_{j+1} uses G1(d_{j+1}, m) = χ⁺(d_{j+1}·m)·G1_dist(d_{j+1}) (eq. 9)
//! and, for the correlated model, the local factors χ⁺ of both directions in
//! G2. After a Lambertian bounce d_{j+1} can point anywhere on the sphere —
//! downward into the macrosurface, or upward after arriving from above — but
//! never behind its own facet: the integrand of v_j vanishes unless
//! d_{j+1}·m > 0 and −d_j·m > 0, and on that support every χ⁺ equals one. The
//! segment terms therefore factor out of the m-integral and are the direction-
//! only pair factors of the conductor (table in `posfree.rs`):
//!   middle, d_{j+1} up:   p_j e_{j+1} = cont(L_j, Λ(d_{j+1}))/L_j
//!   middle, d_{j+1} down: p_j e_{j+1} = 1/L_j
//!   last (ω_o up):        p_{k−1} e_k = Segments::last(L_{k−1}, Λ(ω_o)).
//! Unlike a conductor (z never decreases along specular reflections), a
//! diffuse walk can go up and then down again; the pair factors above do not
//! assume monotone z.
//!
//! # Sampling weights cancel to the albedo product
//! Drawing m ~ D_{−d_j} then d_{j+1} from the cosine lobe about m gives d_{j+1}
//! the density p(−d_j → d_{j+1})/a = v_j/(a L_j). The path-prefix ratio per
//! vertex is v_j·(p_j e_{j+1})/density = a·L_j·(p_j e_{j+1}) = a·cont: with the
//! walk continuing with probability cont and otherwise leaving, the sampling
//! weight is Π a (per channel), and the exit density reproduces the last
//! factor (1 − cont = L_j·last for an upward direction, 0 for a downward one).
//! With a = 1 the walk conserves energy: albedo 1 (furnace).
//!
//! # Evaluation
//! v_j has no closed form for GGX/Beckmann. As in Heitz's stochastic phase
//! function, (a/π)⟨ω_o, m⟩⁺ with m ~ D_{−d_j} is an unbiased estimate of
//! p(−d_j → ω_o); next-event estimation reuses the normal m drawn for the
//! continuation at the same vertex (the expectation of each NEE term given the
//! past is exact, so the estimator stays unbiased).

use super::Segments;
use crate::models::WalkOptions;
use crate::walk::{cosine_about, russian_roulette, vertex_numbers};
use crate::microfacet::Microfacet;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// First vertex after which Russian roulette may end a path (as `posfree`).
const RR_START: u32 = 1;

/// PT estimator with next-event estimation of f(ω_i, ω_o)·cos θ_o for the
/// diffuse microsurface of albedo `albedo` (per channel). Orders
/// `opts.orders`, at most `opts.max_bounces` vertices, segment model
/// `opts.segments`.
pub fn eval_pt(mf: &Microfacet, albedo: Spectrum, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let seg = opts.segments;
    let lambda_o = mf.lambda(wo);
    let mut w = wi; // −d_j
    let mut l = 1.0 + mf.lambda(wi); // L_j
    let mut throughput = Spectrum::ONE;
    let mut result = Spectrum::ZERO;
    for j in 0..opts.max_bounces {
        let order = j + 1;
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(w, u1, u2) else { break };
        // NEE: v_j·last = L_j·(a/π)⟨ω_o, m⟩⁺·last(L_j, Λ_o), m ~ D_{−d_j}.
        if order >= opts.orders.0 && order <= opts.orders.1 {
            let c = wo.dot(m);
            if c > 0.0 {
                result += throughput * albedo * (c * FRAC_1_PI * l * seg.last(l, lambda_o));
            }
        }
        if order >= opts.orders.1 {
            break;
        }
        let (u3, u4) = rng.next2();
        let d_next = cosine_about(m, u3, u4);
        throughput *= albedo;
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            throughput *= seg.continue_up(l, lambda);
            l = lambda;
        } else {
            l = mf.abs_lambda(d_next);
        }
        if !(l > 0.0) || !l.is_finite() || !(throughput.max_value() > 0.0) {
            // Λ = 0 (leaves for sure) or a horizontal direction (p = 1/L = 0).
            break;
        }
        w = -d_next;
        if j + 1 >= RR_START && !russian_roulette(&mut throughput, rng) {
            break;
        }
    }
    result
}

/// Random-walk sampler: returns (ω_o, weight = Π albedo, order) or None when
/// the walk exceeds `opts.max_bounces`. The first vertex uses the caller's
/// (u_exit, u1, u2) for the exit decision and the visible normal; the
/// Lambertian direction and later vertices use `rng`.
pub fn sample_walk(
    mf: &Microfacet,
    albedo: Spectrum,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if wi.z <= 0.0 {
        return None;
    }
    let seg: Segments = opts.segments;
    let mut w = wi;
    let mut l = 1.0 + mf.lambda(wi);
    let mut weight = Spectrum::ONE;
    for j in 0..opts.max_bounces {
        let (u_exit, u1, u2) = vertex_numbers(j, first, rng);
        let m = mf.sample_visible(w, u1, u2)?;
        let (u3, u4) = rng.next2();
        let d_next = cosine_about(m, u3, u4);
        weight *= albedo;
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            let p_continue = seg.continue_up(l, lambda);
            if u_exit >= p_continue {
                return Some((d_next, weight, j + 1));
            }
            l = lambda;
        } else {
            l = mf.abs_lambda(d_next);
        }
        if !(l > 0.0) || !l.is_finite() {
            return None;
        }
        w = -d_next;
    }
    None
}
