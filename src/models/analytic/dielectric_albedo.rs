//! E_r + E_t of `single` on a rough dielectric (Importance mode, no 1/η²) over
//! (α, relative IOR n, μ) for both sides of the interface: entering a denser
//! medium (η_r = n ≥ 1) and leaving it (η_r = 1/n, total internal reflection
//! included). Computed on first use by a deterministic product quadrature over
//! visible normals (exact VNDF, weight G1_mitsuba(ω_i)/G1_exact(ω_i) ·
//! (F·G1(ω_r) + (1 − F)·G1(ω_t))) and cached per distribution. Used by
//! `compensated` on dielectrics (src/models/analytic/compensated_dielectric.rs).

use crate::config::Distribution;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{mitsuba, reflect, refract, Microfacet};
use crate::tables::{self, Axis, Grid, Warp};
use glam::DVec3;
use std::sync::OnceLock;

/// Relative IORs the table spans (n ≥ 1; the leaving side reads 1/n).
pub const ETA_MIN: f64 = 1.01;
pub const ETA_MAX: f64 = 3.0;
/// Roughness nodes uniform in √α over [1e-4, 4] (as the conductor table).
pub const ALPHA: Axis = Axis::ends(Warp::Sqrt, 0.01, 2.0, 32);
/// μ nodes uniform in μ over [0, 1] (node 0 evaluated at μ = 1e-3).
pub const MU: Axis = Axis::ends(Warp::Identity, 0.0, 1.0, 32);
/// Number of IOR nodes ([`eta_axis`]).
pub const N_ETA: usize = 32;
/// Quadrature grid per (α, μ): GRID × GRID visible normals (warped product
/// midpoint rule), shared by every η node and both sides.
pub const GRID: usize = 28;
/// Lower clamp of the tabulated albedo (bounds the compensation by 1/E_MIN).
pub const E_MIN: f64 = 1e-3;
/// μ at which node 0 (μ = 0) is evaluated.
const MU_FLOOR: f64 = 1e-3;

/// IOR nodes uniform in the cosine of the critical angle √(1 − 1/n²) between
/// ETA_MIN and ETA_MAX, which spreads them where the albedos change fastest
/// (n near 1, where the total-internal-reflection cone opens).
pub fn eta_axis() -> Axis {
    let w = Warp::CriticalCosine;
    Axis::ends(w, w.apply(ETA_MIN), w.apply(ETA_MAX), N_ETA)
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
    enter: Grid<3>,
    leave: Grid<3>,
}

impl DielectricAlbedoTable {
    /// Computes the table (uncached; `get` caches it) over the available threads.
    pub fn compute(dist: Distribution) -> Self {
        let eta = eta_axis();
        let etas: Vec<f64> = (0..eta.n).map(|k| eta.node(k)).collect();
        let row = eta.n * MU.n;
        // Per α row: [side][eta][mu] with side 0 entering, 1 leaving.
        let rows = tables::build(ALPHA.n, 2 * row, |j, out: &mut [f64]| {
            for i in 0..MU.n {
                let (e, l) = single_albedo_multi(dist, ALPHA.node(j), MU.node(i).max(MU_FLOOR), &etas, GRID);
                for k in 0..eta.n {
                    out[k * MU.n + i] = e[k].clamp(E_MIN, 1.0);
                    out[row + k * MU.n + i] = l[k].clamp(E_MIN, 1.0);
                }
            }
        });
        let side =
            |s: usize| Grid { axes: [ALPHA, eta, MU], values: rows.chunks(2 * row).flat_map(|r| r[s * row..(s + 1) * row].to_vec()).collect() };
        DielectricAlbedoTable { enter: side(0), leave: side(1) }
    }

    pub fn get(dist: Distribution) -> &'static DielectricAlbedoTable {
        static TABLES: [OnceLock<DielectricAlbedoTable>; 2] = [const { OnceLock::new() }; 2];
        tables::per_distribution(&TABLES, dist, Self::compute)
    }

    /// The grids (entering, leaving) over (α, n, μ), for the C ABI's `msx_table`.
    pub fn grids(&self) -> [&Grid<3>; 2] {
        [&self.enter, &self.leave]
    }

    /// E(μ, α, η_r), trilinear in (√α, √(1 − 1/n²), μ); η_r < 1 reads the leaving table at 1/η_r.
    pub fn e(&self, alpha: f64, mu: f64, eta_r: f64) -> f64 {
        let (n, table) = if eta_r >= 1.0 { (eta_r, &self.enter) } else { (1.0 / eta_r, &self.leave) };
        table.at([alpha, n, mu.abs()])
    }
}
