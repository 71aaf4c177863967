//! Bidirectional estimator (Wang et al. 2022 §4.2, eqs. 27–29) of the
//! position-free conductor BSDF of [`super::conductor`], for both segment models.
//!
//! # Path contribution as a chain of pair factors
//! A path of order k is d_0 = −ω_i, d_1, …, d_{k−1}, d_k = ω_o; the integration
//! variables are the k − 1 inner directions (solid angle each, eq. 4). With
//! L_j = |Λ(d_j)| and the table of `posfree.rs`, eq. 1 factors into one term per
//! vertex j, each depending on the two directions around it only:
//!
//!   f = Π_{j=0}^{k−1} φ_j(d_j, d_{j+1}),
//!   φ_j = F_j·D(h_j)/(4|cos d_j|) · g_j,    h_j = normalize(−d_j + d_{j+1}),
//!   g_j = cont(L_j, d_{j+1})/L_j   (j < k−1;  cont = Segments::continue_up for
//!                                   an upward d_{j+1}, 1 for a downward one)
//!   g_{k−1} = Segments::last(L_{k−1}, Λ(ω_o)).
//!
//! Every φ_j is the *forward* (ω_i → ω_o) term: the correlated model is not
//! reciprocal, so the light subpath below is sampled backwards but its
//! contribution is always these forward factors.
//!
//! # Sampling densities (solid angle)
//! With A(ω) = ∫⟨ω,m⟩D(m)dm the projected area (A(−d_j) = |cos d_j|·L_j):
//! - camera (forward) step at vertex j: m ~ D_{−d_j}, d_{j+1} = reflect(−d_j, m):
//!   pf_j = D_{−d_j}(h_j)/(4⟨−d_j,h_j⟩) = D(h_j) / (4 A(−d_j));
//! - light (backward) step at vertex j: m ~ D_{d_{j+1}}, −d_j = reflect(d_{j+1}, m):
//!   pr_j = D(h_j) / (4 A(d_{j+1}))   (the sign flip d ↦ −d preserves solid angle).
//!
//! The camera subpath starts from d_0 and samples d_1, d_2, …; the light subpath
//! starts from d_k = ω_o and samples d_{k−1}, d_{k−2}, … (Fresnel per channel
//! through the φ_j). Strategy s ∈ {0, …, k−1} of order k takes d_1..d_s from
//! the camera and d_{s+1}..d_{k−1} (t = k−1−s directions) from the light and
//! evaluates the connecting vertex s deterministically; its density is
//!
//!   p_s = Π_{j=0}^{s−1} pf_j · Π_{j=s+1}^{k−1} pr_j        (eq. 27)
//!
//! s = k−1 is path tracing with next-event estimation towards ω_o (Wang eq. 25),
//! s = 0 is light tracing connected to ω_i. The k strategies are combined with
//! the balance heuristic (eq. 28), w_s = p_s / Σ_{s'} p_{s'}, computed from the
//! ratios p_{s−1}/p_s = pr_s/pf_{s−1} and p_{s+1}/p_s = pf_s/pr_{s+1}:
//!
//!   Σ_{s'<s} p_{s'}/p_s = a_s(1 + a_{s−1}(1 + … (1 + a_1))),   a_u = pr_u/pf_{u−1},
//!   Σ_{s'>s} p_{s'}/p_s = b_s(1 + b_{s+1}(1 + … (1 + b_{k−2}))), b_u = pf_u/pr_{u+1},
//!
//! whose inner parts are accumulated along each subpath (a_u with u < s only
//! involves camera directions, b_u with u > s only light directions).
//!
//! # Lengths, roulette and unbiasedness
//! The balance heuristic above is the exact one only if every strategy's
//! density is p_s as written, so the subpaths used for orders 1..=K_b are
//! sampled with fixed length (K_b − 1 directions each) and **no** Russian
//! roulette; K_b = min(orders.1, max_bounces, bdpt_orders). All k strategies of
//! every order k ≤ K_b are then always available (the weights sum to one over
//! the strategies that actually run). Orders K_b < k ≤ min(orders.1,
//! max_bounces) — little energy for moderate α, but a lot at α ≳ 2 — are
//! estimated by continuing the camera subpath as the unidirectional PT of
//! `posfree::eval_pt` (one strategy, weight 1, roulette allowed): the sum of an
//! unbiased BDPT estimate of the low orders and an unbiased PT estimate of the
//! high orders is unbiased. Subpaths stop early only on measure-zero events
//! (a direction that sees no microfacet, Λ = 0 exactly).

use super::conductor::{pt_walk, PtState};
use super::Segments;
use crate::models::{ConductorFresnel, WalkOptions};
use crate::microfacet::{reflect, Microfacet};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;

/// Default number of orders handled bidirectionally (higher orders: PT).
/// Each subpath costs K_b − 1 visible-normal samples (no roulette) and there
/// are K_b(K_b+1)/2 connections. Measured (release, copper, all orders, three
/// direction pairs, α ∈ {0.5, 1, 2}): the variance per call falls 2–26× vs PT
/// and stops improving beyond K_b ≈ 4 for α ≤ 1; (variance × time) is best at
/// K_b = 3 for GGX and K_b = 2 for Beckmann (whose VNDF sampler is a Newton
/// solve, ≈ 3–5× dearer than GGX's).
pub const DEFAULT_BDPT_ORDERS: u32 = 3;
/// Largest K_b (stack arrays).
pub const MAX_BDPT_ORDERS: u32 = 32;

/// First continuation vertex after which roulette may end the PT tail (as posfree).
const RR_START: u32 = 1;

#[derive(Clone, Copy)]
struct CamVertex {
    /// d_s (direction of travel, arriving at vertex s).
    d: DVec3,
    /// L_s = |Λ(d_s)|.
    l: f64,
    /// A(−d_s) = |cos d_s|·L_s.
    area_back: f64,
    /// f/p of the prefix d_0..d_s (product of F·cont).
    thr: Spectrum,
    /// pf_{s−1}: density of d_s (s ≥ 1).
    pdf_in: f64,
    /// B_{s−1} = a_{s−1}(1 + a_{s−2}(1 + …)), 0 for s ≤ 1.
    left: f64,
}

#[derive(Clone, Copy)]
struct LightVertex {
    /// e_t = d_{k−t} (direction of travel in the forward path).
    e: DVec3,
    /// |Λ(e_t)|: Λ(e_t) itself when e_t points up.
    l: f64,
    /// A(e_t).
    area: f64,
    /// Product of forward factors φ over pr for the t sampled steps.
    w: Spectrum,
    /// pr: density of e_t given e_{t−1} (t ≥ 1).
    pdf_in: f64,
    /// E_{t−1} = b(t−1)(1 + b(t−2)(1 + …)), 0 for t ≤ 1.
    right: f64,
}

const CAM0: CamVertex = CamVertex { d: DVec3::ZERO, l: 0.0, area_back: 0.0, thr: Spectrum::ZERO, pdf_in: 0.0, left: 0.0 };
const LIG0: LightVertex = LightVertex { e: DVec3::ZERO, l: 0.0, area: 0.0, w: Spectrum::ZERO, pdf_in: 0.0, right: 0.0 };

/// Smith quantities of a direction d from one Λ evaluation:
/// (L = |Λ(d)|, A(d), A(−d)), with A(d) = |cos d|·|Λ(−d)| and A(−d) = |cos d|·L.
/// Λ of the upward direction with the same slope, u ≥ 0, gives |Λ(d)| = u
/// (d up) or 1 + u (d down) without cancellation (docs/paper-notes.md).
#[inline]
pub(crate) fn smith(mf: &Microfacet, d: DVec3) -> (f64, f64, f64) {
    let u = mf.lambda(DVec3::new(d.x, d.y, d.z.abs()));
    let c = d.z.abs();
    if d.z >= 0.0 {
        (u, c * (1.0 + u), c * u)
    } else {
        (1.0 + u, c * u, c * (1.0 + u))
    }
}

/// g_j · L_j for a middle vertex: the continue factor of the next direction.
#[inline]
pub(crate) fn cont(seg: Segments, l: f64, next: DVec3, l_next: f64) -> f64 {
    if next.z > 0.0 {
        seg.continue_up(l, l_next)
    } else {
        1.0
    }
}

/// BDPT estimate of f(ω_i, ω_o)·cos θ_o with the default number of
/// bidirectional orders ([`DEFAULT_BDPT_ORDERS`]).
pub fn eval_bdpt(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    eval_bdpt_with(mf, fresnel, wi, wo, opts, DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`MAX_BDPT_ORDERS`]) and higher orders by path tracing.
pub fn eval_bdpt_with(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    wo: DVec3,
    opts: &WalkOptions,
    bdpt_orders: u32,
    rng: &mut Sampler,
) -> Spectrum {
    if wi.z < 0.0 && wo.z > 0.0 {
        // ω_i below the macro surface (normal mapping): the PT estimator, which covers it (same expectation).
        return super::conductor::eval_pt(mf, fresnel, wi, wo, opts, rng);
    }
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let seg = opts.segments;
    let (o_lo, o_hi) = (opts.orders.0.max(1), opts.orders.1.min(opts.max_bounces));
    if o_lo > o_hi {
        return Spectrum::ZERO;
    }
    let kb = o_hi.min(bdpt_orders.clamp(1, MAX_BDPT_ORDERS)); // orders ≤ kb: bidirectional
    let pt_tail = o_hi > kb;
    let lambda_o = mf.lambda(wo);
    let mut result = Spectrum::ZERO;

    // ---- camera subpath d_0..d_{n_c} (n_c = kb − 1, or kb if the PT tail needs d_kb)
    let n_c_target = if pt_tail { kb } else { kb - 1 } as usize;
    let mut cam = [CAM0; MAX_BDPT_ORDERS as usize + 1];
    {
        let l0 = 1.0 + mf.lambda(wi);
        cam[0] = CamVertex { d: -wi, l: l0, area_back: mf.projected_area(wi), thr: Spectrum::ONE, pdf_in: 0.0, left: 0.0 };
    }
    let mut n_c = 0usize;
    let mut b_acc = 0.0; // B_{s} accumulated
    while n_c < n_c_target {
        let s = n_c;
        let cv = cam[s];
        if !(cv.l > 0.0) || !cv.l.is_finite() || !(cv.area_back > 0.0) {
            break;
        }
        let w = -cv.d;
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(w, u1, u2) else { break };
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            break;
        }
        let d_next = reflect(w, m);
        let (l_next, area_next, area_back_next) = smith(mf, d_next);
        let dm = mf.d(m);
        let pf = dm / (4.0 * cv.area_back);
        if !(pf > 0.0) || !pf.is_finite() || !(area_next > 0.0) {
            break;
        }
        // a_s = pr_s / pf_{s−1} for s ≥ 1; B_s = a_s (1 + B_{s−1}).
        let left_for_next = if s >= 1 {
            let pr = dm / (4.0 * area_next);
            b_acc = pr / cv.pdf_in * (1.0 + b_acc);
            b_acc
        } else {
            0.0
        };
        let thr = cv.thr * fresnel.eval(cos_wm) * cont(seg, cv.l, d_next, l_next);
        cam[s + 1] = CamVertex { d: d_next, l: l_next, area_back: area_back_next, thr, pdf_in: pf, left: left_for_next };
        n_c += 1;
    }

    // ---- light subpath e_0 = ω_o, e_1 = d_{k−1}, … (n_l = kb − 1 sampled)
    let mut lig = [LIG0; MAX_BDPT_ORDERS as usize + 1];
    let mut n_l = 0usize;
    if o_lo <= kb {
        lig[0] = LightVertex { e: wo, l: lambda_o, area: mf.projected_area(wo), w: Spectrum::ONE, pdf_in: 0.0, right: 0.0 };
        let mut e_acc = 0.0;
        while n_l + 1 < kb as usize {
            let t = n_l;
            let lv = lig[t];
            if !(lv.area > 0.0) || !lv.area.is_finite() {
                break;
            }
            let (u1, u2) = rng.next2();
            let Some(m) = mf.sample_visible(lv.e, u1, u2) else { break };
            let cos_em = lv.e.dot(m);
            if cos_em <= 0.0 {
                break;
            }
            let e_next = -reflect(lv.e, m); // d_j, arriving at vertex j = k−1−t
            let (l_next, area_next, area_back_next) = smith(mf, e_next);
            let cos_next = e_next.z.abs();
            if !(l_next > 0.0) || !l_next.is_finite() || !(cos_next > 0.0) {
                break;
            }
            let dm = mf.d(m);
            let pr = dm / (4.0 * lv.area);
            if !(pr > 0.0) || !pr.is_finite() || !(area_back_next > 0.0) {
                break;
            }
            // Forward factor φ_j / pr_j = F·A(d_{j+1})·g_j / |cos d_j| (D cancels).
            let g = if t == 0 { seg.last(l_next, lambda_o) } else { cont(seg, l_next, lv.e, lv.l) / l_next };
            let w = lv.w * fresnel.eval(cos_em) * (lv.area * g / cos_next);
            // b(t) = lf_t / lr_{t−1} for t ≥ 1; E_t = b(t)(1 + E_{t−1}).
            let right_for_next = if t >= 1 {
                let pf = dm / (4.0 * area_back_next);
                e_acc = pf / lv.pdf_in * (1.0 + e_acc);
                e_acc
            } else {
                0.0
            };
            lig[t + 1] = LightVertex { e: e_next, l: l_next, area: area_next, w, pdf_in: pr, right: right_for_next };
            n_l += 1;
        }

        // ---- connections: order k, strategy s, t = k − 1 − s
        for k in o_lo..=kb {
            let k = k as usize;
            // `s` is the strategy (camera vertices), not only an index into `cam`.
            #[allow(clippy::needless_range_loop)]
            for s in 0..k {
                let t = k - 1 - s;
                if s > n_c || t > n_l {
                    continue;
                }
                let cv = &cam[s];
                let lv = &lig[t];
                if !(cv.thr.max_value() > 0.0) || !(lv.w.max_value() > 0.0) {
                    continue;
                }
                let cos_s = cv.d.z.abs();
                if !(cv.l > 0.0) || !cv.l.is_finite() || !(cos_s > 0.0) || !(lv.area > 0.0) {
                    continue;
                }
                let h = -cv.d + lv.e;
                let len = h.length();
                if !(len > 0.0) {
                    continue;
                }
                let h = h / len;
                let cos_h = -cv.d.dot(h);
                if h.z <= 0.0 || cos_h <= 0.0 {
                    continue;
                }
                let dh = mf.d(h);
                if !(dh > 0.0) {
                    continue;
                }
                let g = if t == 0 { seg.last(cv.l, lambda_o) } else { cont(seg, cv.l, lv.e, lv.l) / cv.l };
                let phi = dh * g / (4.0 * cos_s);
                // Balance heuristic.
                let mut denom = 1.0;
                if s >= 1 {
                    let pr_s = dh / (4.0 * lv.area);
                    denom += pr_s / cv.pdf_in * (1.0 + cv.left);
                }
                if t >= 1 {
                    let pf_s = dh / (4.0 * cv.area_back);
                    denom += pf_s / lv.pdf_in * (1.0 + lv.right);
                }
                let weight = phi / denom;
                if !weight.is_finite() {
                    continue;
                }
                result += cv.thr * lv.w * fresnel.eval(cos_h) * weight;
            }
        }
    }

    // ---- orders kb+1 ..= o_hi: the camera subpath continues as PT with NEE.
    if pt_tail && n_c == kb as usize {
        let cv = cam[kb as usize];
        let state = PtState { w: -cv.d, l: cv.l, throughput: cv.thr };
        result += pt_walk(mf, fresnel, wo, lambda_o, seg, state, kb, (o_lo, o_hi), kb + RR_START, rng);
    }
    result
}
