//! Single scattering through a rough dielectric interface, Walter et al. 2007,
//! exactly as Mitsuba 3's built-in `roughdielectric` computes it (its `eval`,
//! `pdf` and `sample`; with `sample_visible = false` the weight differs, below),
//! so that `model="single"` equals the built-in (README.md's parameter table,
//! docs/paper-notes.md):
//!
//! * `eta` = η_int/η_ext; ω_i with z < 0 lies inside, where the relative IOR
//!   seen by the query is 1/η;
//! * half vector m = normalize(ω_i + η_r ω_o) (η_r = 1 for reflection, the
//!   query's relative IOR for transmission), flipped into the upper hemisphere;
//! * separable Smith G = G1(ω_i, m)·G1(ω_o, m) with Mitsuba's G1 (rational
//!   approximation for Beckmann) and its local side test (v·m)(v·n) > 0;
//! * reflection F·D·G/(4|cos θ_i|); transmission
//!   |(1−F)·D·G·η_r²·(ω_i·m)(ω_o·m) / (cos θ_i (ω_i·m + η_r ω_o·m)²)|, times
//!   1/η_r² in Radiance mode (solid-angle compression), 1 in Importance mode;
//! * sampling: Mitsuba's VNDF sampler for ω_i mirrored to the upper side,
//!   reflect with probability F, refract otherwise; weight G1(ω_o, m)
//!   (× η_ti² for transmission in Radiance mode);
//! * with `sample_visible=false` ([`Sampling::AllNormals`]): m ~ D'(m)·cos θ_m
//!   where D' has roughdielectric's widened α·(1.2 − 0.2·√|cos θ_i|) (Walter
//!   et al. 2007, §5.3), and `pdf` the same density. The weight is
//!   G(ω_i, ω_o)·(ω_i·m)/(cos θ_i cos θ_m)·D(m)/D'(m), exactly f·|cos θ_o|/pdf.
//!   Mitsuba 3.9.1's roughdielectric leaves out the factor D(m)/D'(m), so its
//!   sample weights are not f·|cos θ_o|/pdf there (their mean is measurably
//!   off: docs/mitsuba.md); here the expected value does not depend on the
//!   sampler.
//!
//! Values are f·|cos θ_o| without the specular tints; the caller applies
//! `specular_reflectance` / `specular_transmittance` by the returned
//! `is_reflection` flag.

use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::{mitsuba, reflect, refract, Microfacet};
use glam::DVec3;

/// Mitsuba's D(m) including its cut-off: values with D·cos θ_m ≤ 1e-20 are 0.
#[inline]
fn d_mitsuba(mf: &Microfacet, m: DVec3) -> f64 {
    let d = mf.d(m);
    if d * m.z > 1e-20 {
        d
    } else {
        0.0
    }
}

/// Mitsuba's `mulsign(v, s)`: v with the sign of s (sign bit).
#[inline]
fn mulsign(v: DVec3, s: f64) -> DVec3 {
    if s.is_sign_negative() {
        -v
    } else {
        v
    }
}

/// The half vector of eval/pdf, the relative IOR η_r and whether the pair is a reflection.
#[inline]
fn half_vector(eta: f64, wi: DVec3, wo: DVec3) -> Option<(DVec3, f64, bool)> {
    let reflect = wi.z * wo.z > 0.0;
    let eta_r = if wi.z > 0.0 { eta } else { 1.0 / eta };
    let m = wi + wo * if reflect { 1.0 } else { eta_r };
    let len = m.length();
    if !(len > 0.0) || !len.is_finite() {
        return None;
    }
    let m = m / len;
    Some((mulsign(m, m.z), eta_r, reflect))
}

/// f(ω_i, ω_o)·|cos θ_o| and whether (ω_i, ω_o) is a reflection pair.
pub fn eval(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3, radiance: bool) -> (f64, bool) {
    let is_reflection = wi.z * wo.z > 0.0;
    if wi.z == 0.0 {
        return (0.0, is_reflection);
    }
    let Some((m, eta_r, reflect)) = half_vector(eta, wi, wo) else { return (0.0, is_reflection) };
    let d = d_mitsuba(mf, m);
    let (wim, wom) = (wi.dot(m), wo.dot(m));
    let f = dielectric_full(wim, eta).0;
    let g = mitsuba::smith_g1(mf, wi, m) * mitsuba::smith_g1(mf, wo, m);
    let value = if reflect {
        f * d * g / (4.0 * wi.z.abs())
    } else {
        let scale = if radiance { 1.0 / (eta_r * eta_r) } else { 1.0 };
        let denom = wim + eta_r * wom;
        (scale * (1.0 - f) * d * g * eta_r * eta_r * wim * wom / (wi.z * denom * denom)).abs()
    };
    (if value.is_finite() { value } else { 0.0 }, is_reflection)
}

/// Density (solid angle) of `sample` with visible normals at ω_o.
pub fn pdf(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    pdf_with(mf, Sampling::Visible, eta, wi, wo)
}

/// The density m is drawn with (visible normals of ω_i mirrored upward, or all
/// normals of the widened distribution), as Mitsuba's `MicrofacetDistribution::pdf`.
#[inline]
fn normal_pdf(mf: &Microfacet, sampling: Sampling, wi: DVec3, m: DVec3) -> f64 {
    let wi_up = mulsign(wi, wi.z);
    match sampling {
        Sampling::Visible => d_mitsuba(mf, m) * mitsuba::smith_g1(mf, wi_up, m) * wi_up.dot(m).abs() / wi.z.abs(),
        Sampling::AllNormals => d_mitsuba(&mitsuba::widened(mf, wi.z), m) * m.z,
    }
}

/// Density (solid angle) of `sample` at ω_o with either sampler.
pub fn pdf_with(mf: &Microfacet, sampling: Sampling, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    if wi.z == 0.0 {
        return 0.0;
    }
    let Some((m, eta_r, reflect)) = half_vector(eta, wi, wo) else { return 0.0 };
    let (wim, wom) = (wi.dot(m), wo.dot(m));
    if !(wim * wi.z > 0.0 && wom * wo.z > 0.0) {
        return 0.0;
    }
    let dwh_dwo = if reflect {
        1.0 / (4.0 * wom)
    } else {
        let denom = wim + eta_r * wom;
        eta_r * eta_r * wom / (denom * denom)
    };
    let mut prob = normal_pdf(mf, sampling, wi, m);
    let f = dielectric_full(wim, eta).0;
    prob *= if reflect { f } else { 1.0 - f };
    let p = prob * dwh_dwo.abs();
    if p.is_finite() {
        p
    } else {
        0.0
    }
}

/// Samples ω_o with Mitsuba's choices: `sample1` picks reflection when
/// `sample1 ≤ F`, (u1, u2) drive the visible-normal sampler. Returns
/// (ω_o, pdf, weight = f·|cos θ_o|/pdf, is_reflection), or None where Mitsuba's
/// sample is inactive (grazing ω_i, zero pdf). As in Mitsuba, a sample whose
/// ω_o ends on the wrong side of the facet comes back with weight 0.
pub fn sample(
    mf: &Microfacet,
    eta: f64,
    sampling: Sampling,
    wi: DVec3,
    (sample1, u1, u2): (f64, f64, f64),
    radiance: bool,
) -> Option<(DVec3, f64, f64, bool)> {
    let cos_i = wi.z;
    if cos_i == 0.0 || !cos_i.is_finite() {
        return None;
    }
    let m = match sampling {
        Sampling::Visible => mitsuba::sample_visible(mf, mulsign(wi, cos_i), u1, u2),
        Sampling::AllNormals => mitsuba::sample_all(&mitsuba::widened(mf, cos_i), u1, u2),
    };
    let mut pdf = normal_pdf(mf, sampling, wi, m);
    if !(pdf != 0.0) || !pdf.is_finite() {
        return None;
    }
    let wim = wi.dot(m);
    // A normal drawn from all normals may face away from ω_i: no lobe scatters there (roughdielectric
    // returns such a sample with weight 0 and a density of nothing; here it is no sample).
    if sampling == Sampling::AllNormals && !(wim * cos_i > 0.0) {
        return None;
    }
    let (f, cos_t, eta_it, eta_ti) = dielectric_full(wim, eta);
    let selected_r = sample1 <= f;
    pdf *= if selected_r { f } else { 1.0 - f };
    let mut weight = 1.0;
    let (wo, dwh_dwo) = if selected_r {
        let wo = reflect(wi, m);
        (wo, 1.0 / (4.0 * wo.dot(m)))
    } else {
        let wo = refract(wi, m, cos_t, eta_ti);
        if radiance {
            weight *= eta_ti * eta_ti;
        }
        let wom = wo.dot(m);
        let denom = wim + eta_it * wom;
        (wo, eta_it * eta_it * wom / (denom * denom))
    };
    weight *= match sampling {
        Sampling::Visible => mitsuba::smith_g1(mf, wo, m),
        // f·|cos θ_o|/pdf with m drawn from the widened D'·cos θ_m (pdf > 0 above, so D' > 0).
        Sampling::AllNormals => {
            let g = mitsuba::smith_g1(mf, wi, m) * mitsuba::smith_g1(mf, wo, m);
            let ratio = d_mitsuba(mf, m) / d_mitsuba(&mitsuba::widened(mf, cos_i), m);
            g * wim / (cos_i * m.z) * ratio
        }
    };
    pdf *= dwh_dwo.abs();
    if !(pdf > 0.0) || !pdf.is_finite() || !weight.is_finite() {
        return None;
    }
    Some((wo, pdf, weight, selected_r))
}
