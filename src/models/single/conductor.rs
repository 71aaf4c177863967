//! Single scattering, Walter et al. 2007, exactly as Mitsuba 3's built-in
//! `roughconductor` computes it: separable Smith G = G1(ω_i)·G1(ω_o) (with
//! Mitsuba's rational G1 for Beckmann) and Mitsuba's visible-normal sampler.
//! `eval` returns f·cos θ_o = F·D·G / (4 cos θ_i). Sampling draws visible
//! normals, or with [`Sampling::AllNormals`] (`sample_visible=false`) normals
//! from D(m)·cos θ_m, with the density and weight roughconductor reports then.

use crate::microfacet::mitsuba::Sampling;
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

/// Density of `sample` with visible normals: D(h)·G1(ω_i)/(4 cos θ_i).
pub fn pdf(mf: &Microfacet, wi: DVec3, wo: DVec3) -> f64 {
    pdf_with(mf, Sampling::Visible, wi, wo)
}

/// Density of `sample` with either sampler: D(h)·G1(ω_i)/(4 cos θ_i) for the
/// visible normals, D(h)·cos θ_h/(4 ω_o·h) for all normals.
pub fn pdf_with(mf: &Microfacet, sampling: Sampling, wi: DVec3, wo: DVec3) -> f64 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    let h = (wi + wo).normalize();
    if wi.dot(h) <= 0.0 || wo.dot(h) <= 0.0 {
        return 0.0;
    }
    match sampling {
        Sampling::Visible => mf.d(h) * mitsuba::smith_g1(mf, wi, h) / (4.0 * wi.z),
        Sampling::AllNormals => mitsuba::pdf_all(mf, h) / (4.0 * wo.dot(h)),
    }
}

/// `eval` and `pdf` in one pass (the half vector, D and G1(ω_i) computed once):
/// the same values as the two functions.
pub fn eval_pdf(mf: &Microfacet, fresnel: &ConductorFresnel, sampling: Sampling, wi: DVec3, wo: DVec3) -> (Spectrum, f64) {
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
    let pdf = if wi.dot(h) <= 0.0 || wo.dot(h) <= 0.0 {
        0.0
    } else {
        match sampling {
            Sampling::Visible => d * g1_i / (4.0 * wi.z),
            Sampling::AllNormals => d * h.z / (4.0 * wo.dot(h)),
        }
    };
    (value, pdf)
}

/// Returns (ω_o, pdf, weight = f·cos θ_o / pdf) or None for an invalid sample.
pub fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, sampling: Sampling, wi: DVec3, u1: f64, u2: f64) -> Option<(DVec3, f64, Spectrum)> {
    if wi.z <= 0.0 {
        return None;
    }
    let (m, pdf_m) = match sampling {
        Sampling::Visible => {
            let m = mitsuba::sample_visible(mf, wi, u1, u2);
            (m, mf.d(m) * mitsuba::smith_g1(mf, wi, m) * wi.dot(m).abs() / wi.z)
        }
        Sampling::AllNormals => {
            let m = mitsuba::sample_all(mf, u1, u2);
            (m, mitsuba::pdf_all(mf, m))
        }
    };
    let wo = reflect(wi, m);
    let pdf = pdf_m / (4.0 * wo.dot(m));
    if !(pdf > 0.0) || !pdf.is_finite() || wo.z <= 0.0 {
        return None;
    }
    // f·cos θ_o/pdf: G1(ω_o) for the visible normals; for all normals
    // G(ω_i, ω_o)·(ω_i·m)/(cos θ_i cos θ_m), as roughconductor.
    let g = match sampling {
        Sampling::Visible => mitsuba::smith_g1(mf, wo, m),
        Sampling::AllNormals => mitsuba::smith_g1(mf, wi, m) * mitsuba::smith_g1(mf, wo, m) * wi.dot(m) / (wi.z * m.z),
    };
    let weight = fresnel.eval(wi.dot(m)) * g;
    Some((wo, pdf, weight))
}
