//! Directional albedo tables (F = 1) over (cos θ, α), computed by this
//! project's own deterministic quadrature on first use and cached: the
//! single-scattering albedo of `single` (for `compensated`) and the order-1
//! albedos of the multiple-scattering models (for the MIS density).

use super::{Axis, Grid, Warp};
use crate::config::Distribution;
use crate::microfacet::{mitsuba, reflect, Microfacet};
use crate::tables;
use glam::DVec3;
use std::sync::OnceLock;

/// Roughness nodes uniform in √α over [1e-4, 4] (E varies fastest with α
/// at high roughness, where a log-α grid was measured 3 % off between nodes).
const ALPHA: Axis = Axis::ends(Warp::Sqrt, 0.01, 2.0, 48);
/// cos θ nodes at the centres of 32 equal cells of μ² (denser near grazing).
const MU: Axis = Axis::centred(Warp::Square, 0.0, 1.0, 32);
/// Stratified quadrature grid per table entry (GRID × GRID visible normals).
const GRID: usize = 32;

/// Directional albedos with F = 1 for one distribution, over (α, μ):
/// `single` (Mitsuba's separable G, for `compensated`) and order 1 of the
/// uncorrelated and height-correlated models (for the MIS density), plus E_avg(α).
pub struct AlbedoTable {
    /// `single`, clamped into [1e-6, 1].
    e: Grid<2>,
    /// ∫ D G1(ω_i) G1(ω_o) / (4 cos θ_i).
    e1_uncorr: Grid<2>,
    /// ∫ D G2(ω_i, ω_o) / (4 cos θ_i).
    e1_corr: Grid<2>,
    /// 2∫E(μ)μ dμ of `single`.
    e_avg: Grid<1>,
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
        // Per α row: the three albedos at every μ node, and E_avg.
        let rows = tables::build(ALPHA.n, 3 * MU.n + 1, |j, row: &mut [f64]| {
            let alpha = ALPHA.node(j);
            let mut avg = 0.0;
            for i in 0..MU.n {
                let (single, uncorr, corr) = albedos(dist, alpha, MU.node(i));
                let v = single.clamp(1e-6, 1.0);
                row[i] = v;
                row[MU.n + i] = uncorr.clamp(0.0, 1.0);
                row[2 * MU.n + i] = corr.clamp(0.0, 1.0);
                // 2∫E μ dμ with μ = √t: dμ·2μ = dt, so a midpoint rule in t.
                avg += v / MU.n as f64;
            }
            row[3 * MU.n] = avg;
        });
        let part =
            |k: usize| Grid { axes: [ALPHA, MU], values: rows.chunks(3 * MU.n + 1).flat_map(|r| r[k * MU.n..(k + 1) * MU.n].to_vec()).collect() };
        let e_avg = Grid { axes: [ALPHA], values: rows.chunks(3 * MU.n + 1).map(|r| r[3 * MU.n]).collect() };
        AlbedoTable { e: part(0), e1_uncorr: part(1), e1_corr: part(2), e_avg }
    }

    pub fn get(dist: Distribution) -> &'static AlbedoTable {
        static TABLES: [OnceLock<AlbedoTable>; 2] = [const { OnceLock::new() }; 2];
        tables::per_distribution(&TABLES, dist, AlbedoTable::compute)
    }

    /// E(μ, α) of `single` (F = 1).
    pub fn e(&self, alpha: f64, mu: f64) -> f64 {
        self.e.at([alpha, mu])
    }

    /// Order-1 albedo (F = 1) of the uncorrelated (separable exact G1) model.
    pub fn e1_uncorrelated(&self, alpha: f64, mu: f64) -> f64 {
        self.e1_uncorr.at([alpha, mu])
    }

    /// Order-1 albedo (F = 1) with the height-correlated G2 (correlated, heitz, invariance).
    pub fn e1_correlated(&self, alpha: f64, mu: f64) -> f64 {
        self.e1_corr.at([alpha, mu])
    }

    pub fn e_avg(&self, alpha: f64) -> f64 {
        self.e_avg.at([alpha])
    }

    /// The grids themselves (for the C ABI's `msx_table`, which hands them to
    /// the Dr.Jit engine): `single`, order 1 uncorrelated, order 1 correlated.
    pub fn grids(&self) -> [&Grid<2>; 3] {
        [&self.e, &self.e1_uncorr, &self.e1_corr]
    }

    /// The grid of E_avg(α) (for `msx_table`).
    pub fn e_avg_grid(&self) -> &Grid<1> {
        &self.e_avg
    }
}
