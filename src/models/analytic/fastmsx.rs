//! Fast-MSX, Rosales et al. 2023: single scattering (Walter 2007, GGX,
//! separable Smith G — here exactly `single`, as Mitsuba computes it) plus an
//! analytic second-bounce lobe from an asymmetric V-cavity (Alg. 1, eqs. 16–20):
//!
//!   c = normalize(h + n),  θ_vc = acos(c·v),  θ_m = (π − acos(v·l))/4   (Alg. 1, eq. 16)
//!   G_I = 1 − max(0, sin(θ_vc − θ_m)/sin(θ_vc + θ_m))                   (eq. 17)
//!   D_I = α²/(π (cos²θ_m (α² − 1) + 1)²)                                  (eq. 18)
//!   F_I = F²  (F of the direct lobe, here the exact conductor Fresnel)   (eq. 19)
//!   f_SI = D_I G_I F_I / (2 c·v)                                          (eq. 20)
//!
//! v is the view direction (Mitsuba's ω_i in Radiance mode), l the light (ω_o).
//! The paper is isotropic GGX only; an anisotropic α enters D_I as √(α_u α_v).
//! The model is neither reciprocal nor energy conserving (the paper says so);
//! its albedo is measured in the tests. Sampling uses `single`'s sampler.

use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::ConductorFresnel;
use crate::microfacet::Microfacet;
use crate::models::single::conductor as single;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::f64::consts::PI;

/// The second-bounce term f_SI·cos θ_o alone.
pub fn eval_second(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let (v, l) = (wi, wo);
    let h = (v + l).normalize();
    let c = h + DVec3::Z;
    let c = c / c.length();
    let cos_cv = c.dot(v).clamp(-1.0, 1.0);
    if cos_cv <= 0.0 {
        return Spectrum::ZERO;
    }
    let theta_vc = cos_cv.acos();
    let theta_m = (PI - v.dot(l).clamp(-1.0, 1.0).acos()) * 0.25;
    let denom = (theta_vc + theta_m).sin();
    let op = if denom > 0.0 { (theta_vc - theta_m).sin() / denom } else { 0.0 };
    let g_i = (1.0 - op.max(0.0)).clamp(0.0, 1.0);
    let a2 = mf.alpha_u * mf.alpha_v;
    let cm2 = theta_m.cos().powi(2);
    let t = cm2 * (a2 - 1.0) + 1.0;
    let d_i = a2 / (PI * t * t);
    let f = fresnel.eval(v.dot(h));
    let value = d_i * g_i / (2.0 * cos_cv) * wo.z;
    if !value.is_finite() {
        return Spectrum::ZERO;
    }
    f * f * value
}

/// f·cos θ_o of the full Fast-MSX lobe (single + second bounce).
pub fn eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> Spectrum {
    single::eval(mf, fresnel, wi, wo) + eval_second(mf, fresnel, wi, wo)
}

/// Samples with `single`'s sampler (visible normals, or all normals with
/// `sample_visible=false`); weight = eval/pdf.
pub fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, sampling: Sampling, wi: DVec3, u1: f64, u2: f64) -> Option<(DVec3, f64, Spectrum)> {
    let (wo, pdf, weight_single) = single::sample(mf, fresnel, sampling, wi, u1, u2)?;
    Some((wo, pdf, weight_single + eval_second(mf, fresnel, wi, wo) * (1.0 / pdf)))
}
