//! Mitsuba 3's own single-scattering conventions, reproduced so that
//! `model="single"` equals the built-in `roughconductor` (README.md's parameter table, docs/paper-notes.md):
//!
//! * the separable Smith term G = G1(ω_i)·G1(ω_o);
//! * for Beckmann, Mitsuba's G1 is the rational approximation of Walter et
//!   al. 2007 (< 0.35 % from the exact Smith G1), not the exact Λ;
//! * its visible-normal sampler (`sample_visible_11`): the concentric-disk
//!   construction for GGX, three Newton steps in the erf domain for Beckmann;
//! * its sampler of all normals, m ~ D(m)·cos θ_m (`sample_all`), which the
//!   built-ins use with `sample_visible=false` ([`Sampling::AllNormals`]).
//!
//! Only `model="single"` uses this file; every multiple-scattering model uses
//! the exact full-sphere functions of `super`.

use super::special::{erf, erfinv, INV_SQRT_PI};
use super::{Distribution, Microfacet};
use glam::DVec3;
use std::f64::consts::PI;

/// Mitsuba's `smith_g1(v, m)` (upper hemisphere, local test included).
#[inline]
pub fn smith_g1(mf: &Microfacet, v: DVec3, m: DVec3) -> f64 {
    if v.dot(m) * v.z <= 0.0 {
        return 0.0;
    }
    let xy = (mf.alpha_u * v.x).powi(2) + (mf.alpha_v * v.y).powi(2);
    if xy == 0.0 {
        return 1.0;
    }
    let tan2 = xy / (v.z * v.z);
    match mf.dist {
        Distribution::Beckmann => {
            let a = 1.0 / tan2.sqrt();
            if a >= 1.6 {
                1.0
            } else {
                (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
            }
        }
        Distribution::Ggx => 2.0 / (1.0 + (1.0 + tan2).sqrt()),
    }
}

/// Which normals `single` (and the closed forms built on it) draw: Mitsuba's
/// `sample_visible` parameter of `roughconductor` / `roughdielectric`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampling {
    /// `sample_visible=true` (the default): m ~ D_ωi(m), the visible normals.
    Visible,
    /// `sample_visible=false`: m ~ D(m)·cos θ_m, whatever ω_i.
    AllNormals,
}

/// Mitsuba's sampler of all normals (`MicrofacetDistribution::sample` with
/// `sample_visible=false`): m with density D(m)·cos θ_m. `u1` drives the
/// elevation, `u2` the azimuth, as Mitsuba's `sample.x()` and `sample.y()`.
pub fn sample_all(mf: &Microfacet, u1: f64, u2: f64) -> DVec3 {
    let (sin_phi, cos_phi, alpha2) = if mf.alpha_u == mf.alpha_v {
        let (s, c) = (2.0 * PI * u2).sin_cos();
        (s, c, mf.alpha_u * mf.alpha_u)
    } else {
        // φ from the anisotropic distribution's azimuthal marginal, then the
        // α of that azimuth (Mitsuba's construction).
        let tmp = mf.alpha_v / mf.alpha_u * (2.0 * PI * u2).tan();
        let cos_phi = (1.0 / (tmp * tmp + 1.0).sqrt()).copysign((u2 - 0.5).abs() - 0.25);
        let sin_phi = cos_phi * tmp;
        (sin_phi, cos_phi, 1.0 / ((cos_phi / mf.alpha_u).powi(2) + (sin_phi / mf.alpha_v).powi(2)))
    };
    let cos_theta = match mf.dist {
        Distribution::Beckmann => 1.0 / (1.0 - alpha2 * (1.0 - u1).ln()).sqrt(),
        Distribution::Ggx => 1.0 / (1.0 + alpha2 * u1 / (1.0 - u1)).sqrt(),
    };
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    DVec3::new(cos_phi * sin_theta, sin_phi * sin_theta, cos_theta)
}

/// The density of [`sample_all`] at m: D(m)·cos θ_m.
#[inline]
pub fn pdf_all(mf: &Microfacet, m: DVec3) -> f64 {
    mf.d(m) * m.z
}

/// roughdielectric's widened roughness for sampling all normals (Walter et
/// al. 2007, §5.3): α·(1.2 − 0.2·√|cos θ_i|), which lowers the weights' variance.
pub fn widened(mf: &Microfacet, cos_theta_i: f64) -> Microfacet {
    let s = 1.2 - 0.2 * cos_theta_i.abs().sqrt();
    Microfacet::new(mf.dist, mf.alpha_u * s, mf.alpha_v * s)
}

/// Mitsuba's visible-normal sampler for an upward `wi`.
pub fn sample_visible(mf: &Microfacet, wi: DVec3, u1: f64, u2: f64) -> DVec3 {
    let wp = DVec3::new(mf.alpha_u * wi.x, mf.alpha_v * wi.y, wi.z).normalize();
    let st = (wp.x * wp.x + wp.y * wp.y).sqrt();
    let (sin_phi, cos_phi) = if st > 0.0 { ((wp.y / st).clamp(-1.0, 1.0), (wp.x / st).clamp(-1.0, 1.0)) } else { (0.0, 1.0) };
    let (sx, sy) = sample_visible_11(mf.dist, wp.z, u1, u2);
    let slope_x = (cos_phi * sx - sin_phi * sy) * mf.alpha_u;
    let slope_y = (sin_phi * sx + cos_phi * sy) * mf.alpha_v;
    DVec3::new(-slope_x, -slope_y, 1.0).normalize()
}

fn sample_visible_11(dist: Distribution, cos_theta_i: f64, u1: f64, u2: f64) -> (f64, f64) {
    match dist {
        Distribution::Beckmann => {
            let tan_theta_i = (1.0 - cos_theta_i * cos_theta_i).max(0.0).sqrt() / cos_theta_i;
            let cot_theta_i = 1.0 / tan_theta_i;
            // Parameterised in the erf domain; start from the θ = π/2 solution.
            let maxval = erf(cot_theta_i);
            let u1 = u1.clamp(1e-6, 1.0 - 1e-6);
            let u2 = u2.clamp(1e-6, 1.0 - 1e-6);
            let mut x = maxval - (maxval + 1.0) * erf((-u1.ln()).sqrt());
            let s = u1 * (1.0 + maxval + INV_SQRT_PI * tan_theta_i * (-cot_theta_i * cot_theta_i).exp());
            for _ in 0..3 {
                let slope = erfinv(x);
                let value = 1.0 + x + INV_SQRT_PI * tan_theta_i * (-slope * slope).exp() - s;
                let derivative = 1.0 - slope * tan_theta_i;
                x -= value / derivative;
            }
            (erfinv(x), erfinv(2.0 * u2 - 1.0))
        }
        Distribution::Ggx => {
            let (px, py) = square_to_disk_concentric(u1, u2);
            let s = 0.5 * (1.0 + cos_theta_i);
            let lo = (1.0 - px * px).max(0.0).sqrt();
            let py = lo + (py - lo) * s;
            let z = (1.0 - px * px - py * py).max(0.0).sqrt();
            let sin_theta_i = (1.0 - cos_theta_i * cos_theta_i).max(0.0).sqrt();
            let norm = 1.0 / (sin_theta_i * py + cos_theta_i * z);
            ((cos_theta_i * py - sin_theta_i * z) * norm, px * norm)
        }
    }
}

/// Shirley-Chiu concentric square-to-disk mapping (as Mitsuba's warp).
fn square_to_disk_concentric(u1: f64, u2: f64) -> (f64, f64) {
    let x = 2.0 * u1 - 1.0;
    let y = 2.0 * u2 - 1.0;
    if x == 0.0 && y == 0.0 {
        return (0.0, 0.0);
    }
    let (r, phi) = if x.abs() > y.abs() { (x, (PI / 4.0) * (y / x)) } else { (y, PI / 2.0 - (PI / 4.0) * (x / y)) };
    let (s, c) = phi.sin_cos();
    (r * c, r * s)
}
