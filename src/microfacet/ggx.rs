//! GGX (Trowbridge-Reitz) specifics: Λ and visible-normal sampling with the
//! spherical-cap method (Dupuy & Benyoub 2023), exact for incident
//! directions below the horizon too.

use glam::DVec3;
use std::f64::consts::PI;

/// Λ for an upward direction with (α tan θ)² = `alpha_tan2`:
/// (−1 + √(1 + α²tan²θ))/2, written without cancellation.
#[inline]
pub fn lambda_up(alpha_tan2: f64) -> f64 {
    if !alpha_tan2.is_finite() {
        return f64::INFINITY;
    }
    alpha_tan2 / (2.0 * (1.0 + (1.0 + alpha_tan2).sqrt()))
}

/// Visible normal for the stretched (α = 1) unit direction `w` on the full sphere.
#[inline]
pub fn sample_visible_std(w: DVec3, u1: f64, u2: f64) -> Option<DVec3> {
    // Sample the spherical cap z ∈ [−w.z, 1].
    let phi = 2.0 * PI * u1;
    let z = (1.0 - u2) * (1.0 + w.z) - w.z;
    let sin_theta = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = phi.sin_cos();
    let h = DVec3::new(sin_theta * c, sin_theta * s, z) + w;
    if h.z <= 0.0 {
        return None;
    }
    Some(h)
}
