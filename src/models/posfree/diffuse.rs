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
//! only pair factors of the conductor (table in `mod.rs`):
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

use super::conductor::{cont, smith};
use super::{Options, Segments};
use crate::microfacet::Microfacet;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use crate::walk::{bdpt, cosine_about, russian_roulette, vertex_numbers, RR_START};
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// PT estimator with next-event estimation of f(ω_i, ω_o)·cos θ_o for the
/// diffuse microsurface of albedo `albedo` (per channel). Orders
/// `opts.walk.orders`, at most `opts.walk.max_bounces` vertices, segment model
/// `opts.segments`.
pub fn eval_pt(mf: &Microfacet, albedo: Spectrum, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let walk = Walk { mf, albedo, wo, lambda_o: mf.lambda(wo), seg: opts.segments };
    walk.from(wi, 1.0 + mf.lambda(wi), Spectrum::ONE, 0, opts.walk.clamped_orders(), rng)
}

/// What the PT walk of a diffuse microsurface needs besides its state.
struct Walk<'a> {
    mf: &'a Microfacet,
    albedo: Spectrum,
    wo: DVec3,
    lambda_o: f64,
    seg: Segments,
}

impl Walk<'_> {
    /// The walk from vertex `first_vertex` (0-based) on, the light arriving
    /// from `w` = −d_j with L_j = `l` and throughput `throughput`: a visible
    /// normal m ~ D_w per vertex serves the NEE, v_j·last = L_j·(a/π)⟨ω_o, m⟩⁺·
    /// last(L_j, Λ_o), and the Lambertian continuation; Russian roulette after
    /// every vertex. Orders `orders` (the upper one within the bounce cap).
    /// Shared by `eval_pt` and the BDPT's tail.
    fn from(&self, mut w: DVec3, mut l: f64, mut throughput: Spectrum, first_vertex: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let mut result = Spectrum::ZERO;
        for j in first_vertex..orders.1 {
            // Λ = 0 (leaves for sure), a horizontal direction (p = 1/L = 0), or nothing left to carry.
            if !(l > 0.0) || !l.is_finite() || !(throughput.max_value() > 0.0) {
                break;
            }
            let order = j + 1;
            let (u1, u2) = rng.next2();
            let Some(m) = self.mf.sample_visible(w, u1, u2) else { break };
            if order >= orders.0 {
                let c = self.wo.dot(m);
                if c > 0.0 {
                    result += throughput * self.albedo * (c * FRAC_1_PI * l * self.seg.last(l, self.lambda_o));
                }
            }
            if order >= orders.1 {
                break;
            }
            let (u3, u4) = rng.next2();
            let d_next = cosine_about(m, u3, u4);
            throughput *= self.albedo;
            if d_next.z > 0.0 {
                let lambda = self.mf.lambda(d_next);
                throughput *= self.seg.continue_up(l, lambda);
                l = lambda;
            } else {
                l = self.mf.abs_lambda(d_next);
            }
            w = -d_next;
            if j + 1 >= RR_START && !russian_roulette(&mut throughput, rng) {
                break;
            }
        }
        result
    }
}

/// Random-walk sampler: returns (ω_o, weight = Π albedo, order) or None when
/// the walk exceeds `opts.walk.max_bounces`. The first vertex uses the caller's
/// (u_exit, u1, u2) for the exit decision and the visible normal; the
/// Lambertian direction and later vertices use `rng`.
pub fn sample_walk(
    mf: &Microfacet,
    albedo: Spectrum,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &Options,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    if wi.z <= 0.0 {
        return None;
    }
    let seg: Segments = opts.segments;
    let mut w = wi;
    let mut l = 1.0 + mf.lambda(wi);
    let mut weight = Spectrum::ONE;
    for j in 0..opts.walk.max_bounces {
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

// ---------------------------------------------------------------------------
// The bidirectional estimator (src/walk/bdpt.rs) of the diffuse microsurface.
//
// # The vertex integral
// With I(d_j, d_{j+1}) = ∫⟨d_{j+1}, m⟩⁺⟨−d_j, m⟩⁺ D(m) dm (no closed form),
// posfree_diffuse's vertex term is v_j = (a/π)·I/|cos d_j| and the path
// contribution is f = Π φ_j, φ_j = v_j·g_j with the conductor's pair factors
// g_j = cont(L_j, d_{j+1})/L_j (j < k−1), g_{k−1} = last(L_{k−1}, Λ_o).
//
// # Sampling densities and the estimator
// - camera step (m ~ D_{−d_j}, d_{j+1} cosine about m):
//   pf_j = I/(π A(−d_j)), so φ_j/pf_j = a·L_j·g_j = a·cont (as PT);
// - light step (the reversed ray arrives along −d_{j+1}: m ~ D_{d_{j+1}},
//   −d_j cosine about m): pr_j = I/(π A(d_{j+1})), so
//   φ_j/pr_j = a·A(d_{j+1})·g_j/|cos d_j| — the same integral I cancels;
// - connection at vertex s: I(d_s, d_{s+1}) is replaced by its unbiased
//   one-sample estimate A(−d_s)·⟨d_{s+1}, m_s⟩⁺ with m_s ~ D_{−d_s}, the normal
//   the camera drew at vertex s (as posfree_diffuse's NEE: m_s is independent
//   of the light subpath and of the camera prefix, so each connection is
//   conditionally unbiased).
//
// # MIS weights
// The exact balance heuristic needs I at every vertex, which has no closed
// form. Any weights w_s(path) ≥ 0 that are deterministic functions of the
// directions d_0..d_k and sum to one over the k strategies keep the sum
// unbiased; they are taken as the balance heuristic of the *surrogate*
// densities p̂f_j = A(d_{j+1})/π, p̂r_j = A(−d_j)/π (each true density with
// I(a, b) replaced by A(−a)·A(b)). Then
//   p̂_{s−1}/p̂_s = ρ_s = A(−d_s)/A(d_s) = |Λ(d_s)|/|Λ(−d_s)|,
// a ratio of a single inner direction, so the weights are path-only, exactly
// computable and independent of the random normals. These weights are not the
// optimal balance heuristic (the surrogate ignores the angular shape of I),
// only a valid partition of unity; the variance gain measured in
// tests/posfree/diffuse_bdpt.rs is what it is.
//

/// A camera vertex: d_s, L_s, A(−d_s), the prefix f/p (a-weighted Π cont) and
/// the normal m_s ~ D_{−d_s} drawn at it (None: not drawn, or no visible normal).
#[derive(Clone, Copy, Default)]
struct CamVertex {
    d: DVec3,
    l: f64,
    area_back: f64,
    thr: Spectrum,
    m: Option<DVec3>,
}

/// A light vertex: e_t = d_{k−t}, |Λ(e_t)|, A(e_t) and Π φ/pr of its t steps.
#[derive(Clone, Copy, Default)]
struct LightVertex {
    e: DVec3,
    l: f64,
    area: f64,
    w: Spectrum,
}

/// The diffuse microsurface's vertex terms for `walk::bdpt`: true densities
/// in the weights f/p, the surrogate densities p̂f_j = A(d_{j+1}),
/// p̂r_j = A(−d_j) (the common 1/π dropped) in the MIS weights.
struct Bidirectional<'a> {
    walk: Walk<'a>,
    wi: DVec3,
}

impl Bidirectional<'_> {
    /// g_j between an arriving direction with |Λ| = `l` and `next` (ω_o when `last`).
    #[inline]
    fn g(&self, l: f64, next: DVec3, l_next: f64, last: bool) -> f64 {
        if last {
            self.walk.seg.last(l, self.walk.lambda_o)
        } else {
            cont(self.walk.seg, l, next, l_next) / l
        }
    }
}

impl bdpt::BdptSurface for Bidirectional<'_> {
    type Cam = CamVertex;
    type Light = LightVertex;
    /// φ_s with I(d_s, d_{s+1}) replaced by its one-sample estimate.
    type Conn = f64;
    type Value = Spectrum;

    fn camera_start(&self) -> CamVertex {
        let mf = self.walk.mf;
        CamVertex { d: -self.wi, l: 1.0 + mf.lambda(self.wi), area_back: mf.projected_area(self.wi), thr: Spectrum::ONE, m: None }
    }

    fn camera_ready(&self, v: &CamVertex) -> bool {
        v.l > 0.0 && v.l.is_finite() && v.thr.max_value() > 0.0
    }

    fn camera_step(&self, v: &mut CamVertex, s: usize, rng: &mut Sampler) -> Option<bdpt::Step<CamVertex>> {
        let mf = self.walk.mf;
        let (u1, u2) = rng.next2();
        let m = mf.sample_visible(-v.d, u1, u2)?;
        v.m = Some(m);
        let (u3, u4) = rng.next2();
        let d_next = cosine_about(m, u3, u4);
        let (l_next, area_next, area_back_next) = smith(mf, d_next);
        if !(l_next > 0.0) || !l_next.is_finite() || !(area_next > 0.0) || !(area_back_next > 0.0) {
            return None;
        }
        let thr = v.thr * self.walk.albedo * cont(self.walk.seg, v.l, d_next, l_next);
        let vertex = CamVertex { d: d_next, l: l_next, area_back: area_back_next, thr, m: None };
        Some(bdpt::Step { vertex, p_in: area_next, p_rev: if s >= 1 { v.area_back } else { 0.0 } })
    }

    fn camera_last(&self, v: &mut CamVertex, rng: &mut Sampler) {
        let (u1, u2) = rng.next2();
        v.m = self.walk.mf.sample_visible(-v.d, u1, u2);
    }

    fn light_start(&self) -> LightVertex {
        let wo = self.walk.wo;
        LightVertex { e: wo, l: self.walk.lambda_o, area: self.walk.mf.projected_area(wo), w: Spectrum::ONE }
    }

    fn light_ready(&self, v: &LightVertex) -> bool {
        v.w.max_value() > 0.0 && v.area > 0.0 && v.area.is_finite()
    }

    fn light_step(&self, v: &LightVertex, t: usize, rng: &mut Sampler) -> Option<bdpt::Step<LightVertex>> {
        let mf = self.walk.mf;
        let (u1, u2) = rng.next2();
        let m = mf.sample_visible(v.e, u1, u2)?;
        let (u3, u4) = rng.next2();
        let e_next = -cosine_about(m, u3, u4); // d_j
        let (l_next, area_next, area_back_next) = smith(mf, e_next);
        let cos_next = e_next.z.abs();
        if !(l_next > 0.0) || !l_next.is_finite() || !(cos_next > 0.0) || !(area_next > 0.0) || !(area_back_next > 0.0) {
            return None;
        }
        let g = self.g(l_next, v.e, v.l, t == 0);
        let w = v.w * self.walk.albedo * (v.area * g / cos_next);
        let vertex = LightVertex { e: e_next, l: l_next, area: area_next, w };
        Some(bdpt::Step { vertex, p_in: area_back_next, p_rev: if t >= 1 { v.area } else { 0.0 } })
    }

    fn connect(&self, cam: &[CamVertex], light: &[LightVertex]) -> Option<bdpt::Connection<f64>> {
        let (s, t) = (cam.len() - 1, light.len() - 1);
        let (cv, lv) = (&cam[s], &light[t]);
        let m = cv.m?;
        if !(cv.thr.max_value() > 0.0) || !(lv.w.max_value() > 0.0) {
            return None;
        }
        let c = lv.e.dot(m);
        if !(c > 0.0) {
            return None;
        }
        // φ_s with I ≈ A(−d_s)⟨d_{s+1}, m_s⟩⁺: (a/π)·L_s·⟨d_{s+1}, m_s⟩⁺·g.
        let phi = c * FRAC_1_PI * cv.l * self.g(cv.l, lv.e, lv.l, t == 0);
        let pr = if s >= 1 { cv.area_back } else { 0.0 };
        let pf = if t >= 1 { lv.area } else { 0.0 };
        Some(bdpt::Connection { pr, pf, data: phi })
    }

    fn weighted(&self, conn: &bdpt::Connection<f64>, cv: &CamVertex, lv: &LightVertex, denom: f64) -> Option<Spectrum> {
        let v = conn.data / denom;
        v.is_finite().then(|| cv.thr * lv.w * self.walk.albedo * v)
    }

    fn pt_tail(&self, cam: &[CamVertex], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Spectrum {
        let cv = &cam[kb as usize];
        self.walk.from(-cv.d, cv.l, cv.thr, kb, orders, rng)
    }
}

/// BDPT estimate of f(ω_i, ω_o)·cos θ_o (orders `opts.walk.orders`), default K_b.
pub fn eval_bdpt(mf: &Microfacet, albedo: Spectrum, wi: DVec3, wo: DVec3, opts: &Options, rng: &mut Sampler) -> Spectrum {
    eval_bdpt_with(mf, albedo, wi, wo, opts, bdpt::DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`bdpt::MAX_BDPT_ORDERS`]) and higher orders by path tracing.
pub fn eval_bdpt_with(mf: &Microfacet, albedo: Spectrum, wi: DVec3, wo: DVec3, opts: &Options, bdpt_orders: u32, rng: &mut Sampler) -> Spectrum {
    if !(wi.z > 0.0) || !(wo.z > 0.0) {
        return Spectrum::ZERO;
    }
    let surface = Bidirectional { walk: Walk { mf, albedo, wo, lambda_o: mf.lambda(wo), seg: opts.segments }, wi };
    bdpt::estimate(&surface, opts.walk.clamped_orders(), bdpt_orders, rng)
}
