//! Bidirectional estimator of the position-free rough *diffuse* microsurface of
//! [`super::diffuse`] (Lambertian facets, Wang 2022 segment terms), for
//! both segment models. Structure as in [`super::bdpt_conductor`] (read it first).
//!
//! # The vertex integral
//! With I(d_j, d_{j+1}) = ∫⟨d_{j+1}, m⟩⁺⟨−d_j, m⟩⁺ D(m) dm (no closed form),
//! posfree_diffuse's vertex term is v_j = (a/π)·I/|cos d_j| and the path
//! contribution is f = Π φ_j, φ_j = v_j·g_j with the conductor's pair factors
//! g_j = cont(L_j, d_{j+1})/L_j (j < k−1), g_{k−1} = last(L_{k−1}, Λ_o).
//!
//! # Sampling densities and the estimator
//! - camera step (m ~ D_{−d_j}, d_{j+1} cosine about m):
//!   pf_j = I/(π A(−d_j)), so φ_j/pf_j = a·L_j·g_j = a·cont (as PT);
//! - light step (the reversed ray arrives along −d_{j+1}: m ~ D_{d_{j+1}},
//!   −d_j cosine about m): pr_j = I/(π A(d_{j+1})), so
//!   φ_j/pr_j = a·A(d_{j+1})·g_j/|cos d_j| — the same integral I cancels;
//! - connection at vertex s: I(d_s, d_{s+1}) is replaced by its unbiased
//!   one-sample estimate A(−d_s)·⟨d_{s+1}, m_s⟩⁺ with m_s ~ D_{−d_s}, the normal
//!   the camera drew at vertex s (as posfree_diffuse's NEE: m_s is independent
//!   of the light subpath and of the camera prefix, so each connection is
//!   conditionally unbiased).
//!
//! # MIS weights
//! The exact balance heuristic needs I at every vertex, which has no closed
//! form. Any weights w_s(path) ≥ 0 that are deterministic functions of the
//! directions d_0..d_k and sum to one over the k strategies keep the sum
//! unbiased; they are taken as the balance heuristic of the *surrogate*
//! densities p̂f_j = A(d_{j+1})/π, p̂r_j = A(−d_j)/π (each true density with
//! I(a, b) replaced by A(−a)·A(b)). Then
//!   p̂_{s−1}/p̂_s = ρ_s = A(−d_s)/A(d_s) = |Λ(d_s)|/|Λ(−d_s)|,
//! a ratio of a single inner direction, so the weights are path-only, exactly
//! computable and independent of the random normals. These weights are not the
//! optimal balance heuristic (the surrogate ignores the angular shape of I),
//! only a valid partition of unity; the variance gain measured in
//! tests/bdpt_diffuse.rs is what it is.
//!
//! Fixed-length subpaths without roulette for orders ≤ K_b, PT tail (with NEE
//! as posfree_diffuse::eval_pt) above K_b.

use crate::models::WalkOptions;
use crate::walk::{cosine_about, russian_roulette};
use crate::microfacet::Microfacet;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// Orders handled bidirectionally by default, and at most (as for conductors).
pub use super::bdpt_conductor::{DEFAULT_BDPT_ORDERS, MAX_BDPT_ORDERS};
use super::bdpt_conductor::{cont, smith};

const RR_START: u32 = 1;

#[derive(Clone, Copy)]
struct CamVertex {
    /// d_s.
    d: DVec3,
    /// L_s.
    l: f64,
    /// a-weighted Π cont of the prefix (= f/p).
    thr: Spectrum,
    /// Σ_{s'<s} p̂_{s'}/p̂_s.
    left: f64,
    /// m_s ~ D_{−d_s} (None: not drawn / no visible normal).
    m: Option<DVec3>,
}

#[derive(Clone, Copy)]
struct LightVertex {
    /// e_t = d_{k−t}.
    e: DVec3,
    /// |Λ(e_t)|.
    l: f64,
    /// A(e_t).
    area: f64,
    /// Π φ/pr of the t sampled steps.
    w: Spectrum,
    /// Σ_{s'>s} p̂_{s'}/p̂_s for a connection with this vertex as d_{s+1}.
    right: f64,
}

const CAM0: CamVertex = CamVertex { d: DVec3::ZERO, l: 0.0, thr: Spectrum::ZERO, left: 0.0, m: None };
const LIG0: LightVertex = LightVertex { e: DVec3::ZERO, l: 0.0, area: 0.0, w: Spectrum::ZERO, right: 0.0 };

/// BDPT estimate of f(ω_i, ω_o)·cos θ_o (orders `opts.orders`), default K_b.
pub fn eval_bdpt(mf: &Microfacet, albedo: Spectrum, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    eval_bdpt_with(mf, albedo, wi, wo, opts, DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`MAX_BDPT_ORDERS`]) and higher orders by path tracing.
pub fn eval_bdpt_with(
    mf: &Microfacet,
    albedo: Spectrum,
    wi: DVec3,
    wo: DVec3,
    opts: &WalkOptions,
    bdpt_orders: u32,
    rng: &mut Sampler,
) -> Spectrum {
    if !(wi.z > 0.0) || !(wo.z > 0.0) {
        return Spectrum::ZERO;
    }
    let seg = opts.segments;
    let (o_lo, o_hi) = (opts.orders.0.max(1), opts.orders.1.min(opts.max_bounces));
    if o_lo > o_hi {
        return Spectrum::ZERO;
    }
    let kb = o_hi.min(bdpt_orders.clamp(1, MAX_BDPT_ORDERS));
    let pt_tail = o_hi > kb;
    let lambda_o = mf.lambda(wo);
    let mut result = Spectrum::ZERO;

    // ---- camera subpath: normals m_0..m_{kb−1}, directions d_1..d_{n_c}
    let n_c_target = if pt_tail { kb } else { kb - 1 } as usize;
    let mut cam = [CAM0; MAX_BDPT_ORDERS as usize + 1];
    cam[0] = CamVertex { d: -wi, l: 1.0 + mf.lambda(wi), thr: Spectrum::ONE, left: 0.0, m: None };
    let mut n_c = 0usize;
    for s in 0..kb as usize {
        let cv = cam[s];
        if !(cv.l > 0.0) || !cv.l.is_finite() {
            break;
        }
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(-cv.d, u1, u2) else { break };
        cam[s].m = Some(m);
        if s >= n_c_target {
            break;
        }
        let (u3, u4) = rng.next2();
        let d_next = cosine_about(m, u3, u4);
        let (l_next, area_next, area_back_next) = smith(mf, d_next);
        if !(l_next > 0.0) || !l_next.is_finite() || !(area_next > 0.0) || !(area_back_next > 0.0) {
            break;
        }
        let thr = cv.thr * albedo * cont(seg, cv.l, d_next, l_next);
        // ρ_{s+1} = A(−d_{s+1})/A(d_{s+1}); left_{s+1} = ρ_{s+1}(1 + left_s) (left_0 = 0, no term for s = 0).
        let rho = area_back_next / area_next;
        let left = rho * (1.0 + if s >= 1 { cv.left } else { 0.0 });
        cam[s + 1] = CamVertex { d: d_next, l: l_next, thr, left, m: None };
        n_c = s + 1;
        if !(thr.max_value() > 0.0) {
            break;
        }
    }

    // ---- light subpath e_0 = ω_o, e_1 = d_{k−1}, …
    if o_lo <= kb {
        let mut lig = [LIG0; MAX_BDPT_ORDERS as usize + 1];
        let mut n_l = 0usize;
        lig[0] = LightVertex { e: wo, l: lambda_o, area: mf.projected_area(wo), w: Spectrum::ONE, right: 0.0 };
        while n_l + 1 < kb as usize {
            let t = n_l;
            let lv = lig[t];
            if !(lv.w.max_value() > 0.0) || !(lv.area > 0.0) || !lv.area.is_finite() {
                break;
            }
            let (u1, u2) = rng.next2();
            let Some(m) = mf.sample_visible(lv.e, u1, u2) else { break };
            let (u3, u4) = rng.next2();
            let e_next = -cosine_about(m, u3, u4); // d_j
            let (l_next, area_next, area_back_next) = smith(mf, e_next);
            let cos_next = e_next.z.abs();
            if !(l_next > 0.0) || !l_next.is_finite() || !(cos_next > 0.0) || !(area_next > 0.0) || !(area_back_next > 0.0) {
                break;
            }
            let g = if t == 0 { seg.last(l_next, lambda_o) } else { cont(seg, l_next, lv.e, lv.l) / l_next };
            let w = lv.w * albedo * (lv.area * g / cos_next);
            // 1/ρ_j of the new inner direction d_j; right = (1/ρ_j)(1 + right_prev).
            let inv_rho = area_next / area_back_next;
            let right = inv_rho * (1.0 + if t >= 1 { lv.right } else { 0.0 });
            lig[t + 1] = LightVertex { e: e_next, l: l_next, area: area_next, w, right };
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
                let Some(m) = cv.m else { continue };
                if !(cv.thr.max_value() > 0.0) || !(lv.w.max_value() > 0.0) {
                    continue;
                }
                let c = lv.e.dot(m);
                if !(c > 0.0) {
                    continue;
                }
                let g = if t == 0 { seg.last(cv.l, lambda_o) } else { cont(seg, cv.l, lv.e, lv.l) / cv.l };
                // φ_s with I ≈ A(−d_s)⟨d_{s+1}, m_s⟩⁺: (a/π)·L_s·⟨d_{s+1}, m_s⟩⁺·g.
                let phi = c * FRAC_1_PI * cv.l * g;
                let mut denom = 1.0;
                if s >= 1 {
                    denom += cv.left;
                }
                if t >= 1 {
                    denom += lv.right;
                }
                let v = phi / denom;
                if v.is_finite() {
                    result += cv.thr * lv.w * albedo * v;
                }
            }
        }
    }

    // ---- orders kb+1 ..= o_hi: the camera subpath continues as PT with NEE.
    if pt_tail && n_c == kb as usize {
        let cv = cam[kb as usize];
        let mut w = -cv.d;
        let mut l = cv.l;
        let mut throughput = cv.thr;
        for j in kb..opts.max_bounces {
            if !(l > 0.0) || !l.is_finite() || !(throughput.max_value() > 0.0) {
                break;
            }
            let order = j + 1;
            let (u1, u2) = rng.next2();
            let Some(m) = mf.sample_visible(w, u1, u2) else { break };
            if order >= o_lo && order <= o_hi {
                let c = wo.dot(m);
                if c > 0.0 {
                    result += throughput * albedo * (c * FRAC_1_PI * l * seg.last(l, lambda_o));
                }
            }
            if order >= o_hi {
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
            w = -d_next;
            if j + 1 >= kb + RR_START && !russian_roulette(&mut throughput, rng) {
                break;
            }
        }
    }
    result
}
