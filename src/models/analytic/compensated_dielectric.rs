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
//! The table E(μ, α, n) is computed on first use by this project's own
//! deterministic product quadrature over visible normals (exact VNDF, weight
//! G1_mitsuba(ω_i)/G1_exact(ω_i) · (F·G1(ω_r) + (1 − F)·G1(ω_t))) and cached
//! in a `OnceLock` per distribution.
//!
//! Limitations: the compensated lobe is not reciprocal (the scale depends on
//! ω_i only, as in Turquin 2019); anisotropic roughness uses α = √(α_u α_v);
//! η_r outside [1/3, 3] or within 1.01 of 1 uses the nearest table edge.

use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{mitsuba, reflect, refract, Distribution, Microfacet};
use crate::models::single::dielectric as single_dielectric;
use glam::DVec3;
use std::sync::OnceLock;

/// Table resolution. μ nodes uniform in μ over [0, 1] (node 0 evaluated at
/// μ = 1e-3); roughness nodes uniform in √α over [1e-4, 4] (as the conductor
/// table); relative IOR nodes uniform in √(1 − 1/n²) over n ∈ [1.01, 3].
pub const N_MU: usize = 32;
pub const N_ALPHA: usize = 32;
pub const N_ETA: usize = 32;
const SQRT_ALPHA_MIN: f64 = 0.01;
const SQRT_ALPHA_MAX: f64 = 2.0;
pub const ETA_MIN: f64 = 1.01;
pub const ETA_MAX: f64 = 3.0;
/// Quadrature grid per (μ, α): GRID × GRID visible normals (warped product
/// midpoint rule), shared by every η node and both sides.
pub const GRID: usize = 28;
/// Lower clamp of the tabulated albedo (bounds the scale by 1/E_MIN).
const E_MIN: f64 = 1e-3;

fn mu_node(i: usize) -> f64 {
    (i as f64 / (N_MU - 1) as f64).max(1e-3)
}

fn alpha_node(j: usize) -> f64 {
    (SQRT_ALPHA_MIN + (SQRT_ALPHA_MAX - SQRT_ALPHA_MIN) * j as f64 / (N_ALPHA - 1) as f64).powi(2)
}

/// The relative-IOR coordinate: the cosine of the critical angle √(1 − 1/n²),
/// which spreads the nodes where the albedos change fastest (n near 1, where
/// the total-internal-reflection cone opens).
fn eta_coord(n: f64) -> f64 {
    (1.0 - 1.0 / (n * n)).max(0.0).sqrt()
}

fn eta_node(k: usize) -> f64 {
    let (y0, y1) = (eta_coord(ETA_MIN), eta_coord(ETA_MAX));
    let y = y0 + (y1 - y0) * k as f64 / (N_ETA - 1) as f64;
    1.0 / (1.0 - y * y).sqrt()
}

/// Directional albedos E_r + E_t of `single_dielectric` (Importance mode) for
/// an upward ω_i with cos θ_i = μ at every relative IOR of `etas`, for both
/// sides: returns (entering: η_r = n, leaving: η_r = 1/n) per n, by the
/// deterministic product quadrature with `grid`² visible normals.
pub fn single_albedo_multi(dist: Distribution, alpha: f64, mu: f64, etas: &[f64], grid: usize) -> (Vec<f64>, Vec<f64>) {
    let mf = Microfacet::new(dist, alpha, alpha);
    let mu = mu.clamp(1e-6, 1.0);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let g1_exact = mf.g1_dist(wi);
    let mut enter = vec![0.0; etas.len()];
    let mut leave = vec![0.0; etas.len()];
    if !(g1_exact > 0.0) {
        return (enter, leave);
    }
    // Product midpoint rule in s ∈ [0, 1]² warped by u = s²(3 − 2s) (weight
    // du/ds = 6s(1 − s)): nodes crowd both ends of each sampler input, where
    // the tails of the slope distribution (steep facets: grazing refraction,
    // total internal reflection) live.
    let nodes: Vec<(f64, f64)> = (0..grid)
        .map(|a| {
            let s = (a as f64 + 0.5) / grid as f64;
            (s * s * (3.0 - 2.0 * s), 6.0 * s * (1.0 - s) / grid as f64)
        })
        .collect();
    for &(u1, w1) in &nodes {
        for &(u2, w2) in &nodes {
            let Some(m) = mf.sample_visible(wi, u1, u2) else { continue };
            let w = w1 * w2 * mitsuba::smith_g1(&mf, wi, m) / g1_exact;
            if !(w > 0.0) {
                continue;
            }
            let wim = wi.dot(m);
            let g_r = mitsuba::smith_g1(&mf, reflect(wi, m), m);
            for (k, &n) in etas.iter().enumerate() {
                // Entering (ω_i outside, η = n) and leaving (by the z-mirror
                // symmetry, ω_i inside with η = n equals ω_i outside with η = 1/n).
                for (side, eta) in [(0, n), (1, 1.0 / n)] {
                    let (f, cos_t, _, eta_ti) = dielectric_full(wim, eta);
                    let g_t = if f < 1.0 { mitsuba::smith_g1(&mf, refract(wi, m, cos_t, eta_ti), m) } else { 0.0 };
                    let v = w * (f * g_r + (1.0 - f) * g_t);
                    if side == 0 {
                        enter[k] += v;
                    } else {
                        leave[k] += v;
                    }
                }
            }
        }
    }
    (enter, leave)
}

/// Direct (untabulated) quadrature of the albedo at one relative IOR η_r
/// (> 1: entering a denser medium, < 1: leaving it), `grid`² visible normals.
pub fn single_albedo(dist: Distribution, alpha: f64, mu: f64, eta_r: f64, grid: usize) -> f64 {
    let (n, leaving) = if eta_r >= 1.0 { (eta_r, false) } else { (1.0 / eta_r, true) };
    let (e, l) = single_albedo_multi(dist, alpha, mu, &[n], grid);
    if leaving {
        l[0]
    } else {
        e[0]
    }
}

/// E(μ, α, n) for both sides of the interface, one distribution.
pub struct DielectricAlbedoTable {
    enter: Vec<f64>, // [alpha][eta][mu]
    leave: Vec<f64>, // [alpha][eta][mu]
}

impl DielectricAlbedoTable {
    /// Computes the table (uncached; `get` caches it). Rows of α are split
    /// over the available threads; the result does not depend on the split.
    pub fn compute(dist: Distribution) -> Self {
        let etas: Vec<f64> = (0..N_ETA).map(eta_node).collect();
        let row = N_ETA * N_MU;
        let mut enter = vec![0.0; N_ALPHA * row];
        let mut leave = vec![0.0; N_ALPHA * row];
        let fill = |j: usize, en: &mut [f64], le: &mut [f64]| {
            for i in 0..N_MU {
                let (e, l) = single_albedo_multi(dist, alpha_node(j), mu_node(i), &etas, GRID);
                for k in 0..N_ETA {
                    en[k * N_MU + i] = e[k].clamp(E_MIN, 1.0);
                    le[k * N_MU + i] = l[k].clamp(E_MIN, 1.0);
                }
            }
        };
        let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).clamp(1, 8);
        let rows_per = N_ALPHA.div_ceil(threads);
        std::thread::scope(|s| {
            for (t, (en, le)) in enter.chunks_mut(rows_per * row).zip(leave.chunks_mut(rows_per * row)).enumerate() {
                let fill = &fill;
                s.spawn(move || {
                    for (r, (en_r, le_r)) in en.chunks_mut(row).zip(le.chunks_mut(row)).enumerate() {
                        fill(t * rows_per + r, en_r, le_r);
                    }
                });
            }
        });
        DielectricAlbedoTable { enter, leave }
    }

    pub fn get(dist: Distribution) -> &'static DielectricAlbedoTable {
        static GGX: OnceLock<DielectricAlbedoTable> = OnceLock::new();
        static BECKMANN: OnceLock<DielectricAlbedoTable> = OnceLock::new();
        match dist {
            Distribution::Ggx => GGX.get_or_init(|| Self::compute(Distribution::Ggx)),
            Distribution::Beckmann => BECKMANN.get_or_init(|| Self::compute(Distribution::Beckmann)),
        }
    }

    /// (lower node, fraction) of x ∈ [0, n − 1] clamped.
    #[inline]
    fn coord(x: f64, n: usize) -> (usize, f64) {
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, (n - 1) as f64) };
        let i = (x.floor() as usize).min(n - 2);
        (i, x - i as f64)
    }

    /// E(μ, α, η_r), trilinear in (μ, √α, √(1 − 1/n²)); η_r < 1 reads the leaving table at 1/η_r.
    pub fn e(&self, alpha: f64, mu: f64, eta_r: f64) -> f64 {
        let (n, table) = if eta_r >= 1.0 { (eta_r, &self.enter) } else { (1.0 / eta_r, &self.leave) };
        let (j, fa) = Self::coord((alpha.sqrt() - SQRT_ALPHA_MIN) / (SQRT_ALPHA_MAX - SQRT_ALPHA_MIN) * (N_ALPHA - 1) as f64, N_ALPHA);
        let (y0, y1) = (eta_coord(ETA_MIN), eta_coord(ETA_MAX));
        let (k, fe) = Self::coord((eta_coord(n) - y0) / (y1 - y0) * (N_ETA - 1) as f64, N_ETA);
        let (i, fm) = Self::coord(mu.abs() * (N_MU - 1) as f64, N_MU);
        let at = |jj: usize, kk: usize| {
            let base = jj * N_ETA * N_MU + kk * N_MU + i;
            table[base] * (1.0 - fm) + table[base + 1] * fm
        };
        let at_a = |jj: usize| at(jj, k) * (1.0 - fe) + at(jj, k + 1) * fe;
        at_a(j) * (1.0 - fa) + at_a(j + 1) * fa
    }
}

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

/// Density of `sample` (the single-scattering sampler's).
pub fn pdf(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    single_dielectric::pdf(mf, eta, wi, wo)
}

/// Samples ω_o as `single_dielectric::sample`; returns (ω_o, pdf, weight = eval/pdf).
pub fn sample(mf: &Microfacet, eta: f64, wi: DVec3, sample1: f64, u1: f64, u2: f64, radiance: bool) -> Option<(DVec3, f64, f64)> {
    let (wo, pdf, weight, _) = single_dielectric::sample(mf, eta, wi, sample1, u1, u2, radiance)?;
    Some((wo, pdf, weight * scale(mf, eta, wi)))
}
