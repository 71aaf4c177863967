//! The dielectric interface in one convention, for every model: `eta` =
//! η_int/η_ext of the interface, the exterior above the macro surface (z > 0),
//! as Mitsuba's `roughdielectric`. A walk that works in the frame of the
//! medium it travels in (the interior mirrored to the top) sees the relative
//! IOR [`eta_seen`]. Fresnel and refraction come in two arithmetic forms of
//! the same formulas: Mitsuba's (`fresnel::dielectric_full`, `refract`, which
//! `single` must reproduce bit for bit and the position-free walks use,
//! [`reflect_or_refract`]) and the unit-vector form of the height-based walks
//! of Heitz 2016 and Cui 2023 (`fresnel::dielectric`, [`refract_unit`]).
//! The forms are equivalent but round differently: a walk moved from one to
//! the other draws a different random stream (a rounding difference flips rare
//! decisions), which the fixed-seed checks of heavy-tailed estimators notice
//! (docs/testing.md, "Heavy-tailed estimators and fixed seeds").

use super::fresnel::dielectric_full;
use super::{reflect, refract};
use glam::DVec3;

/// Mitsuba's IOR of BK7 glass (the default `int_ior` of `roughdielectric`),
/// the relative IOR a material carries when no dielectric sets one.
pub const BK7_IOR: f64 = 1.5046;

/// Whether a relative IOR can describe an interface (finite, > 0).
#[inline]
pub fn valid_ior(eta: f64) -> bool {
    eta.is_finite() && eta > 0.0
}

/// Relative IOR η_t/η_i seen by light on one side: η outside, 1/η inside.
#[inline]
pub fn eta_seen(eta: f64, outside: bool) -> f64 {
    if outside {
        eta
    } else {
        1.0 / eta
    }
}

/// Mitsuba's Radiance-mode factor of a result that crossed the interface:
/// 1/η_r² with η_r = η_t/η_i from ω_i's side to ω_o's (radiance is compressed
/// by the change of solid angle); 1 for a reflection or in Importance mode.
/// Along a path the factors of the refractions telescope to this one.
#[inline]
pub fn radiance_scale(eta: f64, radiance: bool, wi_outside: bool, wo_outside: bool) -> f64 {
    if radiance && wi_outside != wo_outside {
        let e = eta_seen(eta, wi_outside);
        1.0 / (e * e)
    } else {
        1.0
    }
}

/// Refraction of `w` (pointing away from the facet, w·m = `cos_i` > 0)
/// through the facet m with relative IOR `eta_rel` = η_t/η_i: the unit
/// direction on the far side, in the same frame; None under total internal
/// reflection.
#[inline]
pub fn refract_unit(w: DVec3, m: DVec3, cos_i: f64, eta_rel: f64) -> Option<DVec3> {
    let sin2_t = (1.0 - cos_i * cos_i).max(0.0) / (eta_rel * eta_rel);
    if sin2_t >= 1.0 {
        return None;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let o = m * (cos_i / eta_rel - cos_t) - w / eta_rel;
    let len = o.length();
    if !(len > 0.0) || !len.is_finite() {
        return None;
    }
    Some(o / len)
}

/// Light arriving from `w` (pointing away from the facet, w·m = `cos_wm` > 0)
/// at the facet m of an interface with relative IOR `eta_rel` (η_t/η_i):
/// reflected when `u < F`, refracted otherwise. Returns the new direction
/// (on the far side of the facet for a refraction, in the same frame as w),
/// whether it refracted, and F (1 under total internal reflection, where the
/// light always reflects).
#[inline]
pub fn reflect_or_refract(w: DVec3, m: DVec3, cos_wm: f64, eta_rel: f64, u: f64) -> (DVec3, bool, f64) {
    let (f, cos_t, _, eta_ti) = dielectric_full(cos_wm, eta_rel);
    if u < f {
        (reflect(w, m), false, f)
    } else {
        (refract(w, m, cos_t, eta_ti), true, f)
    }
}
