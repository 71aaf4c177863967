//! The invariance-principle model on specular conductor facets (Cui et al.
//! 2023): the estimators over the recursion of `recursion.rs`.
//!
//! **Estimators.** `eval`: sample d_{j+1} by reflecting −d_j about a visible
//! normal (density v_j/(F_j·L_j)); the NEE at vertex m towards ω_o then weighs
//! Π_{j≤m}F_j · D(h)/(4A(−d_m)) · p_exit(d_0..d_m, ω_o). The walk carries the
//! conditional hit probabilities H_{m}/H_{m−1} in its throughput and plays
//! Russian roulette on it after the vertex's estimates (sure survival while the
//! weight is ≥ 1/2, `RR_KEEP`); the heights are integrated out exactly. The
//! walk stops as soon as an upward direction is at least as steep as ω_o:
//! z only grows along the upward run, so no later vertex can reach ω_o (their
//! estimates are exactly 0; not a truncation). For orders 2 and 3 the last
//! inner direction is also sampled from the side of ω_o and the two strategies
//! are combined with the balance heuristic (a one-vertex light subpath, one
//! per call; closed form because the model is position-free).
//! `sample`: the same walk with exit
//! probability 1 − H_m/H_{m−1} at each upward direction; the sampling density
//! is then exactly the path contribution divided by Π F, so the weight is the
//! product of the Fresnel terms (Cui Alg. 2 with the exact exit probability —
//! the printed 1/|Λ(d_k)|, or G1(d_k) = 1/(1+Λ(d_k)), needs a weight ratio).
//!
//! **Efficiency** of `eval` against Heitz's walk, and of the BDPT below against
//! both: measured by `benches/models.rs`, numbers in benches/README.md.

use super::recursion::MonotoneExit;
use crate::microfacet::ConductorFresnel;
use crate::microfacet::{reflect, Microfacet};
use crate::models::posfree::conductor::{self as posfree_conductor, CamVertex, ConductorSegments, LightVertex as WalkLight, Outgoing};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use crate::walk::{bdpt, russian_roulette_keep, sample_conductor, ConductorExit, RR_START};
use glam::DVec3;

/// Throughput (largest channel) above which the walk of `eval` surely goes on.
/// Below it the roulette keeps the walk with probability throughput/RR_KEEP,
/// so a survivor carries weight RR_KEEP. Heitz's rule (keep with probability
/// equal to the throughput, RR_KEEP = 1) ends too many of the walks that can
/// still reach ω_o once those that cannot are stopped exactly (see `eval`):
/// at GGX α = 1, 1/2 lowers the variance per call by 6 % (off-specular) and
/// 13 % (mirror) for ≈ 5 % more time.
const RR_KEEP: f64 = 0.5;

/// Highest order estimated by the connection as well as by the walk's NEE.
/// Beyond it the NEE alone is better: at GGX α = 1 off-specular, connecting
/// at every order raises the variance per call by 4 % (the shared y
/// correlates the orders) and costs a D, a Fresnel term and an O(a) exit
/// probability per vertex. Order 3 still pays (−8 % variance for ≈ 5 % time).
const CONNECT_MAX_ORDER: u32 = 3;

/// One unbiased estimate of f(ω_i, ω_o)·cos θ_o of the invariance model,
/// restricted to the orders `opts.orders` and at most `opts.max_bounces`
/// vertices. Order 1 is deterministic:
/// F·D·G2/(4 cos θ_i) with G2 = 1/(1 + Λ(ω_i) + Λ(ω_o)).
///
/// Orders 2 ≤ k ≤ `CONNECT_MAX_ORDER` (3) combine two strategies for the last
/// inner direction d_{k−1} with the balance heuristic: the walk's own sample
/// (visible normals of −d_{k−2}, closed by NEE at vertex k−1) and a connection
/// from vertex k−2 to d_{k−1} = y = −(ω_o reflected about a visible normal of
/// ω_o). Both are closed forms thanks to the position-free path contribution;
/// the second removes most of the variance off-specular, where the NEE phase
/// value at the last vertex peaks (order-2 variance ÷2.5–4 at GGX α = 0.5–1).
///
/// One y serves both connected orders (`LightVertex`): each order's connection is
/// unbiased for any y drawn from its density, independently of the walk, so
/// reusing it only correlates the orders. A fresh y per connection lowers the
/// variance by ≈ 6 % (GGX α = 1, off-specular) for ≈ 15–30 % more time per call
/// (a visible-normal sample, a D, a Λ and a Fresnel term each).
pub fn eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    if !(wi.z > 0.0) || !(wo.z > 0.0) || !wi.is_finite() || !wo.is_finite() {
        return Spectrum::ZERO;
    }
    let Some(last) = opts.last_order() else { return Spectrum::ZERO };
    let lambda_o = mf.lambda(wo);
    if !lambda_o.is_finite() {
        return Spectrum::ZERO;
    }
    let area_o = wo.z * (1.0 + lambda_o); // A(ω_o)
    let pdf_scale_o = 0.25 / area_o;
    // The connection strategy serves orders 2..=CONNECT_MAX_ORDER.
    let connects = last >= 2 && opts.orders.0 <= CONNECT_MAX_ORDER;
    let light = if connects { LightVertex::sample(mf, fresnel, wo, pdf_scale_o, rng) } else { None };
    let l0 = mf.abs_lambda(-wi);
    let walk = Walk { mf, fresnel, wo, lambda_o, pdf_scale_o, connect_max: CONNECT_MAX_ORDER, light: light.as_ref() };
    let state = WalkState { w: wi, pdf_scale: 0.25 / (wi.z * l0), pdf_walk: 0.0, dp: MonotoneExit::new(l0), throughput: Spectrum::ONE };
    walk.from(state, 0, (opts.orders.0, last), rng)
}

/// A walk of `eval` arriving at a vertex: w = −d_m, 1/(4 A(w)) with the
/// projected area A(w) = |cos d_m|·|Λ(d_m)| (reflect_pdf(w, x) = D(h)/(4 A(w))
/// for every x the vertex scatters into: ω_o for the NEE, y for the
/// connection, the walk's own sample), the density with which the walk
/// sampled d_m from −d_{m−1} (the forward strategy's density in the MIS weight
/// of the NEE at vertex m ≥ 1), the exit table of d_0..d_m and the throughput
/// Π F · Π (H_j/H_{j−1}) / Π q.
#[derive(Clone)]
pub(crate) struct WalkState {
    pub w: DVec3,
    pub pdf_scale: f64,
    pub pdf_walk: f64,
    pub dp: MonotoneExit,
    pub throughput: Spectrum,
}

/// What the walk of `eval` needs besides its state: ω_o, and the connection
/// strategy for orders 2..=`connect_max` (none with `light` None and
/// `connect_max` 0).
pub(crate) struct Walk<'a> {
    pub mf: &'a Microfacet,
    pub fresnel: &'a ConductorFresnel,
    pub wo: DVec3,
    pub lambda_o: f64,
    pub pdf_scale_o: f64,
    pub connect_max: u32,
    light: Option<&'a LightVertex>,
}

impl Walk<'_> {
    /// The walk without the connection strategy (the BDPT's tail).
    pub fn unidirectional<'a>(mf: &'a Microfacet, fresnel: &'a ConductorFresnel, wo: DVec3, lambda_o: f64) -> Walk<'a> {
        Walk { mf, fresnel, wo, lambda_o, pdf_scale_o: 0.25 / (wo.z * (1.0 + lambda_o)), connect_max: 0, light: None }
    }

    /// The estimates of the vertices from `first_vertex` (0-based) on, within
    /// `orders` (the upper one within the bounce cap).
    /// One loop over the vertices: its steps (next event, roulette, scattering,
    /// exit bookkeeping) share the walk's state.
    pub fn from(&self, state: WalkState, first_vertex: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let (mf, fresnel, wo, lambda_o) = (self.mf, self.fresnel, self.wo, self.lambda_o);
        let WalkState { mut w, mut pdf_scale, mut pdf_walk, mut dp, mut throughput } = state;
        let last = orders.1;
        let mut result = Spectrum::ZERO;
        for j in first_vertex..last {
            let order = j + 1;
            if order >= orders.0 {
                // NEE: v_m/L_m = D(h)/(4 A(−d_m)) = reflect_pdf(w, ω_o).
                let (d_h, cos_wh) = half_vector_d(mf, w, wo);
                let mut value = d_h * pdf_scale;
                if j > 0 && order <= self.connect_max && value > 0.0 {
                    // Balance heuristic against the connection, which samples
                    // y = d_m as reflect_pdf(ω_o, −d_m): the same half vector,
                    // D(h)/(4 A(ω_o)). (The power heuristic lowers the variance
                    // by 2 % at GGX α = 1 off-specular and raises it by 8 % at
                    // α = 0.5 grazing.)
                    let p_rev = d_h * self.pdf_scale_o;
                    value *= pdf_walk / (pdf_walk + p_rev);
                }
                if value > 0.0 && value.is_finite() {
                    value *= dp.exit_given_hits(lambda_o);
                    result += throughput * fresnel.eval(cos_wh) * value;
                }
            }
            if order >= last {
                break;
            }
            // Connection strategy for order + 1: d_{m+1} = y from the side of ω_o.
            if order + 1 >= orders.0 && order < self.connect_max {
                if let Some(light) = self.light {
                    result += throughput * light.connect(mf, fresnel, &dp, w, pdf_scale, lambda_o);
                }
            }
            // Russian roulette on the weight carried so far (Π F · H_m), played
            // after the estimates of this vertex: they always see the continuous
            // hit probability (a near-vertical upward d_m hits with probability
            // ∝ Λ(d_m) while its NEE phase value ∝ 1/Λ(d_m); a binary decision
            // before the NEE multiplies the variance of order 2 ≈ 2×).
            if j >= RR_START && !russian_roulette_keep(&mut throughput, rng, RR_KEEP) {
                break;
            }
            let (u1, u2) = rng.next2();
            let Some((m, cos_wm, d_next)) = mf.reflect_visible(w, u1, u2) else { break };
            // Along the upward run z only grows (module docs: d'.z > d.z for every
            // front-facing facet, and exactly so in floating point:
            // d'.z = d.z + 2(w·m)m.z with w·m, m.z > 0). Once an upward d.z ≥ ω_o.z
            // no later vertex can reach ω_o: the NEE's half vector has
            // h.z ∝ ω_o.z − d.z ≤ 0 (D = 0), and the connection's y has
            // y.z ≤ ω_o.z ≤ d.z (D = 0 again, or a downward y after an upward
            // direction: non-monotone). Every further estimate is exactly 0.
            let up = d_next.z > 0.0;
            if up && d_next.z >= wo.z {
                break;
            }
            throughput *= fresnel.eval(cos_wm);
            // m is the half vector of w and d_next: density D(m)/(4 A(w)), needed
            // by the MIS weight of the next NEE while the connection serves it.
            if order < self.connect_max {
                pdf_walk = mf.d(m) * pdf_scale;
            }
            let l_next;
            if up {
                l_next = mf.lambda(d_next);
                if !l_next.is_finite() {
                    break;
                }
                let cont = dp.push_up(l_next);
                throughput *= cont;
                if !(cont > 0.0) || !(throughput.max_value() > 0.0) {
                    break;
                }
            } else {
                l_next = mf.abs_lambda(d_next);
                if !l_next.is_finite() || !dp.push_down(l_next) {
                    break;
                }
            }
            w = -d_next;
            pdf_scale = 0.25 / (d_next.z.abs() * l_next);
        }
        result
    }
}

/// (D(h), w·h) for the half vector h of w and x; (0, 0) when w does not see h.
#[inline]
fn half_vector_d(mf: &Microfacet, w: DVec3, x: DVec3) -> (f64, f64) {
    let h = w + x;
    let len = h.length();
    if !(len > 0.0) {
        return (0.0, 0.0);
    }
    let h = h * (1.0 / len);
    let c = w.dot(h);
    if !(c > 0.0) {
        return (0.0, 0.0);
    }
    (mf.d(h), c)
}

/// The one-vertex light subpath of the connection strategy: y = −(ω_o
/// reflected about a visible normal m of ω_o), with everything about it that
/// does not depend on the walk.
struct LightVertex {
    y: DVec3,
    /// |Λ(y)|, and whether y points up.
    l_y: f64,
    up: bool,
    /// Density of y: reflect_pdf(ω_o, −y) = D(m)/(4 A(ω_o)).
    pdf: f64,
    /// reflect_pdf(−y, ω_o) = D(m)/(4 A(−y)): the last vertex's phase value.
    phase: f64,
    /// F(ω_o·m) at the last vertex.
    fresnel: Spectrum,
}

impl LightVertex {
    /// `pdf_scale_o` = 1/(4 A(ω_o)).
    fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, wo: DVec3, pdf_scale_o: f64, rng: &mut Sampler) -> Option<Self> {
        let (u1, u2) = rng.next2();
        let m = mf.sample_visible(wo, u1, u2)?;
        let cos1 = wo.dot(m);
        if !(cos1 > 0.0) {
            return None;
        }
        let y = -reflect(wo, m);
        let up = y.z > 0.0;
        let l_y = if up { mf.lambda(y) } else { mf.abs_lambda(y) };
        let area_y = y.z.abs() * l_y; // A(−y)
        let d_m = mf.d(m);
        let (pdf, phase) = (d_m * pdf_scale_o, 0.25 * d_m / area_y);
        if !(pdf > 0.0) || !(phase > 0.0) || !pdf.is_finite() || !phase.is_finite() || !l_y.is_finite() {
            return None;
        }
        Some(LightVertex { y, l_y, up, pdf, phase, fresnel: fresnel.eval(cos1) })
    }

    /// The connection estimate at vertex m (w = −d_m, `pdf_scale` = 1/(4 A(w))): the path
    /// d_0..d_m, y, ω_o weighted by the balance heuristic against the walk
    /// sampling y from the visible normals of w, divided by the density of
    /// d_1..d_m and by H_m (the caller multiplies by its throughput).
    fn connect(&self, mf: &Microfacet, fresnel: &ConductorFresnel, dp: &MonotoneExit, w: DVec3, pdf_scale: f64, lambda_o: f64) -> Spectrum {
        let (d_h, cos0) = half_vector_d(mf, w, self.y);
        let p_fwd = d_h * pdf_scale; // reflect_pdf(w, y): the walk's density of y
        if !(p_fwd > 0.0) || !p_fwd.is_finite() {
            return Spectrum::ZERO;
        }
        let exit = if self.up { dp.exit_via_up(self.l_y, lambda_o) } else { dp.exit_via_down(self.l_y, lambda_o) };
        // F_m F_y · reflect_pdf(w, y)·reflect_pdf(−y, ω_o)·exit / p_y, times
        // the balance heuristic p_y/(p_fwd + p_y) against the walk.
        let value = p_fwd * self.phase * exit / (p_fwd + self.pdf);
        if !(value > 0.0) || !value.is_finite() {
            return Spectrum::ZERO;
        }
        fresnel.eval(cos0) * self.fresnel * value
    }
}

/// Random-walk sampling of the invariance model: reflect about visible normals
/// and, at each upward direction d_m, leave with probability 1 − H_m/H_{m−1}
/// (the exact conditional exit probability of the heights-integrated walk).
/// The density of the sampled ω_o and order is then the path contribution over
/// Π F, so the weight is Π F (≤ 1 per channel, no roulette needed).
/// `first` = (u_exit, u1, u2) drives the first vertex. Returns None when the
/// walk needs more than min(max_bounces, orders.1) vertices, leaves before
/// orders.0, or meets a degenerate direction — the same truncation as `eval`,
/// so E[weight·g(ω_o)] = ∫ g·eval.
pub fn sample(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if !(wi.z > 0.0) || !wi.is_finite() {
        return None;
    }
    let last = opts.last_order()?;
    let mut dp = MonotoneExit::new(mf.abs_lambda(-wi));
    let (wo, weight, order) = sample_conductor(mf, fresnel, wi, first, last, &mut dp, rng)?;
    (order >= opts.orders.0 && wo.is_finite()).then_some((wo, weight, order))
}

/// The invariance exit: the exact probability of leaving given the monotone
/// run so far; a non-finite Λ ends the walk.
impl ConductorExit for MonotoneExit {
    fn up(&mut self, lambda: f64) -> Option<f64> {
        if !lambda.is_finite() {
            return None;
        }
        Some(self.push_up(lambda))
    }

    fn down(&mut self, l: f64) -> bool {
        l.is_finite() && self.push_down(l)
    }
}

// ---------------------------------------------------------------------------
// The bidirectional estimator: Cui 2023 "the bidirectional estimator is the
// same as Wang et al. except for the segment term", and so it is here — the
// position-free conductor's (src/models/posfree/conductor.rs, on
// src/walk/bdpt.rs) with `WholePath` as its segment term. S_k does not factor
// into pairs, so it is evaluated at each connection from the directions of
// both subpaths.
//
// With v_j = F_j·D(h_j)/(4|cos d_j|) and S_k = p_exit(d_0..d_k)/Π L_j
// (recursion.rs), f = Π_j F_j·pf_j · p_exit, pf_j = D(h_j)/(4 A(−d_j)) the
// camera step's density and pr_j = D(h_j)/(4 A(d_{j+1})) the light step's.
// Strategy s: f/p_s = [Π_{j<s} F_j] · F_s pf_s · [Π_{j>s} F_j A(d_{j+1})/A(−d_j)]
// · p_exit(d_0..d_k): the camera weight is Π F, the light weight the last
// bracket, and the connection adds F_s pf_s times the exit probability of the
// whole path (the camera's exit table extended by the light's directions).

/// The segment term of the invariance model for the position-free conductor's
/// bidirectional estimator: bare pair factors 1/L_j, the whole path's exit
/// probability at each connection, this model's walk above K_b.
struct WholePath;

/// The exit table of the directions d_0..d_m (|Λ| and direction, d_0 first);
/// None on a non-monotone path.
fn exit_table(mut dirs: impl Iterator<Item = (f64, DVec3)>) -> Option<MonotoneExit> {
    let (l0, _) = dirs.next()?;
    let mut dp = MonotoneExit::new(l0);
    for (l, d) in dirs {
        if d.z > 0.0 {
            dp.push_up(l);
        } else if !dp.push_down(l) {
            return None;
        }
    }
    Some(dp)
}

impl ConductorSegments for WholePath {
    #[inline]
    fn cont(&self, _l: f64, _next: DVec3, _l_next: f64) -> f64 {
        1.0
    }

    #[inline]
    fn last(&self, l: f64, _lambda_o: f64) -> f64 {
        1.0 / l
    }

    /// p_exit of d_0..d_s, e_t, …, e_1, ω_o.
    fn whole_path(&self, cam: &[CamVertex], light: &[WalkLight], lambda_o: f64) -> Option<f64> {
        let dirs = cam.iter().map(|c| (c.l, c.d)).chain(light[1..].iter().rev().map(|v| (v.l, v.e)));
        Some(exit_table(dirs)?.exit_probability(lambda_o))
    }

    fn pt_tail(&self, to: Outgoing, cam: &[CamVertex], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let Some(dp) = exit_table(cam.iter().map(|c| (c.l, c.d))) else { return Spectrum::ZERO };
        let cv = &cam[kb as usize];
        let walk = Walk::unidirectional(to.mf, to.fresnel, to.wo, to.lambda_o);
        let state = WalkState { w: -cv.d, pdf_scale: 0.25 / cv.area_back, pdf_walk: 0.0, throughput: cv.thr * dp.hit_probability(), dp };
        walk.from(state, kb, orders, rng)
    }
}

/// BDPT estimate of f(ω_i, ω_o)·cos θ_o of the invariance model: orders up
/// to [`bdpt::DEFAULT_BDPT_ORDERS`] bidirectionally, higher ones by the walk
/// of `eval` (without its connection strategy).
pub fn eval_bdpt(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    if !(wi.z > 0.0) || !(wo.z > 0.0) || !wi.is_finite() || !wo.is_finite() || !mf.lambda(wo).is_finite() {
        return Spectrum::ZERO;
    }
    posfree_conductor::estimate_bdpt(mf, fresnel, &WholePath, wi, wo, opts, bdpt::DEFAULT_BDPT_ORDERS, rng)
}
