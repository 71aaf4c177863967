//! Microfacet primitives shared by every model: the normal distribution D,
//! the full-sphere Smith Λ, the distant masking G1_dist, the projected area,
//! and visible-normal (VNDF) sampling for incident directions on the whole
//! sphere (from bounce 2 on, a random walk meets the surface from below).
//!
//! Conventions (docs/conventions.md): local frame, z = macro normal. Λ(−ω) = −1 − Λ(ω),
//! so Λ ≥ 0 for upward and Λ ≤ −1 for downward directions.

pub mod beckmann;
pub mod dielectric;
pub mod fresnel;
pub mod ggx;
pub mod mitsuba;
pub mod special;

mod microsurface;

pub use microsurface::{ConductorFresnel, Microsurface};

use crate::config::Distribution;
use glam::DVec3;

/// Smallest and largest roughness the core works with. Mitsuba clamps α to
/// ≥ 1e-4 as well; the upper bound keeps Λ, D and the walk lengths finite.
pub const ALPHA_MIN: f64 = 1e-4;
pub const ALPHA_MAX: f64 = 1e4;

/// An anisotropic microfacet distribution (α_u along x, α_v along y).
#[derive(Clone, Copy, Debug)]
pub struct Microfacet {
    pub dist: Distribution,
    pub alpha_u: f64,
    pub alpha_v: f64,
}

impl Microfacet {
    /// Roughness is clamped into [ALPHA_MIN, ALPHA_MAX]; a NaN becomes ALPHA_MIN.
    pub fn new(dist: Distribution, alpha_u: f64, alpha_v: f64) -> Self {
        let clamp = |a: f64| if a.is_nan() { ALPHA_MIN } else { a.clamp(ALPHA_MIN, ALPHA_MAX) };
        Microfacet { dist, alpha_u: clamp(alpha_u), alpha_v: clamp(alpha_v) }
    }

    /// (α tan θ)² of a direction: the only quantity Λ depends on.
    #[inline]
    fn alpha_tan2(&self, w: DVec3) -> f64 {
        let xy = (self.alpha_u * w.x).powi(2) + (self.alpha_v * w.y).powi(2);
        if xy == 0.0 {
            0.0
        } else {
            xy / (w.z * w.z)
        }
    }

    /// Λ of the upper-hemisphere direction with the same (α tan θ)²: ≥ 0.
    #[inline]
    fn lambda_up(&self, alpha_tan2: f64) -> f64 {
        match self.dist {
            Distribution::Ggx => ggx::lambda_up(alpha_tan2),
            Distribution::Beckmann => beckmann::lambda_up(alpha_tan2),
        }
    }

    /// Full-sphere Smith Λ(ω). +∞ for horizontal directions (z = 0).
    #[inline]
    pub fn lambda(&self, w: DVec3) -> f64 {
        let l = self.lambda_up(self.alpha_tan2(w));
        if w.z >= 0.0 {
            l
        } else {
            -1.0 - l
        }
    }

    /// |Λ(ω)| computed without cancellation: Λ for upward ω, 1 + Λ(−ω) for downward.
    #[inline]
    pub fn abs_lambda(&self, w: DVec3) -> f64 {
        let l = self.lambda_up(self.alpha_tan2(w));
        if w.z >= 0.0 {
            l
        } else {
            1.0 + l
        }
    }

    /// Distant masking G1_dist(ω) = |1/(1 + Λ(ω))| (Wang eq. 10). For downward
    /// ω this exceeds 1 and is not a probability; never clamp it.
    #[inline]
    pub fn g1_dist(&self, w: DVec3) -> f64 {
        let l = self.lambda_up(self.alpha_tan2(w));
        if w.z >= 0.0 {
            1.0 / (1.0 + l)
        } else {
            1.0 / l
        }
    }

    /// Smith masking with the local (back-facing) test: χ⁺(ω·m)·G1_dist(ω).
    #[inline]
    pub fn g1(&self, w: DVec3, m: DVec3) -> f64 {
        if w.dot(m) > 0.0 {
            self.g1_dist(w)
        } else {
            0.0
        }
    }

    /// Projected area A(ω) = ∫⟨ω, m⟩ D(m) dm = cos θ (1 + Λ(ω)), stable on the full sphere.
    #[inline]
    pub fn projected_area(&self, w: DVec3) -> f64 {
        let l = self.lambda_up(self.alpha_tan2(w));
        if w.z >= 0.0 {
            w.z * (1.0 + l)
        } else {
            -w.z * l
        }
    }

    /// Normal distribution D(m), zero for m in the lower hemisphere.
    #[inline]
    pub fn d(&self, m: DVec3) -> f64 {
        if m.z <= 0.0 {
            return 0.0;
        }
        let (ax, ay) = (self.alpha_u, self.alpha_v);
        let z2 = m.z * m.z;
        let v = match self.dist {
            Distribution::Beckmann => {
                let sx = m.x / ax;
                let sy = m.y / ay;
                (-(sx * sx + sy * sy) / z2).exp() / (std::f64::consts::PI * ax * ay * z2 * z2)
            }
            Distribution::Ggx => {
                // 1/(π α_u α_v t²) with t = (m_x/α_u)² + (m_y/α_v)² + m_z²,
                // scaled by (α_u α_v)² to need one division: u = t·(α_u α_v)².
                let (ax2, ay2) = (ax * ax, ay * ay);
                let u = m.x * m.x * ay2 + m.y * m.y * ax2 + z2 * ax2 * ay2;
                let a = ax * ay;
                a * a * a / (std::f64::consts::PI * u * u)
            }
        };
        if v.is_finite() {
            v
        } else {
            0.0
        }
    }

    /// Distribution of visible normals D_ω(m) = ⟨ω, m⟩ D(m) / A(ω).
    #[inline]
    pub fn d_visible(&self, w: DVec3, m: DVec3) -> f64 {
        let cos = w.dot(m);
        if cos <= 0.0 {
            return 0.0;
        }
        let area = self.projected_area(w);
        if area <= 0.0 || !area.is_finite() {
            return 0.0;
        }
        cos * self.d(m) / area
    }

    /// Density (solid angle) of reflecting ω into `wo` when m is drawn from D_ω:
    /// D_ω(h) / (4 ω·h) with h the half vector.
    #[inline]
    pub fn reflect_pdf(&self, w: DVec3, wo: DVec3) -> f64 {
        let h = w + wo;
        let len = h.length();
        if len <= 0.0 {
            return 0.0;
        }
        let h = h / len;
        let c = w.dot(h);
        if c <= 0.0 {
            return 0.0;
        }
        self.d_visible(w, h) / (4.0 * c)
    }

    /// Samples a visible normal m ~ D_ω for any ω with θ ∈ [0, π). Returns
    /// `None` when ω sees no microfacet (straight down, or numerically so).
    #[inline]
    pub fn sample_visible(&self, w: DVec3, u1: f64, u2: f64) -> Option<DVec3> {
        let (ax, ay) = (self.alpha_u, self.alpha_v);
        // Stretch to the configuration with α = 1.
        let ws = DVec3::new(ax * w.x, ay * w.y, w.z);
        let len = ws.length();
        if !(len > 0.0) || !len.is_finite() {
            return None;
        }
        let ws = ws / len;
        let m = match self.dist {
            Distribution::Ggx => ggx::sample_visible_std(ws, u1, u2)?,
            Distribution::Beckmann => beckmann::sample_visible_std(ws, u1, u2)?,
        };
        // Unstretch the normal (slopes scale with α).
        let m = DVec3::new(ax * m.x, ay * m.y, m.z);
        let len = m.length();
        if !(len > 0.0) || !len.is_finite() || m.z <= 0.0 {
            return None;
        }
        Some(m / len)
    }

    /// The mirror reflection of ω about a visible normal drawn from (u1, u2):
    /// (m, ω·m, the reflected direction); `None` when ω sees no facet or
    /// ω·m ≤ 0.
    #[inline]
    pub fn reflect_visible(&self, w: DVec3, u1: f64, u2: f64) -> Option<(DVec3, f64, DVec3)> {
        let m = self.sample_visible(w, u1, u2)?;
        let cos_wm = w.dot(m);
        if cos_wm <= 0.0 {
            return None;
        }
        Some((m, cos_wm, reflect(w, m)))
    }
}

/// Mirror reflection of ω about m (both pointing away from the surface).
#[inline]
pub fn reflect(w: DVec3, m: DVec3) -> DVec3 {
    2.0 * w.dot(m) * m - w
}

/// Refraction of ω (pointing away from the surface) through the facet m, as
/// Mitsuba 3's `refract(wi, m, cos_theta_t, eta_ti)`: `cos_t` and `eta_ti` come
/// from [`fresnel::dielectric_full`] (`cos_t` signed, opposite to ω·m). The
/// result points away from the surface on the other side of the facet.
#[inline]
pub fn refract(w: DVec3, m: DVec3, cos_t: f64, eta_ti: f64) -> DVec3 {
    m * (w.dot(m) * eta_ti + cos_t) - w * eta_ti
}
