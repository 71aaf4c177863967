//! Energy compensation for rough dielectrics (`model="compensated"` with a
//! dielectric surface): the single-scattering lobe of `single_dielectric`
//! (Walter 2007, Mitsuba-exact) scaled by 1/E_ss(μ_i, α, η_r), as Turquin et
//! al. 2019 (§ dielectrics) and Kulla & Conty 2017 do for glass:
//!
//!   f = f_ss / E(μ_i, α, η_r),   E = E_r + E_t of `single_dielectric` in
//!   Importance mode (no 1/η² on transmission),
//!
//! so that without absorption the scaled lobe has E_r + E_t = 1 (at the table
//! nodes; up to interpolation between them). Reflection and transmission are
//! scaled by the same factor, i.e. the energy lost by single scattering is
//! redistributed in proportion to the single-scattering split. Incidence from
//! outside sees η_r = η, from inside 1/η; the two sides are compensated
//! separately (two tables: entering a denser medium, η_r = n ≥ 1, and leaving
//! it, η_r = 1/n, with total internal reflection). In Radiance mode the
//! transmitted part keeps `single_dielectric`'s 1/η_r² factor.
//!
//! The table E(μ, α, n) is `dielectric_albedo.rs` beside this file.
//!
//! Limitations: the compensated lobe is not reciprocal (the scale depends on
//! ω_i only, as in Turquin 2019); anisotropic roughness uses α = √(α_u α_v);
//! η_r outside [1/3, 3] or within 1.01 of 1 uses the nearest table edge.

use super::dielectric_albedo::{DielectricAlbedoTable, E_MIN};
use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::Microfacet;
use crate::models::single::dielectric as single_dielectric;
use glam::DVec3;

/// The compensation factor 1/E(μ_i, α, η_r) (≥ 1) for incidence ω_i.
pub fn scale(mf: &Microfacet, eta: f64, wi: DVec3) -> f64 {
    if !(eta > 0.0) || !eta.is_finite() || wi.z == 0.0 || !wi.z.is_finite() {
        return 1.0;
    }
    let eta_r = if wi.z > 0.0 { eta } else { 1.0 / eta };
    let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
    let e = DielectricAlbedoTable::get(mf.dist).e(alpha, wi.z.abs().min(1.0), eta_r);
    let s = 1.0 / e.clamp(E_MIN, 1.0);
    if s.is_finite() {
        s
    } else {
        1.0
    }
}

/// f(ω_i, ω_o)·|cos θ_o| of the compensated lobe (no specular tints).
pub fn eval(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3, radiance: bool) -> f64 {
    let (v, _) = single_dielectric::eval(mf, eta, wi, wo, radiance);
    if v > 0.0 {
        v * scale(mf, eta, wi)
    } else {
        0.0
    }
}

/// Density of `sample` with visible normals (the single-scattering sampler's).
pub fn pdf(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    single_dielectric::pdf(mf, eta, wi, wo)
}

/// Samples ω_o as `single_dielectric::sample`; returns (ω_o, pdf, weight = eval/pdf).
pub fn sample(mf: &Microfacet, eta: f64, sampling: Sampling, wi: DVec3, u: (f64, f64, f64), radiance: bool) -> Option<(DVec3, f64, f64)> {
    let (wo, pdf, weight, _) = single_dielectric::sample(mf, eta, sampling, wi, u, radiance)?;
    Some((wo, pdf, weight * scale(mf, eta, wi)))
}
