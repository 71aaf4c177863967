//! The height-explicit random walk on the Smith microsurface of Heitz et al.
//! 2016, "Multiple-scattering microfacet BSDFs with the Smith model" (conductor
//! §3.2, diffuse §3.3, dielectric §3.4 of the implementation supplement): the
//! whole of `model="heitz"` (`models/heitz/`), and the tail of the invariance
//! model's dielectric walk (`models/invariance/dielectric.rs`), which hands its
//! path over after the first refraction.
//!
//! **API.** [`eval`] and [`sample`] run a walk from ω_i; [`eval_from`] and
//! [`sample_from`] continue one from a [`State`] another walk built
//! ([`State::after_refraction`]); [`local`], [`visible_normal`] and
//! [`dielectric_phase`] are the frame and vertex terms such a walk shares with
//! this one. The height machinery ([`sample_height`], [`sample_height_hit`],
//! [`masking_at`], [`flip_height`]) is public for the tests of supplement §4.1.
//!
//! **Heights.** The BSDF does not depend on the height distribution (supplement
//! §1); we use Heitz's uniform distribution on [−1, 1] and carry the height as
//! t = ln C¹(h) ∈ (−∞, 0] (C¹ the height CDF, t = 0 at the top of the
//! microsurface). In that variable the supplement's Algorithm 1 becomes a
//! free flight with an exponential optical depth E = −ln(1 − U):
//!
//! * upward ray (Λ(ω) ≥ 0): t' = t + E/Λ(ω); the ray leaves when t' ≥ 0, which
//!   happens with probability C¹(h)^Λ = e^{Λt} = G1(ω, h);
//! * downward ray: t' = t − E/|Λ(ω)| (always hits; |Λ| ≥ 1);
//! * Λ = 0 (straight up) leaves; Λ = ∞ (horizontal) hits at the same height.
//!
//! The masking of ω_o at height t is G1(ω_o, h) = e^{Λ(ω_o)·t}.
//!
//! **Sides (dielectric).** As in the supplement, the inside of the material is
//! seen as the vertically flipped microsurface. Each side has its local frame:
//! the identity outside, the point reflection v ↦ −v inside (D and Λ are even in
//! (x, y), so this is the flipped surface); in its own frame a side always sees
//! the standard microsurface from above, with relative IOR η (outside) or 1/η
//! (inside). Crossing the interface maps the height to the flipped one,
//! C¹ ↦ 1 − C¹ (the uniform distribution is symmetric), t ↦ ln(1 − e^t).
//!
//! **Dielectric transport mode.** The walk with the supplement's phase function
//! (η_o² in the transmission term, F as the reflect/refract probability) yields
//! the unscaled (Importance-mode) BSDF, which conserves energy and satisfies
//! f(ω_i, ω_o)/η_o² = f(ω_o, ω_i)/η_i² (η_· the absolute IOR of the side of the
//! direction). With `radiance = true` a result whose ω_o lies on the other side
//! of the macro surface than ω_i is multiplied by 1/η_rel², η_rel = η(ω_o side)/
//! η(ω_i side) — the factor of Mitsuba's roughdielectric. Along a path the
//! per-crossing factors telescope, so applying it once at the end is exact
//! (a path that crosses twice and comes back carries no factor).
//!
//! `eval` returns one unbiased estimate of f(ω_i, ω_o)·|cos θ_o| (Algorithm 2:
//! forward walk from ω_i with next-event estimation towards ω_o at every
//! vertex, phase function × G1(ω_o, h)). One change to Algorithm 2: a ray
//! leaving the microsurface contributes nothing to eval, so every height step
//! is conditioned on hitting and the throughput carries the hit probability
//! 1 − G1(ω, h) instead (its expectation; Russian roulette then ends the
//! walk). With the binary exit test the estimator has infinite variance: a
//! near-vertical upward ray hits with probability ∝ Λ while the phase function
//! at that vertex is ∝ 1/A(ω) ∝ 1/Λ (log-divergent second moment; it showed as
//! 10–25 % errors in the dielectric furnace). `sample` runs the walk without
//! NEE and returns the exit direction (Algorithm 3) with the product of the
//! per-vertex weights (Fresnel for conductors, albedo for diffuse, 1 for
//! dielectrics).

use super::{cosine_about, russian_roulette, WalkOptions};
use crate::microfacet::dielectric::{eta_seen, radiance_scale, refract_unit, valid_ior};
use crate::microfacet::{fresnel, reflect, Microfacet, Microsurface};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::f64::consts::PI;

// ---------------------------------------------------------------------------
// Height machinery (public so that the tests can check supplement §4.1).

/// Next intersection of a ray travelling along `w` (local frame of the current
/// side) from height t = ln C¹(h) ≤ 0, with U = `u` ∈ [0, 1). `None`: the ray
/// leaves the microsurface.
#[inline]
pub fn sample_height(mf: &Microfacet, w: DVec3, t: f64, u: f64) -> Option<f64> {
    let e = -(1.0 - u).ln(); // Exp(1) optical depth, finite for u < 1
    if w.z > 0.0 {
        let l = mf.lambda(w);
        if !(l > 0.0) {
            return None; // Λ = 0: a vertical ray never meets the surface again
        }
        let tn = t + e / l; // Λ = ∞ (numerically horizontal): same height
        if tn >= 0.0 || tn.is_nan() {
            None
        } else {
            Some(tn)
        }
    } else {
        // |Λ| ≥ 1; ∞ for a horizontal ray (stays at its height).
        let l = mf.abs_lambda(w);
        let tn = t - e / l;
        if tn.is_nan() {
            None
        } else {
            Some(tn)
        }
    }
}

/// Next intersection conditioned on hitting the microsurface: returns
/// (t', P_hit) with P_hit = 1 − G1(ω, h) the probability that the ray hits,
/// t' distributed as the hit height of [`sample_height`] given a hit.
/// Downward rays always hit (P_hit = 1). P_hit = 0 when the ray surely leaves.
#[inline]
pub fn sample_height_hit(mf: &Microfacet, w: DVec3, t: f64, u: f64) -> (f64, f64) {
    if w.z > 0.0 {
        let l = mf.lambda(w);
        if !(l > 0.0) || t >= 0.0 {
            return (t, 0.0);
        }
        if l == f64::INFINITY {
            return (t, 1.0); // horizontal: hits at its height
        }
        let p_hit = -(l * t).exp_m1();
        // Exp(1) truncated to [0, −Λt): E = −ln(1 − U·P_hit).
        let tn = t - (-u * p_hit).ln_1p() / l;
        if !(p_hit > 0.0) || tn.is_nan() {
            return (t, 0.0);
        }
        (tn.min(0.0), p_hit.min(1.0))
    } else {
        match sample_height(mf, w, t, u) {
            Some(tn) => (tn, 1.0),
            None => (t, 0.0),
        }
    }
}

/// Masking of the upward direction `w` (local frame) at height t:
/// G1(ω, h) = C¹(h)^Λ(ω) = e^{Λ t}. Zero for directions not pointing up.
#[inline]
pub fn masking_at(mf: &Microfacet, w: DVec3, t: f64) -> f64 {
    if !(w.z > 0.0) {
        return 0.0;
    }
    let l = mf.lambda(w);
    if !(l > 0.0) || t >= 0.0 {
        return 1.0;
    }
    let g = (l * t).exp(); // Λ = ∞ → 0
    if g.is_finite() {
        g
    } else {
        0.0
    }
}

/// Height seen from the other side: ln(1 − e^t), without cancellation.
#[inline]
pub fn flip_height(t: f64) -> f64 {
    if t < -std::f64::consts::LN_2 {
        (-t.exp()).ln_1p()
    } else {
        (-t.exp_m1()).ln()
    }
}

// ---------------------------------------------------------------------------
// Small geometry helpers.

#[inline]
pub fn local(v: DVec3, outside: bool) -> DVec3 {
    if outside {
        v
    } else {
        -v
    }
}

// ---------------------------------------------------------------------------
// Phase functions (local frame of the current side: wi points away from the
// surface towards where the light comes from; the surface is the standard one).

/// Conductor phase function × Fresnel at ω_o (same side): F·D_ωi(h)/(4 ωi·h).
#[inline]
fn conductor_phase(mf: &Microfacet, wi: DVec3, wo: DVec3) -> Option<(f64, f64)> {
    let h = wi + wo;
    let len = h.length();
    if !(len > 1e-12) {
        return None;
    }
    let h = h / len;
    let c = wi.dot(h);
    if !(c > 0.0) || h.z <= 0.0 {
        return None;
    }
    let p = mf.d_visible(wi, h) / (4.0 * c);
    if p.is_finite() && p > 0.0 {
        Some((p, c))
    } else {
        None
    }
}

/// Dielectric phase function (supplement §3.4) for ω_o on the same side
/// (reflection, `same = true`) or on the other side (transmission; ω_o in the
/// current local frame points down). `eta` = relative IOR of the far side.
#[inline]
pub fn dielectric_phase(mf: &Microfacet, wi: DVec3, wo: DVec3, eta: f64, same: bool) -> f64 {
    if same {
        match conductor_phase(mf, wi, wo) {
            Some((p, c)) => p * fresnel::dielectric(c, eta),
            None => 0.0,
        }
    } else {
        // Generalised half vector ∝ −(ωi + η ωo), oriented to the incident side.
        let h = -(wi + wo * eta);
        let len = h.length();
        if !(len > 1e-12) {
            return 0.0;
        }
        let mut h = h / len;
        if h.z < 0.0 {
            h = -h;
        }
        let ci = wi.dot(h);
        let co = wo.dot(h);
        if !(ci > 0.0) || !(co < 0.0) {
            return 0.0;
        }
        let f = fresnel::dielectric(ci, eta);
        if f >= 1.0 {
            return 0.0;
        }
        let denom = ci + eta * co;
        let v = eta * eta * (1.0 - f) * mf.d_visible(wi, h) * (-co) / (denom * denom);
        if v.is_finite() && v > 0.0 {
            v
        } else {
            0.0
        }
    }
}

// ---------------------------------------------------------------------------
// The walk.

/// Result of scattering at a vertex: the new travel direction (local frame of
/// the new side), whether the side changed, and the vertex weight.
struct Scatter {
    dir: DVec3,
    crossed: bool,
    weight: Spectrum,
}

/// Samples the phase function at a vertex: `wi` (local) points back along the
/// incoming ray, m is a visible normal of wi already drawn, (ua, ub) further
/// numbers (diffuse direction, or ua = Fresnel choice for dielectrics).
#[inline]
fn scatter(mat: &Microsurface, wi: DVec3, m: DVec3, outside: bool, ua: f64, ub: f64) -> Option<Scatter> {
    let c = wi.dot(m);
    if !(c > 0.0) {
        return None;
    }
    match mat {
        Microsurface::Conductor(fr) => Some(Scatter { dir: reflect(wi, m), crossed: false, weight: fr.eval(c) }),
        Microsurface::Diffuse { albedo } => Some(Scatter { dir: cosine_about(m, ua, ub), crossed: false, weight: *albedo }),
        Microsurface::Dielectric { eta, .. } => {
            let e = eta_seen(*eta, outside);
            if ua < fresnel::dielectric(c, e) {
                return Some(Scatter { dir: reflect(wi, m), crossed: false, weight: Spectrum::ONE });
            }
            match refract_unit(wi, m, c, e) {
                // In the new side's frame (point reflection) the ray travels upward.
                Some(o) => Some(Scatter { dir: -o, crossed: true, weight: Spectrum::ONE }),
                None => Some(Scatter { dir: reflect(wi, m), crossed: false, weight: Spectrum::ONE }),
            }
        }
    }
}

/// Draws the visible normal of `wi` (local frame).
#[inline]
pub fn visible_normal(mf: &Microfacet, wi: DVec3, u1: f64, u2: f64) -> Option<DVec3> {
    let m = mf.sample_visible(wi, u1, u2)?;
    if m.is_finite() && wi.dot(m) > 0.0 {
        Some(m)
    } else {
        None
    }
}

/// State of a walk between two vertices: the medium the ray travels in
/// (`outside`), its direction in that medium's local frame, its height
/// t = ln C¹(h) (0 = above the microsurface), the throughput, and the order of
/// the vertex it will reach next (1 = first).
#[derive(Clone, Copy, Debug)]
pub struct State {
    outside: bool,
    dir: DVec3,
    t: f64,
    throughput: Spectrum,
    next_order: u32,
}

impl State {
    /// A walk entering the microsurface from the side of ω_i, above it.
    fn start(wi: DVec3) -> Self {
        let outside = wi.z > 0.0;
        State { outside, dir: -local(wi, outside), t: 0.0, throughput: Spectrum::ONE, next_order: 1 }
    }

    /// The state after a refraction at height t (of the side the ray leaves):
    /// the other medium, the refracted direction `o` given in the old frame,
    /// the flipped height.
    pub fn after_refraction(outside: bool, o: DVec3, t: f64, throughput: Spectrum, next_order: u32) -> Self {
        State { outside: !outside, dir: -o, t: flip_height(t), throughput, next_order }
    }

    /// The scattering of `eval_from` and `sample_from` at the vertex the ray
    /// has just reached, on the visible normal m of −dir with the numbers
    /// (ua, ub) of [`scatter`]: the new direction and throughput, the other
    /// side and the flipped height after a refraction, then Russian roulette.
    /// False when the walk ends there.
    fn scatter(&mut self, mat: &Microsurface, m: DVec3, ua: f64, ub: f64, rng: &mut Sampler) -> bool {
        let Some(s) = scatter(mat, -self.dir, m, self.outside, ua, ub) else { return false };
        if !s.dir.is_finite() {
            return false;
        }
        self.throughput *= s.weight;
        self.dir = s.dir;
        if s.crossed {
            self.outside = !self.outside;
            self.t = flip_height(self.t);
        }
        russian_roulette(&mut self.throughput, rng)
    }
}

/// Checks shared by `eval` and `sample`: finite directions, the upper
/// hemisphere for conductor and diffuse, a usable IOR for dielectrics.
fn valid_incidence(mat: &Microsurface, wi: DVec3) -> bool {
    if !wi.is_finite() {
        return false;
    }
    match mat {
        Microsurface::Conductor(_) | Microsurface::Diffuse { .. } => wi.z > 0.0,
        Microsurface::Dielectric { eta, .. } => wi.z != 0.0 && valid_ior(*eta),
    }
}

/// One unbiased estimate of f(ω_i, ω_o)·|cos θ_o| restricted to the scattering
/// orders `opts.orders` (1 = single scattering) and at most `opts.max_bounces`
/// vertices.
pub fn eval(mf: &Microfacet, surf: &Microsurface, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    let mat = *surf;
    if !valid_incidence(&mat, wi) || !valid_incidence(&mat, wo) {
        return Spectrum::ZERO;
    }
    let mut sum = eval_from(mf, surf, wo, State::start(wi), opts, rng);
    if let Microsurface::Dielectric { eta, radiance } = mat {
        sum *= radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0);
    }
    sum
}

/// Heitz's eval walk (NEE towards ω_o at every vertex) from `state` on: the
/// contributions of the vertices of order `state.next_order` and later, scaled
/// by `state.throughput`, within `opts.orders` and `opts.max_bounces`. No
/// Radiance-mode 1/η² (the caller applies it once for the whole path).
/// Public so that a model that integrates the heights of the first vertices
/// exactly can hand the rest of a path to this walk.
/// One loop over the vertices: its steps (next event, roulette, scattering,
/// exit bookkeeping) share the walk's state.
pub fn eval_from(mf: &Microfacet, surf: &Microsurface, wo: DVec3, state: State, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    let mat = *surf;
    let Some(last) = opts.last_order().filter(|&last| state.next_order <= last) else { return Spectrum::ZERO };
    let wo_outside = wo.z > 0.0;
    let mut ray = state;
    let mut sum = Spectrum::ZERO;

    for order in ray.next_order..=last {
        // Next intersection. Leaving contributes nothing to eval, so the hit is
        // forced and weighted by its probability (expected value of Heitz's
        // exit test). This keeps the NEE bounded: a near-vertical upward ray
        // hits with probability ∝ Λ while its phase function (∝ 1/A(ω_i) =
        // 1/Λ) is huge — with a binary exit test the estimator's variance
        // diverges logarithmically (observed in the dielectric furnace).
        let (tn, p_hit) = sample_height_hit(mf, ray.dir, ray.t, rng.next());
        if !(p_hit > 0.0) {
            break;
        }
        ray.t = tn;
        ray.throughput *= p_hit;
        let wi_l = -ray.dir;
        let wo_l = local(wo, ray.outside);
        // A normal visible from wi_l: the diffuse NEE and the continuation
        // share it (both unbiased; linearity of expectation).
        let need_m = order < last || (order >= opts.orders.0 && matches!(mat, Microsurface::Diffuse { .. }));
        let m = if need_m {
            let (u1, u2) = rng.next2();
            visible_normal(mf, wi_l, u1, u2)
        } else {
            None
        };

        // Next-event estimation towards ω_o: phase function × G1(ω_o, h).
        if order >= opts.orders.0 {
            let contrib = match mat {
                Microsurface::Conductor(fr) => match conductor_phase(mf, wi_l, wo_l) {
                    Some((p, c)) => fr.eval(c) * (p * masking_at(mf, wo_l, ray.t)),
                    None => Spectrum::ZERO,
                },
                Microsurface::Diffuse { albedo } => match m {
                    Some(m) => albedo * (m.dot(wo_l).max(0.0) / PI * masking_at(mf, wo_l, ray.t)),
                    None => Spectrum::ZERO,
                },
                Microsurface::Dielectric { eta, .. } => {
                    let e = eta_seen(eta, ray.outside);
                    if wo_outside == ray.outside {
                        Spectrum::splat(dielectric_phase(mf, wi_l, wo_l, e, true) * masking_at(mf, wo_l, ray.t))
                    } else {
                        let p = dielectric_phase(mf, wi_l, wo_l, e, false);
                        if p > 0.0 {
                            Spectrum::splat(p * masking_at(mf, -wo_l, flip_height(ray.t)))
                        } else {
                            Spectrum::ZERO
                        }
                    }
                }
            };
            sum += ray.throughput * contrib;
        }
        if order == last {
            break;
        }

        // Continue the walk.
        let Some(m) = m else { break };
        let (ua, ub) = rng.next2();
        if !ray.scatter(&mat, m, ua, ub, rng) {
            break;
        }
    }
    sum
}

/// Random-walk sampling (supplement Algorithm 3). `first` = (u_choice, u1, u2)
/// drives the first vertex: (u1, u2) the visible normal, u_choice the
/// reflect/refract choice (dielectric) or the first height (conductor,
/// diffuse); every further number comes from `rng`.
///
/// Returns (ω_o, weight, order) with weight = f·|cos θ_o|/p: the product of
/// the Fresnel terms (conductor), of the albedo (diffuse), 1 for dielectrics
/// (times 1/η_rel² for a Radiance-mode transmission), divided by the Russian
/// roulette survival probabilities (the largest channel of a weight is ≤ 1).
/// `None` when the walk needs more than `min(opts.max_bounces, opts.orders.1)`
/// vertices, exits before `opts.orders.0`, or meets a degenerate case — the
/// same truncation as `eval`, so E[weight] = ∫ eval.
pub fn sample(
    mf: &Microfacet,
    surf: &Microsurface,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    let mat = *surf;
    if !valid_incidence(&mat, wi) {
        return None;
    }
    // Bound 1 − ε, one f64 below `rng::unit_interval`'s 1 − ε/2: the two differ
    // only for u = 1 − ε/2 (and u ≥ 1), which this walk maps to 1 − ε.
    let clamp_u = |u: f64| if u.is_finite() { u.clamp(0.0, 1.0 - f64::EPSILON) } else { 0.5 };
    let first = (clamp_u(first.0), clamp_u(first.1), clamp_u(first.2));
    let (wo, weight, order) = sample_from(mf, surf, State::start(wi), Some(first), opts, rng)?;
    let mut weight = weight;
    if let Microsurface::Dielectric { eta, radiance } = mat {
        weight *= radiance_scale(eta, radiance, wi.z > 0.0, wo.z > 0.0);
    }
    if !weight.is_finite() {
        return None;
    }
    Some((wo, weight, order))
}

/// Heitz's sampling walk from `state` on (see [`sample`]); `first` drives the
/// first vertex when the walk starts above the microsurface. Returns the exit
/// direction in the macro frame, the weight without the Radiance-mode 1/η²,
/// and the order. Public for the same reason as [`eval_from`].
pub fn sample_from(
    mf: &Microfacet,
    surf: &Microsurface,
    state: State,
    first: Option<(f64, f64, f64)>,
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    let mat = *surf;
    let last = opts.last_order()?;
    let is_dielectric = matches!(mat, Microsurface::Dielectric { .. });
    let mut ray = state;
    let mut order = ray.next_order.max(1) - 1; // vertices so far

    loop {
        let u_height = match first {
            Some(f) if order == 0 && !is_dielectric => f.0,
            _ => rng.next(),
        };
        match sample_height(mf, ray.dir, ray.t, u_height) {
            Some(tn) => ray.t = tn,
            None => {
                // The ray leaves the microsurface along ray.dir.
                if order == 0 || order < opts.orders.0 {
                    return None;
                }
                let wo = local(ray.dir, ray.outside);
                if !wo.is_finite() || wo.z == 0.0 || !ray.throughput.is_finite() {
                    return None;
                }
                return Some((wo, ray.throughput, order));
            }
        }
        order += 1;
        if order > last {
            return None;
        }
        let wi_l = -ray.dir;
        let (u1, u2, ua, ub) = match first {
            Some(f) if order == 1 => {
                let (a, b) = if is_dielectric { (f.0, 0.0) } else { rng.next2() };
                (f.1, f.2, a, b)
            }
            _ => {
                let (u1, u2) = rng.next2();
                let (a, b) = rng.next2();
                (u1, u2, a, b)
            }
        };
        let m = visible_normal(mf, wi_l, u1, u2)?;
        if !ray.scatter(&mat, m, ua, ub, rng) {
            return None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flip_is_an_involution_and_stable() {
        for &t in &[-1e-300, -1e-12, -0.3, -0.7, -2.0, -50.0] {
            let f = flip_height(t);
            assert!(f.is_finite() && f < 0.0, "{t} {f}");
            let back = flip_height(f);
            assert!((back - t).abs() <= 1e-9 * t.abs().max(1e-300) + 1e-300, "{t} {back}");
        }
    }
}
