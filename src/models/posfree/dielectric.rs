//! Position-free multiple scattering through a rough dielectric interface,
//! Wang et al. 2022 §3.2–3.4 (vertex terms eqs. 2–3, uncorrelated segment terms
//! eqs. 12–14, height-correlated eqs. 19–23), with the readings of docs/paper-notes.md.
//!
//! **Sides and frames.** `eta` = η_int/η_ext; the exterior is above the macro
//! surface (z > 0). The walk tracks the medium the light travels in and works in
//! that medium's frame: the identity outside, the point reflection x → −x
//! inside. In its own frame every medium is "above" the microsurface, the
//! facet normals that face it have m.z > 0 and the same D (D(−m') = D(m') for
//! GGX and Beckmann, anisotropic too), and its relative IOR is η_f = η_t/η_i
//! (η outside, 1/η inside). So each vertex is the conductor vertex of
//! `posfree.rs` plus a refraction branch; a refraction switches the frame, i.e.
//! negates the travel direction d. This is the rule of docs/paper-notes.md: a direction
//! travelling outside exits upward with G1(d), inside it exits downward with
//! G1(−d); otherwise it hits the surface again.
//!
//! **Vertex terms** (current frame, w = −d_j, d = d_{j+1} before any frame switch):
//! reflection v = F·D(h)/(4|w_z|), h = (w + d)/‖w + d‖ (eq. 2, eq. 11's
//! denominator); transmission (eq. 3 with the half vector of docs/paper-notes.md)
//! v = |w·h_t||d·h_t|·η_f²(1−F)·D(h_t) / (|w_z| (w·h_t + η_f d·h_t)²),
//! h_t = −(w + η_f d)/‖·‖ oriented to the incident side (h_t.z > 0, w·h_t > 0,
//! d·h_t < 0). F = F(w·h, η_f), 1 under total internal reflection.
//!
//! **Sampling density.** With L_j = |Λ(d_j)| the projected area of w is
//! A(w) = |w_z|·L_j, so drawing m ~ D_w (full-sphere VNDF) and then reflecting
//! with probability F / refracting with probability 1 − F gives d the density
//! F·D/(4|w_z| L_j) = v·p_j (reflection) and, with Walter's Jacobian
//! η_f²|d·h|/(w·h + η_f d·h)², (1−F)·D·|w·h||d·h|η_f²/(|w_z| L_j (…)²) = v·p_j
//! (transmission), where p_j = G1_dist(−d_j) = 1/L_j (eqs. 11, 14). Hence the
//! path throughput f/pdf of a prefix is the product of the "continue" factors
//! c = L_j·(p_j·e_{j+1}) below — Fresnel cancels against the branch choice.
//!
//! **Segment factors** (Λ = Λ(d_{j+1}) of the new direction in the frame of the
//! medium it travels in, so the exit test is always "d.z > 0 in that frame"):
//!
//! | factor                              | uncorrelated (eqs. 7, 8, 12, 13) | correlated (eqs. 17, 18, 20–23)     |
//! |-------------------------------------|----------------------------------|-------------------------------------|
//! | c, reflected, going up              | Λ/(1+Λ)                          | Λ/(L+Λ)                             |
//! | c, refracted, going up (new frame)  | Λ/(1+Λ)                          | 1 − L·B(L, 1+Λ)                     |
//! | c, going down (either)              | 1                                | 1                                   |
//! | last p_j·e_k, reflection to ω_o     | 1/(L(1+Λ_o))                     | 1/(L+Λ_o)                           |
//! | last p_j·e_k, transmission to ω_o   | 1/(L(1+Λ_o))                     | B(L, 1+Λ_o)                         |
//!
//! with L = L_j and B the Beta function. The correlated column is the
//! height-resampled reading of the segment terms: given the arriving direction,
//! the vertex sits at height u = C(h) ∈ [0, 1] with density L·u^{L−1} (mass
//! 1/L = p_j before normalisation, since ∫u^{L−1} = 1/L); a reflected upward
//! direction escapes with probability u^Λ, and a refracted one, now in the
//! mirrored medium whose height CDF is 1 − u, with (1 − u)^Λ. So
//! ∫u^{L−1}u^Λ du = 1/(L+Λ) (eq. 17 with |Λ|) and ∫u^{L−1}(1−u)^Λ du =
//! B(L, 1+Λ) (eq. 20); for a first vertex from outside, L = 1 + Λ_i, this is
//! Pinel's B(1+Λ_i, 1+Λ_o) (eq. 19), and for reflection Ross's 1/(1+Λ_i+Λ_o).
//! Every c lies in [0, 1] and c = 1 − L·last, so the sampler's exit probability
//! 1 − c makes every sample weight exactly 1 (Importance mode).
//!
//! **Transport mode.** Vertex terms carry no 1/η² (Importance mode, as Wang
//! and Walter). In Radiance mode each refraction scales radiance by
//! (η_i/η_t)²; the product over a path telescopes to (η_side(ω_i)/η_side(ω_o))²,
//! i.e. Mitsuba's 1/η_r² of the macro pair, applied once at the end.
//!
//! Order 1 of `Uncorrelated` is Walter 2007 with the exact separable G1·G1
//! (G1 of each direction taken in its own medium's frame), of `Correlated`
//! with G2 = 1/(1+Λ_i+Λ_o) (reflection) or B(1+Λ_i, 1+Λ_o) (transmission).

use super::{roulette_importance, Segments};
use crate::models::WalkOptions;
use crate::walk::roulette_scalar;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{reflect, refract, Microfacet};
use crate::rng::Sampler;
use glam::DVec3;

/// ln(L·B(L, 1+Λ)) = ln Γ(L+1) + ln Γ(Λ+1) − ln Γ(L+Λ+1) (≤ 0 for L, Λ ≥ 0).
#[inline]
fn ln_l_beta(l: f64, lambda: f64) -> f64 {
    if lambda == 0.0 || l == 0.0 {
        return 0.0;
    }
    if !lambda.is_finite() || !l.is_finite() {
        return f64::NEG_INFINITY;
    }
    let v = libm::lgamma(l + 1.0) + libm::lgamma(lambda + 1.0) - libm::lgamma(l + lambda + 1.0);
    v.min(0.0)
}

/// L·B(L, 1+Λ) = Γ(L+1)Γ(Λ+1)/Γ(L+Λ+1): the probability that a direction with
/// Λ, refracted at a vertex whose arriving direction had |Λ| = L, leaves the
/// surface (height-correlated, mirrored height CDF). In [0, 1].
#[inline]
pub fn l_beta(l: f64, lambda: f64) -> f64 {
    ln_l_beta(l, lambda).exp()
}

/// Beta function B(a, b) for a, b > 0 (via ln Γ).
pub fn beta(a: f64, b: f64) -> f64 {
    (libm::lgamma(a) + libm::lgamma(b) - libm::lgamma(a + b)).exp()
}

/// Continue factor c of the table for an upward new direction with Λ > 0.
#[inline]
pub fn continue_up(seg: Segments, refracted: bool, l: f64, lambda: f64) -> f64 {
    if !lambda.is_finite() {
        return 1.0;
    }
    let c = match (seg, refracted) {
        (Segments::Uncorrelated, _) => lambda / (1.0 + lambda),
        (Segments::Correlated, false) => lambda / (l + lambda),
        (Segments::Correlated, true) => -libm::expm1(ln_l_beta(l, lambda)),
    };
    if c.is_finite() {
        c.clamp(0.0, 1.0)
    } else {
        // L = ∞ (horizontal previous direction, measure zero): the vertex sits at
        // the bottom (u → 0), the reflected direction never escapes, a refracted one always does.
        if refracted {
            0.0
        } else {
            1.0
        }
    }
}

/// Last-segment factor p_j·e_k for an exiting ω_o with Λ_o (in its medium's frame).
#[inline]
pub fn last(seg: Segments, refracted: bool, l: f64, lambda_o: f64) -> f64 {
    let v = match (seg, refracted) {
        (Segments::Uncorrelated, _) => 1.0 / (l * (1.0 + lambda_o)),
        (Segments::Correlated, false) => 1.0 / (l + lambda_o),
        (Segments::Correlated, true) => l_beta(l, lambda_o) / l,
    };
    if v.is_finite() {
        v.max(0.0)
    } else {
        0.0
    }
}

/// Reflection vertex term F·D(h)/(4|w_z|) towards o (current frame, o.z > 0).
#[inline]
pub fn vertex_reflect(mf: &Microfacet, eta_f: f64, w: DVec3, o: DVec3) -> f64 {
    let h = w + o;
    let len = h.length();
    if !(len > 0.0) {
        return 0.0;
    }
    let h = h / len;
    let cw = w.dot(h);
    if !(cw > 0.0) || !(o.dot(h) > 0.0) {
        return 0.0;
    }
    let f = dielectric_full(cw, eta_f).0;
    let v = f * mf.d(h) / (4.0 * w.z.abs());
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// Transmission vertex term (eq. 3) towards o (current frame, o.z < 0).
#[inline]
pub fn vertex_transmit(mf: &Microfacet, eta_f: f64, w: DVec3, o: DVec3) -> f64 {
    let h = -(w + eta_f * o);
    let len = h.length();
    if !(len > 0.0) || !len.is_finite() {
        return 0.0;
    }
    let mut h = h / len;
    if h.z < 0.0 {
        h = -h;
    }
    let (cw, co) = (w.dot(h), o.dot(h));
    if !(cw > 0.0) || !(co < 0.0) {
        return 0.0;
    }
    let f = dielectric_full(cw, eta_f).0;
    if !(f < 1.0) {
        return 0.0;
    }
    let denom = cw + eta_f * co;
    let v = cw * (-co) * eta_f * eta_f * (1.0 - f) * mf.d(h) / (w.z.abs() * denom * denom);
    if v.is_finite() {
        v.max(0.0)
    } else {
        0.0
    }
}

/// Walk state: direction w = −d_j in the current medium's frame, L_j, the
/// frame sign (+1 outside, −1 inside) and η_f of the current medium.
#[derive(Clone, Copy)]
struct State {
    w: DVec3,
    l: f64,
    side: f64,
    eta_f: f64,
}

impl State {
    fn new(mf: &Microfacet, eta: f64, wi: DVec3) -> State {
        let side = if wi.z > 0.0 { 1.0 } else { -1.0 };
        let w = side * wi;
        State { w, l: mf.abs_lambda(-w), side, eta_f: if side > 0.0 { eta } else { 1.0 / eta } }
    }
}

/// Outcome of one vertex: the new direction (frame already switched on a
/// refraction) and whether it was a refraction. None: no visible normal.
#[inline]
fn scatter(mf: &Microfacet, st: &mut State, u_choice: f64, u1: f64, u2: f64) -> Option<(DVec3, bool, f64)> {
    let m = mf.sample_visible(st.w, u1, u2)?;
    let cos_wm = st.w.dot(m);
    if !(cos_wm > 0.0) {
        return None;
    }
    let (f, cos_t, _eta_it, eta_ti) = dielectric_full(cos_wm, st.eta_f);
    if u_choice < f {
        Some((reflect(st.w, m), false, f))
    } else {
        let d = refract(st.w, m, cos_t, eta_ti);
        // Switch to the other medium's frame.
        st.side = -st.side;
        st.eta_f = 1.0 / st.eta_f;
        Some((-d, true, f))
    }
}

/// Radiance-mode factor (η_i/η_o)² of the macro pair (1 for reflection or Importance mode).
#[inline]
fn mode_scale(eta: f64, radiance: bool, wi: DVec3, wo_z: f64) -> f64 {
    if radiance && wi.z * wo_z < 0.0 {
        let eta_r = if wi.z > 0.0 { eta } else { 1.0 / eta };
        1.0 / (eta_r * eta_r)
    } else {
        1.0
    }
}

/// First vertex at which Russian roulette may end a path (as posfree.rs).
const RR_START: u32 = 1;

/// Gain of the next-event value in `posfree::roulette_importance` for
/// dielectrics. Larger than the conductors' because the reflection near the
/// normal is small (F ≈ 0.04 at the first vertex) against the height-chain
/// contributions of the walk; measured (GGX α ∈ {0.2, 0.5, 1}): 100 against 30
/// gains 1.2–2.7× efficiency on reflection at ω_o = n and at the mirror
/// direction, and is within ±5 % elsewhere.
pub(crate) const RR_NEE_GAIN: f64 = 100.0;

#[inline]
fn valid_inputs(eta: f64, wi: DVec3) -> bool {
    eta > 0.0 && eta.is_finite() && wi.z != 0.0 && wi.is_finite()
}

/// PT estimator with next-event estimation to ω_o at every vertex: one unbiased
/// sample of f(ω_i, ω_o)·|cos θ_o| over the orders `opts.orders`, and whether
/// the pair is a reflection (ω_i, ω_o on the same side).
pub fn eval_pt(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> (f64, bool) {
    let is_reflection = wi.z * wo.z > 0.0;
    if !valid_inputs(eta, wi) || wo.z == 0.0 || !wo.is_finite() {
        return (0.0, is_reflection);
    }
    let seg = opts.segments;
    let mut st = State::new(mf, eta, wi);
    // ω_o's Λ in the frame of the medium it exits into (upward there).
    let wo_up = if wo.z > 0.0 { wo } else { -wo };
    let lambda_o = mf.lambda(wo_up);
    let mut throughput = 1.0f64;
    let mut result = 0.0f64;
    for j in 0..opts.max_bounces {
        let order = j + 1;
        // Next-event value at this vertex (without the throughput): ω_o on the
        // walk's side is reached by reflection, otherwise by transmission.
        let o = st.side * wo; // ω_o in the current frame
        let lst = last(seg, o.z < 0.0, st.l, lambda_o);
        let v = if order >= opts.orders.0 && order <= opts.orders.1 {
            lst * if o.z > 0.0 { vertex_reflect(mf, st.eta_f, st.w, o) } else { vertex_transmit(mf, st.eta_f, st.w, o) }
        } else {
            0.0
        };
        if j >= RR_START && !roulette_scalar(&mut throughput, rng, 1.0 / roulette_importance(v, lst, RR_NEE_GAIN)) {
            break;
        }
        result += throughput * v;
        if order >= opts.orders.1 {
            break;
        }
        let u_choice = rng.next();
        let (u1, u2) = rng.next2();
        let Some((d, refracted, _f)) = scatter(mf, &mut st, u_choice, u1, u2) else { break };
        if d.z > 0.0 {
            let lambda = mf.lambda(d);
            throughput *= continue_up(seg, refracted, st.l, lambda);
            st.l = lambda;
            if !(st.l > 0.0) || !(throughput > 0.0) {
                break;
            }
        } else {
            st.l = mf.abs_lambda(d);
        }
        st.w = -d;
    }
    (result * mode_scale(eta, radiance, wi, wo.z), is_reflection)
}

/// Random-walk sampler: at each vertex m ~ D_w, reflect with probability F or
/// refract, and an upward direction (in its medium's frame) leaves with
/// probability 1 − c, so the weight is 1 (× Mitsuba's 1/η_r² for a
/// transmission in Radiance mode). `first` = (sample1, u1, u2) drives the first
/// vertex: sample1 chooses reflection when sample1 < F and, rescaled to [0, 1)
/// within the chosen branch, decides the first exit. Returns (ω_o, weight,
/// order) or None (no visible normal, or `opts.max_bounces` reached).
pub fn sample_walk(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, first: (f64, f64, f64), opts: &WalkOptions, rng: &mut Sampler) -> Option<(DVec3, f64, u32)> {
    if !valid_inputs(eta, wi) {
        return None;
    }
    let seg = opts.segments;
    let mut st = State::new(mf, eta, wi);
    for j in 0..opts.max_bounces {
        let (u_choice, u1, u2) = if j == 0 {
            first
        } else {
            let c = rng.next();
            let (a, b) = rng.next2();
            (c, a, b)
        };
        let (d, refracted, f) = scatter(mf, &mut st, u_choice, u1, u2)?;
        if d.z > 0.0 {
            let lambda = mf.lambda(d);
            let c = continue_up(seg, refracted, st.l, lambda);
            let u_exit = if j == 0 {
                // Reuse sample1: uniform again within the chosen branch.
                let u = if refracted { (u_choice - f) / (1.0 - f) } else { u_choice / f };
                if u.is_finite() {
                    u.clamp(0.0, 1.0 - f64::EPSILON / 2.0)
                } else {
                    rng.next()
                }
            } else {
                rng.next()
            };
            if u_exit >= c {
                let wo = st.side * d;
                return Some((wo, mode_scale(eta, radiance, wi, wo.z), j + 1));
            }
            st.l = lambda;
        } else {
            st.l = mf.abs_lambda(d);
        }
        st.w = -d;
    }
    None
}
