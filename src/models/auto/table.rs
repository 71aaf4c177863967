//! The multiply scattered fraction T₁ = 1 − E₁ of the height-correlated
//! position-free model (`correlated`), E₁ its order-1 albedo with F = 1
//! (conductor), a lossless interface (dielectric) or albedo 1 (diffuse), where
//! the full model's albedo is exactly 1, and the grids of `auto`'s rule
//! (`mod.rs` here, which explains why F = 1 bounds every material): μ_i =
//! |cos θ_i| nodes uniform in μ² over 0.02² … 1, α searched over 0.005 … 4
//! and, for dielectrics, the relative IOR seen from ω_i itself (1/3 … 3). [`ms_fraction_bound`] is the rule's estimator: T₁ + 2
//! standard errors at one exact point (α, μ_i, IOR), E₁ the expectation of the
//! first vertex's exit probability over the visible normals (jittered 32 × 32
//! grid, 64 × 64 for the diffuse microsurface's extra cosine direction, seeded
//! by the point): G2 reflection L₀/(L₀ + Λ), Beta transmission L₀·B(L₀, 1 + Λ').

use crate::config::Distribution;
use crate::config::Surface;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{reflect, refract, Microfacet};
use crate::models::posfree::{dielectric as posfree_dielectric, Segments};
use crate::rng::{hash_words, Sampler};
use crate::tables::{Axis, Warp};
use crate::walk::cosine_about;
use glam::DVec3;

/// ln of the smallest and largest roughness the rule searches, 0.005 and 4.
pub const LN_ALPHA_MIN: f64 = -5.298_317_366_548_036;
pub const LN_ALPHA_MAX: f64 = 1.386_294_361_119_890_6;
/// Smallest μ_i of the rule; below it (grazing) `auto` runs the full model.
pub const MU_MIN: f64 = 0.02;

/// The rule's μ nodes, uniform in μ² over [MU_MIN², 1]: 65 nodes, the ends of
/// 64 cells (the most the C ABI's `msx_auto_rule` hands over).
pub const MU: Axis = Axis::ends(Warp::Square, MU_MIN * MU_MIN, 1.0, 65);
/// The relative IORs (seen from ω_i) the rule covers, 1/3 … 3; outside,
/// `auto` runs the full model.
pub const ETA_MIN: f64 = 1.0 / 3.0;
pub const ETA_MAX: f64 = 3.0;

/// Whether the rule covers the relative IOR `eta` (always, for conductors and
/// diffuse microsurfaces, which have none).
#[inline]
pub fn eta_covered(surface: Surface, eta: f64) -> bool {
    surface != Surface::Dielectric || (ETA_MIN..=ETA_MAX).contains(&eta)
}

/// The relative IOR a dielectric rule is built at and cached by: `eta`
/// rounded to f32, so that both engines, which may compute it in different
/// precisions (η and 1/η of the scene's IORs), reach the same rule.
#[inline]
pub fn eta_key(eta: f64) -> f64 {
    eta as f32 as f64
}

/// Index of the μ cell (between nodes i and i+1 of [`MU`]) holding μ; None
/// below MU_MIN.
#[inline]
pub fn mu_cell(mu: f64) -> Option<usize> {
    if !(mu >= MU_MIN) {
        return None;
    }
    let x = (mu.min(1.0) * mu.min(1.0) - MU.lo) * ((MU.n - 1) as f64 / (MU.hi - MU.lo));
    Some((x.max(0.0) as usize).min(MU.n - 2)) // truncation: no libm floor on baseline x86-64
}

/// Upper bound T₁ + 2 SE of the multiply scattered fraction at one point
/// (a table node, or a point of `auto`'s rule): [`ms_fraction`] on a jittered
/// 32 × 32 grid (64 × 64 for the diffuse microsurface), seeded by the point.
pub fn ms_fraction_bound(surface: Surface, dist: Distribution, eta: f64, alpha: f64, mu: f64) -> f64 {
    let side = if surface == Surface::Diffuse { 64 } else { 32 };
    let (mean, se) = ms_fraction(surface, dist, eta, alpha, mu, side, 0);
    (mean + 2.0 * se).clamp(0.0, 1.0)
}

/// [`ms_fraction_bound`] with a quarter of the samples (16 × 16, 32 × 32 for
/// the diffuse microsurface): the scan of the rule's search.
pub fn ms_fraction_bound_coarse(surface: Surface, dist: Distribution, eta: f64, alpha: f64, mu: f64) -> f64 {
    let side = if surface == Surface::Diffuse { 32 } else { 16 };
    let (mean, se) = ms_fraction(surface, dist, eta, alpha, mu, side, 0);
    (mean + 2.0 * se).clamp(0.0, 1.0)
}

/// The multiply scattered fraction T₁ = 1 − E₁ of the correlated model at
/// (α, μ_i, relative IOR) and its standard error: 1 − the mean first-vertex
/// exit probability over the visible normals, sampled on a jittered
/// `side` × `side` grid; `stream` 0 is the table's, any other value an
/// independent set of samples (tests).
pub fn ms_fraction(surface: Surface, dist: Distribution, eta: f64, alpha: f64, mu: f64, side: usize, stream: u64) -> (f64, f64) {
    let mf = Microfacet::new(dist, alpha, alpha);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let l0 = 1.0 + mf.lambda(wi);
    let words = [surface as u64, dist as u64, eta.to_bits(), alpha.to_bits(), mu.to_bits(), stream];
    let mut rng = Sampler::new(hash_words(if stream == 0 { &words[..5] } else { &words }));
    let leave_up = |d: DVec3, refracted: bool| -> f64 {
        if !(d.z > 0.0) || !d.is_finite() {
            return 0.0; // downward: hits again for sure
        }
        let c = if surface == Surface::Dielectric {
            posfree_dielectric::continue_up(Segments::Correlated, refracted, l0, mf.lambda(d))
        } else {
            Segments::Correlated.continue_up(l0, mf.lambda(d))
        };
        1.0 - c
    };
    let (mut sum, mut sum2) = (0.0, 0.0);
    for gx in 0..side {
        for gy in 0..side {
            let u1 = ((gx as f64 + rng.next()) / side as f64).min(1.0 - f64::EPSILON);
            let u2 = ((gy as f64 + rng.next()) / side as f64).min(1.0 - f64::EPSILON);
            let exit = match mf.sample_visible(wi, u1, u2) {
                None => 0.0,
                Some(m) => match surface {
                    Surface::Conductor => leave_up(reflect(wi, m), false),
                    Surface::Diffuse => {
                        let (a, b) = rng.next2();
                        leave_up(cosine_about(m, a, b), false)
                    }
                    Surface::Dielectric => {
                        let (f, cos_t, _, eta_ti) = dielectric_full(wi.dot(m), eta);
                        let r = f * leave_up(reflect(wi, m), false);
                        // The refracted ray in the other medium's frame is −d.
                        let t = if f < 1.0 { (1.0 - f) * leave_up(-refract(wi, m, cos_t, eta_ti), true) } else { 0.0 };
                        r + t
                    }
                },
            };
            sum += exit;
            sum2 += exit * exit;
        }
    }
    let n = (side * side) as f64;
    let mean = sum / n;
    let se = ((sum2 / n - mean * mean).max(0.0) / n).sqrt();
    (1.0 - mean, se)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_bounds_are_the_logs_of_the_ranges() {
        assert_eq!(LN_ALPHA_MIN, 0.005f64.ln());
        assert_eq!(LN_ALPHA_MAX, 4f64.ln());
    }
}
