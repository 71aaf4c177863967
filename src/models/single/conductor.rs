//! Single scattering, Walter et al. 2007, exactly as Mitsuba 3's built-in
//! `roughconductor` computes it: separable Smith G = G1(ω_i)·G1(ω_o) (with
//! Mitsuba's rational G1 for Beckmann) and Mitsuba's visible-normal sampler.
//! `eval` returns f·cos θ_o = F·D·G / (4 cos θ_i).

use crate::microfacet::ConductorFresnel;
use crate::microfacet::{mitsuba, reflect, Microfacet};
use crate::spectrum::Spectrum;
use glam::DVec3;

pub fn eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let h = (wi + wo).normalize();
    let d = mf.d(h);
    if d == 0.0 {
        return Spectrum::ZERO;
    }
    let g = mitsuba::smith_g1(mf, wi, h) * mitsuba::smith_g1(mf, wo, h);
    fresnel.eval(wi.dot(h)) * (d * g / (4.0 * wi.z))
}

/// Density of `sample`: D(h)·G1(ω_i)/(4 cos θ_i).
pub fn pdf(mf: &Microfacet, wi: DVec3, wo: DVec3) -> f64 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    let h = (wi + wo).normalize();
    if wi.dot(h) <= 0.0 || wo.dot(h) <= 0.0 {
        return 0.0;
    }
    mf.d(h) * mitsuba::smith_g1(mf, wi, h) / (4.0 * wi.z)
}

/// `eval` and `pdf` in one pass (the half vector, D and G1(ω_i) computed once):
/// the same values as the two functions.
pub fn eval_pdf(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> (Spectrum, f64) {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return (Spectrum::ZERO, 0.0);
    }
    let h = (wi + wo).normalize();
    let d = mf.d(h);
    if d == 0.0 {
        return (Spectrum::ZERO, 0.0);
    }
    let g1_i = mitsuba::smith_g1(mf, wi, h);
    let value = fresnel.eval(wi.dot(h)) * (d * g1_i * mitsuba::smith_g1(mf, wo, h) / (4.0 * wi.z));
    let pdf = if wi.dot(h) <= 0.0 || wo.dot(h) <= 0.0 { 0.0 } else { d * g1_i / (4.0 * wi.z) };
    (value, pdf)
}

/// Returns (ω_o, pdf, weight = f·cos θ_o / pdf) or None for an invalid sample.
pub fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, u1: f64, u2: f64) -> Option<(DVec3, f64, Spectrum)> {
    if wi.z <= 0.0 {
        return None;
    }
    let m = mitsuba::sample_visible(mf, wi, u1, u2);
    let wo = reflect(wi, m);
    let pdf_m = mf.d(m) * mitsuba::smith_g1(mf, wi, m) * wi.dot(m).abs() / wi.z;
    let pdf = pdf_m / (4.0 * wo.dot(m));
    if !(pdf > 0.0) || !pdf.is_finite() || wo.z <= 0.0 {
        return None;
    }
    let weight = fresnel.eval(wi.dot(m)) * mitsuba::smith_g1(mf, wo, m);
    Some((wo, pdf, weight))
}
