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
//! `conductor.rs` plus a refraction branch; a refraction switches the frame, i.e.
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

use super::{roulette_importance, Options, Segments};
use crate::microfacet::dielectric::{eta_seen, radiance_scale, reflect_or_refract, valid_ior};
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::Microfacet;
use crate::rng::{unit_interval, Sampler};
use crate::walk::{bdpt, roulette_scalar, RR_START};
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
        State { w, l: mf.abs_lambda(-w), side, eta_f: eta_seen(eta, side > 0.0) }
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
    let (d, refracted, f) = reflect_or_refract(st.w, m, cos_wm, st.eta_f, u_choice);
    if !refracted {
        return Some((d, false, f));
    }
    // Switch to the other medium's frame.
    st.side = -st.side;
    st.eta_f = 1.0 / st.eta_f;
    Some((-d, true, f))
}

/// Gain of the next-event value in `posfree::roulette_importance` for
/// dielectrics. Larger than the conductors' because the reflection near the
/// normal is small (F ≈ 0.04 at the first vertex) against the height-chain
/// contributions of the walk; measured (GGX α ∈ {0.2, 0.5, 1}): 100 against 30
/// gains 1.2–2.7× efficiency on reflection at ω_o = n and at the mirror
/// direction, and is within ±5 % elsewhere.
pub(crate) const RR_NEE_GAIN: f64 = 100.0;

#[inline]
fn valid_inputs(eta: f64, wi: DVec3) -> bool {
    valid_ior(eta) && wi.z != 0.0 && wi.is_finite()
}

/// The next event at a vertex the walk reached in `st`, without the
/// throughput: (last·v, last) with ω_o on the walk's side reached by
/// reflection, otherwise by transmission (Λ_o = `lambda_o` in ω_o's frame).
#[inline]
fn next_event(mf: &Microfacet, seg: Segments, st: &State, wo: DVec3, lambda_o: f64) -> (f64, f64) {
    let o = st.side * wo; // ω_o in the current frame
    let lst = last(seg, o.z < 0.0, st.l, lambda_o);
    (lst * vertex_towards(mf, st, o), lst)
}

/// The vertex term towards o (current frame): reflection above, transmission below.
#[inline]
fn vertex_towards(mf: &Microfacet, st: &State, o: DVec3) -> f64 {
    if o.z > 0.0 {
        vertex_reflect(mf, st.eta_f, st.w, o)
    } else {
        vertex_transmit(mf, st.eta_f, st.w, o)
    }
}

/// ω_o's Λ in the frame of the medium it exits into (upward there).
#[inline]
fn lambda_out(mf: &Microfacet, wo: DVec3) -> f64 {
    mf.lambda(if wo.z > 0.0 { wo } else { -wo })
}

/// PT estimator with next-event estimation to ω_o at every vertex: one unbiased
/// sample of f(ω_i, ω_o)·|cos θ_o| over the orders `opts.walk.orders`.
pub fn eval_pt(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> f64 {
    if !valid_inputs(eta, wi) || wo.z == 0.0 || !wo.is_finite() {
        return 0.0;
    }
    let orders = opts.walk.clamped_orders();
    let result = pt_walk(mf, opts.segments, wo, State::new(mf, eta, wi), 1.0, 0, orders, RR_START, rng);
    result * radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0)
}

/// The PT-with-NEE walk from vertex `first_vertex` (0-based) on, the light
/// arriving in `st` with throughput `throughput`: at each vertex close the
/// path towards ω_o (by reflection on ω_o's side, by transmission across),
/// play Russian roulette from vertex `rr_start` on, then scatter. Orders
/// `orders` (the upper one within the bounce cap). No Radiance-mode 1/η² (the
/// caller applies it once). Shared by `eval_pt` and the BDPT's tail.
#[allow(clippy::too_many_arguments)]
fn pt_walk(
    mf: &Microfacet,
    seg: Segments,
    wo: DVec3,
    mut st: State,
    mut throughput: f64,
    first_vertex: u32,
    orders: (u32, u32),
    rr_start: u32,
    rng: &mut Sampler,
) -> f64 {
    let lambda_o = lambda_out(mf, wo);
    let mut result = 0.0f64;
    for j in first_vertex..orders.1 {
        let order = j + 1;
        let (v, lst) = next_event(mf, seg, &st, wo, lambda_o);
        let v = if order >= orders.0 { v } else { 0.0 };
        if j >= rr_start && !roulette_scalar(&mut throughput, rng, 1.0 / roulette_importance(v, lst, RR_NEE_GAIN)) {
            break;
        }
        result += throughput * v;
        if order >= orders.1 {
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
    result
}

/// Random-walk sampler: at each vertex m ~ D_w, reflect with probability F or
/// refract, and an upward direction (in its medium's frame) leaves with
/// probability 1 − c, so the weight is 1 (× Mitsuba's 1/η_r² for a
/// transmission in Radiance mode). `first` = (sample1, u1, u2) drives the first
/// vertex: sample1 chooses reflection when sample1 < F and, rescaled to [0, 1)
/// within the chosen branch, decides the first exit. Returns (ω_o, weight,
/// order) or None (no visible normal, or `opts.walk.max_bounces` reached).
pub fn sample_walk(
    mf: &Microfacet,
    eta: f64,
    radiance: bool,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &Options,
    rng: &mut Sampler,
) -> Option<(DVec3, f64, u32)> {
    if !valid_inputs(eta, wi) {
        return None;
    }
    let seg = opts.segments;
    let mut st = State::new(mf, eta, wi);
    for j in 0..opts.walk.max_bounces {
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
                unit_interval(u).unwrap_or_else(|| rng.next())
            } else {
                rng.next()
            };
            if u_exit >= c {
                let wo = st.side * d;
                return Some((wo, radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0), j + 1));
            }
            st.l = lambda;
        } else {
            st.l = mf.abs_lambda(d);
        }
        st.w = -d;
    }
    None
}

// ---------------------------------------------------------------------------
// Order 1 in closed form: `model="auto"`'s calls reduced to order 1
// (src/models/auto/mod.rs). The walk's first vertex has no random factor in
// its next event, and its sampler draws the first direction from the density
// v/L_0 (module docs, "Sampling density"): the visible normal of w, then
// reflection with probability F or refraction.

/// Order 1 of the PT estimator: the walk's next event at its first vertex
/// (`eval_pt` capped at one vertex, in the same arithmetic: the same bits),
/// Radiance mode's 1/η_r² included. Deterministic.
pub fn order_one_eval(mf: &Microfacet, seg: Segments, eta: f64, radiance: bool, wi: DVec3, wo: DVec3) -> f64 {
    if !valid_inputs(eta, wi) || wo.z == 0.0 || !wo.is_finite() {
        return 0.0;
    }
    let (v, _) = next_event(mf, seg, &State::new(mf, eta, wi), wo, lambda_out(mf, wo));
    v * radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0)
}

/// The density of [`order_one_sample`]'s ω_o: v(ω_o)/L_0, the visible-normal
/// density of the half vector reaching ω_o times the probability of its
/// branch (F for a reflection on ω_i's side, 1 − F for a refraction across)
/// and the Jacobian of that branch (1/(4 w·h), Walter's for the refraction).
pub fn order_one_pdf(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    if !valid_inputs(eta, wi) || wo.z == 0.0 || !wo.is_finite() {
        return 0.0;
    }
    let st = State::new(mf, eta, wi);
    let p = vertex_towards(mf, &st, st.side * wo) / st.l;
    if p.is_finite() {
        p
    } else {
        0.0
    }
}

/// The walk's first vertex with `first` = (sample1, u1, u2) as `sample_walk`
/// draws it (the same direction), where the new direction leaves the surface:
/// (ω_o, weight, pdf) with pdf = [`order_one_pdf`] and weight =
/// [`order_one_eval`]/pdf = L_0·last × Radiance mode's 1/η_r², the
/// expectation of the walk's exit there (its probability 1 − c) instead of a
/// random exit: L_0/(L_0 + Λ_o) for a reflection, L_0·B(L_0, 1+Λ_o) for a
/// refraction (correlated). None where the direction goes down in its frame
/// (the walk would go on: an order above 1) or has no density.
pub fn order_one_sample(mf: &Microfacet, seg: Segments, eta: f64, radiance: bool, wi: DVec3, first: (f64, f64, f64)) -> Option<(DVec3, f64, f64)> {
    if !valid_inputs(eta, wi) {
        return None;
    }
    let mut st = State::new(mf, eta, wi);
    let l0 = st.l;
    let (d, refracted, _) = scatter(mf, &mut st, first.0, first.1, first.2)?;
    if !(d.z > 0.0) {
        return None;
    }
    let wo = st.side * d;
    let pdf = order_one_pdf(mf, eta, wi, wo);
    if !(pdf > 0.0) {
        return None;
    }
    let weight = l0 * last(seg, refracted, l0, mf.lambda(d)) * radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0);
    Some((wo, weight, pdf))
}

// ---------------------------------------------------------------------------
// The bidirectional estimator (Wang 2022 §4.2 applied to eqs. 2–3, 12–23;
// src/walk/bdpt.rs).
//
// Directions with media: every d_j is kept in global coordinates together
// with the medium it travels in (side σ_j = +1 outside, −1 inside); in that
// medium's frame it is σ_j·d_j (the frames above). σ_0 = sign(ω_i.z),
// σ_k = sign(ω_o.z); the inner media are whatever the subpaths sampled. Vertex
// j is a reflection when σ_j = σ_{j+1} and a refraction otherwise, so any
// camera vertex can be joined to any light vertex.
//
// Factors: with v(a → b) the vertex term of light arriving along a (medium
// σ_a) and leaving along b (medium σ_b), evaluated in a's frame (w = −σ_a a,
// o = σ_a b, η_f of σ_a) and L_j = |Λ(σ_j d_j)|, the forward path contribution
// is f = Π_{j<k} φ_j with φ_j = v(d_j → d_{j+1})·g_j, g_j = c_j/L_j (j < k−1)
// and g_{k−1} = last(…), times Radiance mode's 1/η_r² of the macro pair once.
//
// Densities: sampling m ~ D_w (w = −σ_a a) and reflecting with probability F /
// refracting with 1 − F gives b the density q(a → b) = v(a → b)/|Λ(σ_a a)|.
// The camera step at vertex j samples d_{j+1} with pf_j = q(d_j → d_{j+1});
// the light step samples the reversed ray: it arrives along −d_{j+1} in medium
// σ_{j+1} and scatters with the same sampler to −d_j, so
// pr_j = q(−d_{j+1} → −d_j).

/// A path direction: global coordinates, medium side, |Λ| of it and of its
/// reverse in its own frame.
#[derive(Clone, Copy)]
struct Dir {
    g: DVec3,
    side: f64,
    /// |Λ(σ d)|: L of the vertex it arrives at.
    l: f64,
    /// |Λ(−σ d)|: normaliser of the reversed sampling from this direction.
    r: f64,
}

impl Default for Dir {
    fn default() -> Self {
        Dir { g: DVec3::ZERO, side: 1.0, l: 0.0, r: 0.0 }
    }
}

impl Dir {
    fn new(mf: &Microfacet, g: DVec3, side: f64) -> Dir {
        let loc = side * g;
        let u = mf.lambda(DVec3::new(loc.x, loc.y, loc.z.abs()));
        let (l, r) = if loc.z >= 0.0 { (u, 1.0 + u) } else { (1.0 + u, u) };
        Dir { g, side, l, r }
    }

    #[inline]
    fn reversed(&self) -> Dir {
        Dir { g: -self.g, side: self.side, l: self.r, r: self.l }
    }

    /// Λ(σ d) when σ d points up (its own frame), else None.
    #[inline]
    fn lambda_up(&self) -> Option<f64> {
        if self.side * self.g.z > 0.0 {
            Some(self.l)
        } else {
            None
        }
    }

    /// The walk state of light arriving along this direction.
    fn state(&self, eta: f64) -> State {
        State { w: -self.side * self.g, l: self.l, side: self.side, eta_f: eta_seen(eta, self.side > 0.0) }
    }
}

/// The camera vertex: d_s and the prefix f/p (Π c).
#[derive(Clone, Copy, Default)]
struct CamDir {
    d: Dir,
    thr: f64,
}

/// The light vertex: e_t = d_{k−t} and Π φ/pr of its t steps.
#[derive(Clone, Copy, Default)]
struct LightDir {
    e: Dir,
    w: f64,
}

/// The dielectric's vertex terms for `walk::bdpt`.
struct Bidirectional<'a> {
    mf: &'a Microfacet,
    eta: f64,
    seg: Segments,
    d0: Dir,
    dk: Dir,
    wo: DVec3,
}

impl Bidirectional<'_> {
    /// v(a → b): vertex term in a's frame.
    #[inline]
    fn vtx(&self, a: &Dir, b: &Dir) -> f64 {
        let w = -a.side * a.g;
        let o = a.side * b.g;
        let ef = eta_seen(self.eta, a.side > 0.0);
        if a.side == b.side {
            vertex_reflect(self.mf, ef, w, o)
        } else {
            vertex_transmit(self.mf, ef, w, o)
        }
    }

    /// c of b after a vertex from a (1 for b going down in its frame).
    #[inline]
    fn cont(&self, a: &Dir, b: &Dir) -> f64 {
        match b.lambda_up() {
            Some(lam) => continue_up(self.seg, a.side != b.side, a.l, lam),
            None => 1.0,
        }
    }

    /// g_j for the vertex from a to b; `b_is_last`: b = ω_o.
    #[inline]
    fn g(&self, a: &Dir, b: &Dir, b_is_last: bool) -> f64 {
        if b_is_last {
            last(self.seg, a.side != b.side, a.l, self.dk.l)
        } else {
            self.cont(a, b) / a.l
        }
    }

    /// One sampling step from a (arriving): m ~ D_w, reflect with probability F.
    #[inline]
    fn scatter(&self, a: &Dir, rng: &mut Sampler) -> Option<Dir> {
        let w = -a.side * a.g;
        let u_choice = rng.next();
        let (u1, u2) = rng.next2();
        let m = self.mf.sample_visible(w, u1, u2)?;
        let cos_wm = w.dot(m);
        if !(cos_wm > 0.0) {
            return None;
        }
        let (o, refracted, _) = reflect_or_refract(w, m, cos_wm, eta_seen(self.eta, a.side > 0.0), u_choice);
        let side = if refracted { -a.side } else { a.side };
        let g = a.side * o;
        if !g.is_finite() || g.z == 0.0 {
            return None;
        }
        let d = Dir::new(self.mf, g, side);
        if !(d.l > 0.0) || !d.l.is_finite() || !(d.r > 0.0) || !d.r.is_finite() {
            return None;
        }
        Some(d)
    }
}

/// q(a → b) given v(a → b): the sampling density of b.
#[inline]
fn dens(v: f64, a: &Dir) -> f64 {
    let p = v / a.l;
    if p.is_finite() {
        p
    } else {
        0.0
    }
}

impl bdpt::BdptSurface for Bidirectional<'_> {
    type Cam = CamDir;
    type Light = LightDir;
    /// φ_s.
    type Conn = f64;
    type Value = f64;

    fn camera_start(&self) -> CamDir {
        CamDir { d: self.d0, thr: 1.0 }
    }

    fn camera_ready(&self, v: &CamDir) -> bool {
        v.d.l > 0.0 && v.d.l.is_finite() && v.thr > 0.0
    }

    fn camera_step(&self, v: &mut CamDir, s: usize, rng: &mut Sampler) -> Option<bdpt::Step<CamDir>> {
        let dn = self.scatter(&v.d, rng)?;
        let pf = dens(self.vtx(&v.d, &dn), &v.d);
        if !(pf > 0.0) {
            return None;
        }
        let p_rev = if s >= 1 { dens(self.vtx(&dn.reversed(), &v.d.reversed()), &dn.reversed()) } else { 0.0 };
        let thr = v.thr * self.cont(&v.d, &dn);
        Some(bdpt::Step { vertex: CamDir { d: dn, thr }, p_in: pf, p_rev })
    }

    fn light_start(&self) -> LightDir {
        LightDir { e: self.dk, w: 1.0 }
    }

    fn light_ready(&self, v: &LightDir) -> bool {
        v.w > 0.0
    }

    fn light_step(&self, v: &LightDir, t: usize, rng: &mut Sampler) -> Option<bdpt::Step<LightDir>> {
        let rev = v.e.reversed();
        let b = self.scatter(&rev, rng)?;
        let dj = b.reversed(); // d_j, forward direction arriving at vertex j
        let pr = dens(self.vtx(&rev, &b), &rev);
        if !(pr > 0.0) || !(dj.l > 0.0) || !dj.l.is_finite() {
            return None;
        }
        let vv = self.vtx(&dj, &v.e);
        let w = v.w * (vv * self.g(&dj, &v.e, t == 0)) / pr;
        let p_rev = if t >= 1 { dens(vv, &dj) } else { 0.0 };
        Some(bdpt::Step { vertex: LightDir { e: dj, w: if w.is_finite() { w } else { 0.0 } }, p_in: pr, p_rev })
    }

    fn connect(&self, cam: &[CamDir], light: &[LightDir]) -> Option<bdpt::Connection<f64>> {
        let (s, t) = (cam.len() - 1, light.len() - 1);
        let (cv, lv) = (&cam[s], &light[t]);
        if !(cv.thr > 0.0) || !(lv.w > 0.0) || !(cv.d.l > 0.0) || !cv.d.l.is_finite() {
            return None;
        }
        let v = self.vtx(&cv.d, &lv.e);
        if !(v > 0.0) {
            return None;
        }
        let phi = v * self.g(&cv.d, &lv.e, t == 0);
        let pr = if s >= 1 {
            let rev = lv.e.reversed();
            dens(self.vtx(&rev, &cv.d.reversed()), &rev)
        } else {
            0.0
        };
        let pf = if t >= 1 { dens(v, &cv.d) } else { 0.0 };
        Some(bdpt::Connection { pr, pf, data: phi })
    }

    fn weighted(&self, conn: &bdpt::Connection<f64>, cv: &CamDir, lv: &LightDir, denom: f64) -> Option<f64> {
        let c = cv.thr * conn.data * lv.w / denom;
        c.is_finite().then_some(c)
    }

    fn pt_tail(&self, cam: &[CamDir], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> f64 {
        let cv = &cam[kb as usize];
        pt_walk(self.mf, self.seg, self.wo, cv.d.state(self.eta), cv.thr, kb, orders, kb + RR_START, rng)
    }
}

/// BDPT estimate of f(ω_i, ω_o)·|cos θ_o| (orders `opts.walk.orders`), default K_b.
pub fn eval_bdpt(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> f64 {
    eval_bdpt_with(mf, eta, radiance, wi, wo, opts, bdpt::DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`bdpt::MAX_BDPT_ORDERS`]) and higher orders by path tracing.
#[allow(clippy::too_many_arguments)]
pub fn eval_bdpt_with(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &Options, bdpt_orders: u32, rng: &mut Sampler) -> f64 {
    if !valid_inputs(eta, wi) || wo.z == 0.0 || !wo.is_finite() {
        return 0.0;
    }
    let side_i = if wi.z > 0.0 { 1.0 } else { -1.0 };
    let side_o = if wo.z > 0.0 { 1.0 } else { -1.0 };
    let surface = Bidirectional { mf, eta, seg: opts.segments, d0: Dir::new(mf, -wi, side_i), dk: Dir::new(mf, wo, side_o), wo };
    let result = bdpt::estimate(&surface, opts.walk.clamped_orders(), bdpt_orders, rng);
    let value = result * radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0);
    if value.is_finite() && value > 0.0 {
        value
    } else {
        0.0
    }
}
