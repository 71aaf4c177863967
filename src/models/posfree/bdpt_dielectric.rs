//! Bidirectional estimator of the position-free rough-dielectric BSDF of
//! [`super::dielectric`] (Wang et al. 2022 §4.2 applied to eqs. 2–3,
//! 12–23), for both segment models. Same structure as the conductor BDPT of
//! [`super::bdpt_conductor`]; read that header first.
//!
//! # Directions with media
//! A path of order k is d_0 = −ω_i, d_1, …, d_k = ω_o. Every d_j is stored in
//! global coordinates together with the medium it travels in (side σ_j = +1
//! outside, −1 inside); in that medium's frame it is σ_j·d_j (the frames of
//! `posfree_dielectric.rs`). σ_0 = sign(ω_i.z), σ_k = sign(ω_o.z); the inner
//! media are whatever the subpaths sampled. Vertex j is a reflection when
//! σ_j = σ_{j+1} and a refraction otherwise, so any camera vertex can be joined
//! to any light vertex: the connection is a reflection or a refraction
//! depending on the two media.
//!
//! # Factors
//! With v(a → b) the vertex term of light arriving along a (medium σ_a) and
//! leaving along b (medium σ_b), evaluated in a's frame (w = −σ_a a,
//! o = σ_a b, η_f of σ_a; `vertex_reflect` if σ_a = σ_b else `vertex_transmit`)
//! and L_j = |Λ(σ_j d_j)|, the forward path contribution is
//!
//!   f = Π_{j<k} φ_j,  φ_j = v(d_j → d_{j+1}) · g_j,
//!   g_j = c_j / L_j (j < k−1),  g_{k−1} = last(seg, σ_{k−1} ≠ σ_k, L_{k−1}, Λ_o),
//!
//! c_j the continue factor of `posfree_dielectric` (1 for a direction going
//! down in its own frame), times Mitsuba's Radiance-mode 1/η_r² of the macro
//! pair once. Every φ_j is the forward (ω_i → ω_o) term.
//!
//! # Densities
//! Sampling m ~ D_w (w = −σ_a a) and reflecting with probability F / refracting
//! with 1 − F gives b the solid-angle density
//!
//!   q(a → b) = v(a → b) · |w_z| / A(w) = v(a → b) / |Λ(σ_a a)|
//!
//! (posfree_dielectric's header). The camera step at vertex j samples d_{j+1}
//! with pf_j = q(d_j → d_{j+1}); the light step samples the reversed ray: it
//! arrives along −d_{j+1} in medium σ_{j+1}, scatters with the same sampler to
//! −d_j, so pr_j = q(−d_{j+1} → −d_j) (the medium of d_j is that of the
//! reversed outgoing ray). Strategies, balance-heuristic ratios, fixed-length
//! subpaths without roulette up to K_b and the PT tail above K_b are exactly as
//! in `posfree_bdpt.rs`, with these densities as implemented.

use super::dielectric::{continue_up, last, vertex_reflect, vertex_transmit, RR_NEE_GAIN};
use super::{roulette_importance, Segments};
use crate::models::WalkOptions;
use crate::walk::roulette_scalar;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{reflect, refract, Microfacet};
use crate::rng::Sampler;
use glam::DVec3;

/// Orders handled bidirectionally by default, and at most (as for conductors).
pub use super::bdpt_conductor::{DEFAULT_BDPT_ORDERS, MAX_BDPT_ORDERS};

/// First continuation vertex after which roulette may end the PT tail.
const RR_START: u32 = 1;

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
}

#[inline]
fn eta_f(eta: f64, side: f64) -> f64 {
    if side > 0.0 {
        eta
    } else {
        1.0 / eta
    }
}

/// v(a → b): vertex term in a's frame.
#[inline]
fn vtx(mf: &Microfacet, eta: f64, a: &Dir, b: &Dir) -> f64 {
    let w = -a.side * a.g;
    let o = a.side * b.g;
    let ef = eta_f(eta, a.side);
    if a.side == b.side {
        vertex_reflect(mf, ef, w, o)
    } else {
        vertex_transmit(mf, ef, w, o)
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

/// c of b after a vertex from a (1 for b going down in its frame).
#[inline]
fn cont(seg: Segments, a: &Dir, b: &Dir) -> f64 {
    match b.lambda_up() {
        Some(lam) => continue_up(seg, a.side != b.side, a.l, lam),
        None => 1.0,
    }
}

/// One sampling step from a (arriving): m ~ D_w, reflect with probability F.
#[inline]
fn scatter(mf: &Microfacet, eta: f64, a: &Dir, rng: &mut Sampler) -> Option<Dir> {
    let w = -a.side * a.g;
    let u_choice = rng.next();
    let (u1, u2) = rng.next2();
    let m = mf.sample_visible(w, u1, u2)?;
    let cos_wm = w.dot(m);
    if !(cos_wm > 0.0) {
        return None;
    }
    let (f, cos_t, _, eta_ti) = dielectric_full(cos_wm, eta_f(eta, a.side));
    let (o, side) = if u_choice < f { (reflect(w, m), a.side) } else { (refract(w, m, cos_t, eta_ti), -a.side) };
    let g = a.side * o;
    if !g.is_finite() || g.z == 0.0 {
        return None;
    }
    let d = Dir::new(mf, g, side);
    if !(d.l > 0.0) || !d.l.is_finite() || !(d.r > 0.0) || !d.r.is_finite() {
        return None;
    }
    Some(d)
}

#[derive(Clone, Copy)]
struct CamVertex {
    d: Dir,
    /// Π c of the prefix (= f/p).
    thr: f64,
    /// pf_{s−1}.
    pdf_in: f64,
    /// B_{s−1}.
    left: f64,
}

#[derive(Clone, Copy)]
struct LightVertex {
    /// d_{k−t}.
    e: Dir,
    /// Π φ / pr of the t sampled steps.
    w: f64,
    /// pr of e_t (t ≥ 1).
    pdf_in: f64,
    /// E_{t−1}.
    right: f64,
}

const DIR0: Dir = Dir { g: DVec3::ZERO, side: 1.0, l: 0.0, r: 0.0 };
const CAM0: CamVertex = CamVertex { d: DIR0, thr: 0.0, pdf_in: 0.0, left: 0.0 };
const LIG0: LightVertex = LightVertex { e: DIR0, w: 0.0, pdf_in: 0.0, right: 0.0 };

/// g_j for the vertex from a to b; `b_is_last`: b = ω_o.
#[inline]
fn g_factor(seg: Segments, a: &Dir, b: &Dir, b_is_last: bool, lambda_o: f64) -> f64 {
    if b_is_last {
        last(seg, a.side != b.side, a.l, lambda_o)
    } else {
        cont(seg, a, b) / a.l
    }
}

/// Radiance-mode factor 1/η_r² for a transmission pair.
#[inline]
fn mode_scale(eta: f64, radiance: bool, wi: DVec3, wo_z: f64) -> f64 {
    if radiance && wi.z * wo_z < 0.0 {
        let eta_r = if wi.z > 0.0 { eta } else { 1.0 / eta };
        1.0 / (eta_r * eta_r)
    } else {
        1.0
    }
}

/// BDPT estimate of f(ω_i, ω_o)·|cos θ_o| (orders `opts.orders`), default K_b.
pub fn eval_bdpt(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> f64 {
    eval_bdpt_with(mf, eta, radiance, wi, wo, opts, DEFAULT_BDPT_ORDERS, rng)
}

/// BDPT estimate with orders 1..=`bdpt_orders` bidirectional (clamped to
/// 1..=[`MAX_BDPT_ORDERS`]) and higher orders by path tracing.
#[allow(clippy::too_many_arguments)]
pub fn eval_bdpt_with(
    mf: &Microfacet,
    eta: f64,
    radiance: bool,
    wi: DVec3,
    wo: DVec3,
    opts: &WalkOptions,
    bdpt_orders: u32,
    rng: &mut Sampler,
) -> f64 {
    if !(eta > 0.0) || !eta.is_finite() || wi.z == 0.0 || wo.z == 0.0 || !wi.is_finite() || !wo.is_finite() {
        return 0.0;
    }
    let seg = opts.segments;
    let (o_lo, o_hi) = (opts.orders.0.max(1), opts.orders.1.min(opts.max_bounces));
    if o_lo > o_hi {
        return 0.0;
    }
    let kb = o_hi.min(bdpt_orders.clamp(1, MAX_BDPT_ORDERS));
    let pt_tail = o_hi > kb;
    let side_i = if wi.z > 0.0 { 1.0 } else { -1.0 };
    let side_o = if wo.z > 0.0 { 1.0 } else { -1.0 };
    let d0 = Dir::new(mf, -wi, side_i);
    let dk = Dir::new(mf, wo, side_o);
    let lambda_o = dk.l; // ω_o points up in its own frame
    let mut result = 0.0f64;

    // ---- camera subpath
    let n_c_target = if pt_tail { kb } else { kb - 1 } as usize;
    let mut cam = [CAM0; MAX_BDPT_ORDERS as usize + 1];
    cam[0] = CamVertex { d: d0, thr: 1.0, pdf_in: 0.0, left: 0.0 };
    let mut n_c = 0usize;
    let mut b_acc = 0.0;
    while n_c < n_c_target {
        let s = n_c;
        let cv = cam[s];
        if !(cv.d.l > 0.0) || !cv.d.l.is_finite() || !(cv.thr > 0.0) {
            break;
        }
        let Some(dn) = scatter(mf, eta, &cv.d, rng) else { break };
        let v = vtx(mf, eta, &cv.d, &dn);
        let pf = dens(v, &cv.d);
        if !(pf > 0.0) {
            break;
        }
        let left_for_next = if s >= 1 {
            let pr = dens(vtx(mf, eta, &dn.reversed(), &cv.d.reversed()), &dn.reversed());
            b_acc = pr / cv.pdf_in * (1.0 + b_acc);
            b_acc
        } else {
            0.0
        };
        let thr = cv.thr * cont(seg, &cv.d, &dn);
        cam[s + 1] = CamVertex { d: dn, thr, pdf_in: pf, left: left_for_next };
        n_c += 1;
    }

    // ---- light subpath e_0 = ω_o, e_1 = d_{k−1}, …
    if o_lo <= kb {
        let mut lig = [LIG0; MAX_BDPT_ORDERS as usize + 1];
        let mut n_l = 0usize;
        lig[0] = LightVertex { e: dk, w: 1.0, pdf_in: 0.0, right: 0.0 };
        let mut e_acc = 0.0;
        while n_l + 1 < kb as usize {
            let t = n_l;
            let lv = lig[t];
            if !(lv.w > 0.0) {
                break;
            }
            let rev = lv.e.reversed();
            let Some(b) = scatter(mf, eta, &rev, rng) else { break };
            let dj = b.reversed(); // d_j, forward direction arriving at vertex j
            let pr = dens(vtx(mf, eta, &rev, &b), &rev);
            if !(pr > 0.0) || !(dj.l > 0.0) || !dj.l.is_finite() {
                break;
            }
            let v = vtx(mf, eta, &dj, &lv.e);
            let phi = v * g_factor(seg, &dj, &lv.e, t == 0, lambda_o);
            let w = lv.w * phi / pr;
            let right_for_next = if t >= 1 {
                let pf = dens(v, &dj);
                e_acc = pf / lv.pdf_in * (1.0 + e_acc);
                e_acc
            } else {
                0.0
            };
            lig[t + 1] = LightVertex { e: dj, w: if w.is_finite() { w } else { 0.0 }, pdf_in: pr, right: right_for_next };
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
                if !(cv.thr > 0.0) || !(lv.w > 0.0) || !(cv.d.l > 0.0) || !cv.d.l.is_finite() {
                    continue;
                }
                let v = vtx(mf, eta, &cv.d, &lv.e);
                if !(v > 0.0) {
                    continue;
                }
                let phi = v * g_factor(seg, &cv.d, &lv.e, t == 0, lambda_o);
                let mut denom = 1.0;
                if s >= 1 {
                    let rev = lv.e.reversed();
                    let pr_s = dens(vtx(mf, eta, &rev, &cv.d.reversed()), &rev);
                    denom += pr_s / cv.pdf_in * (1.0 + cv.left);
                }
                if t >= 1 {
                    let pf_s = dens(v, &cv.d);
                    denom += pf_s / lv.pdf_in * (1.0 + lv.right);
                }
                let c = cv.thr * phi * lv.w / denom;
                if c.is_finite() {
                    result += c;
                }
            }
        }
    }

    // ---- orders kb+1 ..= o_hi: the camera subpath continues as PT with NEE.
    if pt_tail && n_c == kb as usize {
        let mut a = cam[kb as usize].d;
        let mut throughput = cam[kb as usize].thr;
        for j in kb..opts.max_bounces {
            if !(a.l > 0.0) || !a.l.is_finite() || !(throughput > 0.0) {
                break;
            }
            let order = j + 1;
            let lst = last(seg, a.side != dk.side, a.l, lambda_o);
            let v = if order >= o_lo && order <= o_hi { vtx(mf, eta, &a, &dk) * lst } else { 0.0 };
            let v = if v.is_finite() { v } else { 0.0 };
            if j >= kb + RR_START && !roulette_scalar(&mut throughput, rng, 1.0 / roulette_importance(v, lst, RR_NEE_GAIN)) {
                break;
            }
            result += throughput * v;
            if order >= o_hi {
                break;
            }
            let Some(dn) = scatter(mf, eta, &a, rng) else { break };
            throughput *= cont(seg, &a, &dn);
            a = dn;
        }
    }
    let value = result * mode_scale(eta, radiance, wi, wo.z);
    if value.is_finite() && value > 0.0 {
        value
    } else {
        0.0
    }
}
