//! Position-free multiple scattering, Wang et al. 2022 (conductors), with the
//! corrected readings of docs/paper-notes.md.
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

use super::{russian_roulette_keep, vertex_numbers, ConductorFresnel, WalkOptions};
use crate::microfacet::{reflect, Microfacet};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;

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

/// First vertex at which Russian roulette may end a path (played on arrival,
/// before the vertex's next event; see [`roulette_importance`]). Roulette from
/// the first continuation on: the continue factor is small for most directions
/// at moderate roughness, and killing those walks early cut the GGX α = 0.5
/// eval time ≈ 3× for ≈ 1.3× the variance per call (measured off-specular), a
/// net efficiency gain; starting at vertex 3 spent most of the time on walks
/// that carried almost no weight.
const RR_START: u32 = 1;

/// PT estimator with next-event estimation towards ω_o at every vertex
/// (Wang eqs. 24–26). Returns one sample of f(ω_i, ω_o)·cos θ_o: Wang's vertex
/// term carries 1/(4|cos θ_i|) only, so the path integral ρ is already cosine-weighted.
///
/// The model is defined on the whole sphere of incident directions (Wang
/// 2022 §5, normal mapping): ω_i below the macro surface (a tilted shading
/// normal) starts the walk with an upward d_0 = −ω_i, whose L_0 = Λ(d_0) is
/// the projected-area factor of ω_i's visible normals there, as at any
/// vertex reached by an upward segment. ω_o must point up (light leaves
/// upward only).
pub fn eval_pt(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    if wi.z == 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    // Vertex 0: light arrives from ω_i, L_0 = |Λ(d_0)| = |Λ(−ω_i)| (1 + Λ(ω_i) for ω_i above).
    let start = PtState { w: wi, l: mf.abs_lambda(-wi), throughput: Spectrum::ONE };
    let orders = (opts.orders.0, opts.orders.1.min(opts.max_bounces));
    pt_walk(mf, fresnel, wo, mf.lambda(wo), opts.segments, start, 0, orders, RR_START, rng)
}

/// A PT walk arriving at a vertex: `w` = −d_j (where the light comes from, seen
/// from the vertex), `l` = L_j = |Λ(d_j)|, and the throughput f/pdf of the prefix.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PtState {
    pub w: DVec3,
    pub l: f64,
    pub throughput: Spectrum,
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

/// Gain of the next-event value in [`roulette_importance`] for conductors.
/// Measured (GGX α ∈ {0.2, 0.5, 1}, Cu, fixed and random pairs, efficiency
/// 1/(variance·time)): 30 within 5 % of the best gain of {10, 30, 100} in
/// every case; 10 loses up to 25 % at α = 1, 100 up to 10 % at α = 0.2.
pub(crate) const RR_NEE_GAIN: f64 = 30.0;

/// Weight of the last-segment factor in [`roulette_importance`]: a bound for
/// the vertices the next-event term does not see; at 0.05 it changed no
/// measured variance (a safety net, not a tuning knob).
pub(crate) const RR_LAST_WEIGHT: f64 = 0.05;

/// The conductor's next-event term at a vertex with w = −d_j and last-segment
/// factor `last`, without the Fresnel factor: (w·h, D(h)·last/(4|w_z|)) with h
/// the half vector of w and ω_o, or None when ω_o cannot be reached by reflection.
#[inline]
fn nee_term(mf: &Microfacet, w: DVec3, wo: DVec3, last: f64) -> Option<(f64, f64)> {
    let h = w + wo;
    let len = h.length();
    if len > 0.0 {
        let h = h / len;
        let cos_wh = w.dot(h);
        if cos_wh > 0.0 && wo.dot(h) > 0.0 {
            return Some((cos_wh, mf.d(h) * last / (4.0 * w.z.abs())));
        }
    }
    None
}

/// The PT-with-NEE walk from vertex `first_vertex` (0-based) on: at each
/// vertex ≥ `rr_start` play Russian roulette on the importance of the vertex
/// (its next-event value included), close the path towards ω_o when its order
/// is within `orders`, then sample the next direction from the visible
/// normals and multiply the Fresnel term and the continue factor. Shared by
/// `eval_pt` and the PT tail of the BDPT estimators.
#[allow(clippy::too_many_arguments)]
pub(crate) fn pt_walk(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wo: DVec3,
    lambda_o: f64,
    segments: Segments,
    state: PtState,
    first_vertex: u32,
    orders: (u32, u32),
    rr_start: u32,
    rng: &mut Sampler,
) -> Spectrum {
    let PtState { mut w, mut l, mut throughput } = state;
    let mut result = Spectrum::ZERO;
    for j in first_vertex..orders.1 {
        // L = 0 (the walk left for sure; p_j = 1/L_j would divide by zero), a
        // horizontal direction (p_j = 0), or nothing left to carry.
        if !(l > 0.0) || !l.is_finite() || !(throughput.max_value() > 0.0) {
            break;
        }
        let order = j + 1;
        let last = segments.last(l, lambda_o);
        let nee = if order >= orders.0 { nee_term(mf, w, wo, last) } else { None };
        if j >= rr_start {
            let importance = roulette_importance(nee.map_or(0.0, |(_, v)| v), last, RR_NEE_GAIN);
            if !russian_roulette_keep(&mut throughput, rng, 1.0 / importance) {
                break;
            }
        }
        // Next-event estimation: close the path towards ω_o at this vertex.
        if let Some((cos_wh, value)) = nee {
            result += throughput * fresnel.eval(cos_wh) * value;
        }
        if order >= orders.1 {
            break;
        }
        // Sample the next direction from the visible normals of w.
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(w, u1, u2) else { break };
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            break;
        }
        let d_next = reflect(w, m);
        throughput *= fresnel.eval(cos_wm);
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            throughput *= segments.continue_up(l, lambda);
            l = lambda;
        } else {
            l = mf.abs_lambda(d_next);
        }
        w = -d_next;
    }
    result
}

/// Random-walk sampler (Wang §4.3 with the exit probabilities of docs/paper-notes.md):
/// at each upward direction the walk leaves with probability 1 − continue_up,
/// so that the weight is the product of the Fresnel terms. The first vertex
/// uses the caller's (u_exit, u1, u2). Returns (ω_o, weight, order) or None.
pub fn sample_walk(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if wi.z == 0.0 {
        return None;
    }
    let mut w = wi;
    let mut l = mf.abs_lambda(-wi); // as in eval_pt: ω_i may lie below the macro surface
    let mut weight = Spectrum::ONE;
    for j in 0..opts.max_bounces {
        let (u_exit, u1, u2) = vertex_numbers(j, first, rng);
        let m = mf.sample_visible(w, u1, u2)?;
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            return None;
        }
        let d_next = reflect(w, m);
        weight *= fresnel.eval(cos_wm);
        if d_next.z > 0.0 {
            let lambda = mf.lambda(d_next);
            let p_continue = opts.segments.continue_up(l, lambda);
            if u_exit >= p_continue {
                return Some((d_next, weight, j + 1));
            }
            l = lambda;
        } else {
            l = mf.abs_lambda(d_next);
        }
        w = -d_next;
    }
    None
}
