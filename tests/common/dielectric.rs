//! Reference formulas of rough dielectrics (Walter 2007, Fresnel, Mitsuba's G1),
//! written from the papers independently of `msx`, and a proposal density over
//! the sphere for integrating dielectric lobes: shared by the tests of
//! `single` (tests/single.rs) and of the position-free dielectric
//! (tests/posfree/dielectric.rs).

use super::*;
use glam::DVec3;
use msx::rng::Sampler;
use msx::Distribution;
use std::f64::consts::PI;

/// Textbook unpolarised Fresnel reflectance for incidence cosine c > 0 and
/// relative IOR n = η_t/η_i; 1 under total internal reflection.
pub fn ref_fresnel(c: f64, n: f64) -> f64 {
    let s2t = (1.0 - c * c) / (n * n);
    if s2t >= 1.0 {
        return 1.0;
    }
    let ct = (1.0 - s2t).sqrt();
    let rs = (c - n * ct) / (c + n * ct);
    let rp = (n * c - ct) / (n * c + ct);
    0.5 * (rs * rs + rp * rp)
}

/// Mitsuba's Smith G1 (Walter 2007 eqs. 27/34 with the local side test):
/// GGX exact, Beckmann rational approximation.
pub fn ref_g1_mitsuba(dist: Distribution, ax: f64, ay: f64, v: DVec3, m: DVec3) -> f64 {
    if v.dot(m) * v.z <= 0.0 {
        return 0.0;
    }
    let s2 = v.x * v.x + v.y * v.y;
    if s2 == 0.0 {
        return 1.0;
    }
    let alpha = ((v.x * v.x * ax * ax + v.y * v.y * ay * ay) / s2).sqrt();
    let tan = s2.sqrt() / v.z.abs();
    match dist {
        Distribution::Ggx => 2.0 / (1.0 + (1.0 + alpha * alpha * tan * tan).sqrt()),
        Distribution::Beckmann => {
            let a = 1.0 / (alpha * tan);
            if a >= 1.6 {
                1.0
            } else {
                (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
            }
        }
    }
}

/// Exact Smith Λ of the upward direction with the same |cos θ| (hemispherical).
pub fn lam_up(dist: Distribution, ax: f64, ay: f64, v: DVec3) -> f64 {
    ref_lambda(dist, ax, ay, DVec3::new(v.x, v.y, v.z.abs()))
}

pub fn ref_beta(a: f64, b: f64) -> f64 {
    (libm::lgamma(a) + libm::lgamma(b) - libm::lgamma(a + b)).exp()
}

/// Side indices (η_i, η_o) of the macro pair (exterior 1, interior η).
pub fn sides(eta: f64, wi: DVec3, wo: DVec3) -> (f64, f64) {
    let ni = if wi.z > 0.0 { 1.0 } else { eta };
    let no = if wo.z > 0.0 { 1.0 } else { eta };
    (ni, no)
}

/// Walter 2007 half vector of the macro pair, oriented up (eqs. 13, 16).
pub fn walter_h(eta: f64, wi: DVec3, wo: DVec3) -> DVec3 {
    let (ni, no) = sides(eta, wi, wo);
    let h = if wi.z * wo.z > 0.0 { wi + wo } else { -(ni * wi + no * wo) };
    let h = h.normalize();
    if h.z < 0.0 {
        -h
    } else {
        h
    }
}

/// Walter 2007 BSDF·|cos θ_o| with a generic G (closure of h), Importance mode.
#[allow(clippy::too_many_arguments)] // every axis of a configuration
pub fn walter(dist: Distribution, ax: f64, ay: f64, eta: f64, wi: DVec3, wo: DVec3, g: f64, mitsuba_cutoff: bool) -> f64 {
    let (ni, no) = sides(eta, wi, wo);
    let h = walter_h(eta, wi, wo);
    let mut d = ref_d(dist, ax, ay, h);
    if mitsuba_cutoff && d * h.z <= 1e-20 {
        // Mitsuba's D drops values with D·cos θ_m ≤ 1e-20.
        d = 0.0;
    }
    let (ih, oh) = (wi.dot(h), wo.dot(h));
    let f = if ih > 0.0 { ref_fresnel(ih, eta) } else { ref_fresnel(-ih, 1.0 / eta) };
    if wi.z * wo.z > 0.0 {
        f * d * g / (4.0 * wi.z.abs())
    } else {
        let den = ni * ih + no * oh;
        (ih * oh).abs() * no * no * (1.0 - f) * d * g / (wi.z.abs() * den * den)
    }
}

/// Transmission pairs whose Fresnel term is well conditioned: cos²θ_t ≥ 0.01
/// (1 − F cancels and F' ∝ 1/cos θ_t next to the critical angle).
pub fn well_conditioned(eta: f64, wi: DVec3, wo: DVec3) -> bool {
    if wi.z * wo.z > 0.0 {
        return true;
    }
    let h = walter_h(eta, wi, wo);
    let c = wi.dot(h);
    let n = if c > 0.0 { eta } else { 1.0 / eta };
    1.0 - (1.0 - c * c) / (n * n) >= 0.01
}

pub fn rel(a: f64, b: f64) -> f64 {
    ((a - b).abs() - 1e-300).max(0.0) / a.abs().max(b.abs()).max(1e-300)
}

pub fn sphere_dir(rng: &mut Sampler, min_abs_z: f64) -> DVec3 {
    loop {
        let (a, b) = rng.next2();
        let w = uniform_sphere(a, b);
        if w.z.abs() >= min_abs_z {
            return w;
        }
    }
}

// ---------------------------------------------------------------------------
// Proposal for outgoing directions on the whole sphere: uniform sphere, plus
// reflection and refraction (Mitsuba's facet-side convention) of ω_i about GGX
// slope normals. A refraction under total internal reflection yields no sample
// (the density below is that of the valid samples: E[g/q·1_valid] = ∫g).

pub struct DielProposal {
    wi: DVec3,
    eta: f64,
    ax: f64,
    ay: f64,
    /// Mixture weights: uniform sphere, reflection, refraction, pool kernels.
    w: [f64; 4],
    /// Optional fixed pool of directions (drawn beforehand, independently of the
    /// integration samples) with von Mises–Fisher kernels of concentration `kappa`
    /// around each: a known density that follows multiple-scattering lobes.
    pool: Vec<DVec3>,
    kappa: f64,
}

/// von Mises–Fisher density κ/(2π(1 − e^{−2κ}))·e^{κ(μ·ω − 1)}.
pub fn vmf_pdf(kappa: f64, mu: DVec3, w: DVec3) -> f64 {
    kappa / (2.0 * PI * (1.0 - (-2.0 * kappa).exp())) * (kappa * (mu.dot(w) - 1.0)).exp()
}

pub fn vmf_sample(kappa: f64, mu: DVec3, u1: f64, u2: f64) -> DVec3 {
    let c = 1.0 + (u1 + (1.0 - u1) * (-2.0 * kappa).exp()).ln() / kappa;
    let c = c.clamp(-1.0, 1.0);
    let s = (1.0 - c * c).max(0.0).sqrt();
    let (t, b) = basis(mu);
    let (sp, cp) = (2.0 * PI * u2).sin_cos();
    (mu * c + t * (s * cp) + b * (s * sp)).normalize()
}

impl DielProposal {
    pub fn new(wi: DVec3, eta: f64, alpha: f64) -> Self {
        DielProposal { wi, eta, ax: alpha, ay: alpha, w: [0.1, 0.45, 0.45, 0.0], pool: Vec::new(), kappa: 1.0 }
    }

    pub fn with_pool(mut self, pool: Vec<DVec3>, alpha: f64) -> Self {
        if !pool.is_empty() {
            self.pool = pool;
            self.kappa = (1.0 / (alpha * alpha)).clamp(2.0, 200.0);
            self.w = [0.1, 0.3, 0.3, 0.3];
        }
        self
    }

    pub fn qm(&self, m: DVec3) -> f64 {
        ggx_slope_normal_pdf(self.ax, self.ay, m)
    }

    pub fn sample(&self, rng: &mut Sampler) -> Option<DVec3> {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.w[0] {
            return Some(uniform_sphere(u1, u2));
        }
        if c >= self.w[0] + self.w[1] + self.w[2] {
            let k = ((rng.next() * self.pool.len() as f64) as usize).min(self.pool.len() - 1);
            return Some(vmf_sample(self.kappa, self.pool[k], u1, u2));
        }
        let m = ggx_slope_normal(self.ax, self.ay, u1, u2);
        if c < self.w[0] + self.w[1] {
            return Some(reflect(self.wi, m).normalize());
        }
        let cos = self.wi.dot(m);
        let e = if cos >= 0.0 { self.eta } else { 1.0 / self.eta };
        let ct2 = 1.0 - (1.0 - cos * cos) / (e * e);
        if ct2 <= 0.0 {
            return None;
        }
        let ct = ct2.sqrt() * if cos >= 0.0 { -1.0 } else { 1.0 };
        Some((m * (cos / e + ct) - self.wi / e).normalize())
    }

    pub fn pdf(&self, o: DVec3) -> f64 {
        let wi = self.wi;
        let mut p = self.w[0] * UNIFORM_SPHERE_PDF;
        if self.w[3] > 0.0 {
            let k: f64 = self.pool.iter().map(|&mu| vmf_pdf(self.kappa, mu, o)).sum();
            p += self.w[3] * k / self.pool.len() as f64;
        }
        let h = wi + o;
        let len = h.length();
        if len > 1e-12 {
            let h = h / len;
            let c = wi.dot(h).abs();
            if c > 0.0 {
                p += self.w[1] * (self.qm(h) + self.qm(-h)) / (4.0 * c);
            }
        }
        for (e, from_front) in [(self.eta, true), (1.0 / self.eta, false)] {
            let h = wi + e * o;
            let len = h.length();
            if !(len > 1e-12) {
                continue;
            }
            let mut h = h / len;
            if h.z < 0.0 {
                h = -h;
            }
            let (ih, oh) = (wi.dot(h), o.dot(h));
            if (ih > 0.0) != from_front || ih == 0.0 || ih * oh >= 0.0 {
                continue;
            }
            let den = ih + e * oh;
            p += self.w[2] * self.qm(h) * e * e * oh.abs() / (den * den);
        }
        p
    }
}
