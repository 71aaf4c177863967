//! Directional albedo tables (F = 1) over (cos θ, α), computed by this
//! project's own deterministic quadrature on first use and cached: the
//! single-scattering albedo of `single` (for `compensated`) and the order-1
//! albedos of the multiple-scattering models (for the MIS density).

use crate::microfacet::{mitsuba, reflect, Distribution, Microfacet};
use glam::DVec3;
use std::sync::OnceLock;

/// Table resolution: cos θ nodes (uniform in μ²) and roughness nodes uniform
/// in √α over [1e-4, 4] (E varies fastest with α at high roughness, where a
/// log-α grid was measured 3 % off between nodes).
const N_MU: usize = 32;
const N_ALPHA: usize = 48;
const SQRT_ALPHA_MIN: f64 = 0.01;
const SQRT_ALPHA_MAX: f64 = 2.0;
/// Stratified quadrature grid per table entry (GRID × GRID visible normals).
const GRID: usize = 32;

/// Directional albedos with F = 1 for one distribution, over (μ, α):
/// `single` (Mitsuba's separable G, for `compensated`) and order 1 of the
/// uncorrelated and height-correlated models (for the MIS density), plus E_avg(α).
pub struct AlbedoTable {
    e: Vec<f64>,        // [alpha][mu], single
    e1_uncorr: Vec<f64>, // [alpha][mu], ∫ D G1(ω_i) G1(ω_o) / (4 cos θ_i)
    e1_corr: Vec<f64>,   // [alpha][mu], ∫ D G2(ω_i, ω_o) / (4 cos θ_i)
    e_avg: Vec<f64>,    // [alpha]
}

fn mu_node(i: usize) -> f64 {
    // Nodes from grazing to normal incidence, denser near grazing.
    let t = (i as f64 + 0.5) / N_MU as f64;
    t.sqrt()
}

fn alpha_node(j: usize) -> f64 {
    (SQRT_ALPHA_MIN + (SQRT_ALPHA_MAX - SQRT_ALPHA_MIN) * j as f64 / (N_ALPHA - 1) as f64).powi(2)
}

/// Directional albedos with F = 1 at (α, μ): (single with Mitsuba's G1,
/// order 1 uncorrelated, order 1 correlated). Expectations over visible
/// normals m ~ D_{ω_i} (density D·G1(ω_i)⟨ω_i, m⟩/cos θ_i) of, respectively,
/// G1m(ω_i)·G1m(ω_o)/G1(ω_i), G1(ω_o) and (1 + Λ_i)/(1 + Λ_i + Λ_o).
pub fn albedos(dist: Distribution, alpha: f64, mu: f64) -> (f64, f64, f64) {
    let mf = Microfacet::new(dist, alpha, alpha);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1_exact = mf.g1_dist(wi);
    let l0 = 1.0 + mf.lambda(wi);
    let (mut s, mut su, mut sc) = (0.0, 0.0, 0.0);
    for a in 0..GRID {
        for b in 0..GRID {
            let u1 = (a as f64 + 0.5) / GRID as f64;
            let u2 = (b as f64 + 0.5) / GRID as f64;
            let Some(m) = mf.sample_visible(wi, u1, u2) else { continue };
            let wo = reflect(wi, m);
            if wo.z <= 0.0 {
                continue;
            }
            let lo = mf.lambda(wo);
            s += mitsuba::smith_g1(&mf, wi, m) * mitsuba::smith_g1(&mf, wo, m) / g1_exact;
            su += 1.0 / (1.0 + lo);
            sc += l0 / (l0 + lo);
        }
    }
    let n = (GRID * GRID) as f64;
    (s / n, su / n, sc / n)
}

/// Directional albedo of `single` with F = 1 (Mitsuba's G1).
pub fn single_albedo(dist: Distribution, alpha: f64, mu: f64) -> f64 {
    albedos(dist, alpha, mu).0
}

impl AlbedoTable {
    fn compute(dist: Distribution) -> Self {
        let mut e = vec![0.0; N_ALPHA * N_MU];
        let mut e1_uncorr = vec![0.0; N_ALPHA * N_MU];
        let mut e1_corr = vec![0.0; N_ALPHA * N_MU];
        let mut e_avg = vec![0.0; N_ALPHA];
        for j in 0..N_ALPHA {
            let alpha = alpha_node(j);
            let mut avg = 0.0;
            for i in 0..N_MU {
                let (single, uncorr, corr) = albedos(dist, alpha, mu_node(i));
                let v = single.clamp(1e-6, 1.0);
                e[j * N_MU + i] = v;
                e1_uncorr[j * N_MU + i] = uncorr.clamp(0.0, 1.0);
                e1_corr[j * N_MU + i] = corr.clamp(0.0, 1.0);
                // 2∫E μ dμ with μ = √t: dμ·2μ = dt, so a midpoint rule in t.
                avg += v / N_MU as f64;
            }
            e_avg[j] = avg;
        }
        AlbedoTable { e, e1_uncorr, e1_corr, e_avg }
    }

    pub fn get(dist: Distribution) -> &'static AlbedoTable {
        static GGX: OnceLock<AlbedoTable> = OnceLock::new();
        static BECKMANN: OnceLock<AlbedoTable> = OnceLock::new();
        match dist {
            Distribution::Ggx => GGX.get_or_init(|| AlbedoTable::compute(Distribution::Ggx)),
            Distribution::Beckmann => BECKMANN.get_or_init(|| AlbedoTable::compute(Distribution::Beckmann)),
        }
    }

    fn alpha_coord(alpha: f64) -> (usize, f64) {
        let x = ((alpha.sqrt() - SQRT_ALPHA_MIN) / (SQRT_ALPHA_MAX - SQRT_ALPHA_MIN) * (N_ALPHA - 1) as f64).clamp(0.0, (N_ALPHA - 1) as f64);
        let j = (x.floor() as usize).min(N_ALPHA - 2);
        (j, x - j as f64)
    }

    /// Bilinear interpolation in (μ², √α).
    fn lerp(table: &[f64], alpha: f64, mu: f64) -> f64 {
        let (j, fa) = Self::alpha_coord(alpha);
        let x = (mu.clamp(0.0, 1.0).powi(2) * N_MU as f64 - 0.5).clamp(0.0, (N_MU - 1) as f64);
        let i = (x.floor() as usize).min(N_MU - 2);
        let fm = x - i as f64;
        let at = |jj: usize| table[jj * N_MU + i] * (1.0 - fm) + table[jj * N_MU + i + 1] * fm;
        at(j) * (1.0 - fa) + at(j + 1) * fa
    }

    /// E(μ, α) of `single` (F = 1).
    pub fn e(&self, alpha: f64, mu: f64) -> f64 {
        Self::lerp(&self.e, alpha, mu)
    }

    /// Order-1 albedo (F = 1) of the uncorrelated (separable exact G1) model.
    pub fn e1_uncorrelated(&self, alpha: f64, mu: f64) -> f64 {
        Self::lerp(&self.e1_uncorr, alpha, mu)
    }

    /// Order-1 albedo (F = 1) with the height-correlated G2 (correlated, heitz, invariance).
    pub fn e1_correlated(&self, alpha: f64, mu: f64) -> f64 {
        Self::lerp(&self.e1_corr, alpha, mu)
    }

    pub fn e_avg(&self, alpha: f64) -> f64 {
        let (j, fa) = Self::alpha_coord(alpha);
        self.e_avg[j] * (1.0 - fa) + self.e_avg[j + 1] * fa
    }
}

