//! The multiply scattered fraction T₁ = 1 − E₁ of the height-correlated
//! position-free model (`correlated`), E₁ its order-1 albedo with F = 1
//! (conductor), a lossless interface (dielectric) or albedo 1 (diffuse), where
//! the full model's albedo is exactly 1. Stored: an upper bound T₁ + 2 standard
//! errors per node, over α (log grid 0.005 … 4), μ_i = |cos θ_i| (μ² uniform
//! over 0.02² … 1) and, for dielectrics, the relative IOR seen from ω_i
//! (log grid 1/3 … 3). E₁ is the expectation of the first vertex's exit
//! probability over the visible normals (jittered 32 × 32 grid, 64 × 64 for the
//! diffuse microsurface's extra cosine direction, fixed seed): G2 reflection
//! L₀/(L₀ + Λ), Beta transmission L₀·B(L₀, 1 + Λ'). Used by `auto`
//! (`mod.rs` here), which explains why F = 1 bounds every material.

use crate::config::Distribution;
use crate::config::Surface;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{reflect, refract, Microfacet};
use crate::models::posfree::{dielectric as posfree_dielectric, Segments};
use crate::rng::{hash_words, Sampler};
use crate::tables::{self, Axis, Warp};
use crate::walk::cosine_about;
use glam::DVec3;
use std::sync::OnceLock;

/// ln of the smallest and largest tabulated roughness, 0.005 and 4.
const LN_ALPHA_MIN: f64 = -5.298_317_366_548_036;
const LN_ALPHA_MAX: f64 = 1.386_294_361_119_890_6;
/// ln 3: relative IORs from 1/3 to 3.
const LN_ETA_MAX: f64 = 1.098_612_288_668_109_8;
/// Smallest tabulated μ_i; below it (grazing) `auto` runs the full model.
pub const MU_MIN: f64 = 0.02;

/// Roughness nodes, log-uniform over [0.005, 4].
pub const ALPHA: Axis = Axis::ends(Warp::Ln, LN_ALPHA_MIN, LN_ALPHA_MAX, 24);
/// μ nodes uniform in μ² over [MU_MIN², 1] (denser towards grazing).
pub const MU: Axis = Axis::ends(Warp::Square, MU_MIN * MU_MIN, 1.0, 16);
/// Relative-IOR nodes, log-uniform over [1/3, 3] (dielectrics only).
pub const ETA: Axis = Axis::ends(Warp::Ln, -LN_ETA_MAX, LN_ETA_MAX, 13);

/// T₁ bounds of one surface and distribution. Dielectric rows are computed one
/// IOR node at a time, when a query first needs it (a scene uses one or two IORs).
pub struct MsTable {
    pub surface: Surface,
    pub dist: Distribution,
    /// Per IOR node: [alpha][mu] T₁ + 2 SE.
    rows: Vec<OnceLock<Vec<f32>>>,
    eta_nodes: [f64; ETA.n],
}

impl MsTable {
    /// The table of a surface and distribution (rows computed on first use).
    pub fn get(surface: Surface, dist: Distribution) -> &'static MsTable {
        static TABLES: [OnceLock<MsTable>; 6] = [const { OnceLock::new() }; 6];
        let i = 2 * surface as usize + (dist == Distribution::Ggx) as usize;
        TABLES[i].get_or_init(|| {
            let n_eta = if surface == Surface::Dielectric { ETA.n } else { 1 };
            MsTable { surface, dist, rows: (0..n_eta).map(|_| OnceLock::new()).collect(), eta_nodes: std::array::from_fn(|e| ETA.node(e)) }
        })
    }

    /// Number of IOR rows (1 for conductors and diffuse microsurfaces).
    pub fn eta_rows(&self) -> usize {
        self.rows.len()
    }

    /// IOR row `e`, computed on first use over the available threads.
    fn row(&self, e: usize) -> &[f32] {
        self.rows[e].get_or_init(|| {
            let eta = if self.surface == Surface::Dielectric { self.eta_nodes[e] } else { 1.0 };
            tables::build(ALPHA.n, MU.n, |a, out: &mut [f32]| {
                for (i, v) in out.iter_mut().enumerate() {
                    *v = ms_fraction_bound(self.surface, self.dist, eta, ALPHA.node(a), MU.node(i)) as f32;
                }
            })
        })
    }

    /// T₁ bound at grid node (IOR e, α a, μ i).
    pub fn node(&self, e: usize, a: usize, i: usize) -> f64 {
        self.row(e)[a * MU.n + i] as f64
    }

    /// The one or two IOR nodes bracketing `eta` (0 for non-dielectrics);
    /// None off the grid.
    pub fn eta_bracket(&self, eta: f64) -> Option<(usize, usize)> {
        if self.surface != Surface::Dielectric {
            return Some((0, 0));
        }
        let nodes = &self.eta_nodes;
        if !(eta >= nodes[0] && eta <= nodes[ETA.n - 1]) {
            return None;
        }
        let above = nodes.partition_point(|&v| v < eta).min(ETA.n - 1); // first node ≥ eta
        if above == 0 || nodes[above] == eta {
            Some((above, above))
        } else {
            Some((above - 1, above))
        }
    }
}

/// Index of the μ cell (between nodes i and i+1) holding μ; None below MU_MIN.
#[inline]
pub fn mu_cell(mu: f64) -> Option<usize> {
    if !(mu >= MU_MIN) {
        return None;
    }
    let x = (mu.min(1.0) * mu.min(1.0) - MU.lo) * ((MU.n - 1) as f64 / (MU.hi - MU.lo));
    Some((x.max(0.0) as usize).min(MU.n - 2)) // truncation: no libm floor on baseline x86-64
}

/// Upper bound T₁ + 2 SE of the multiply scattered fraction at one node:
/// 1 − the mean first-vertex exit probability of the correlated model.
fn ms_fraction_bound(surface: Surface, dist: Distribution, eta: f64, alpha: f64, mu: f64) -> f64 {
    let mf = Microfacet::new(dist, alpha, alpha);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let l0 = 1.0 + mf.lambda(wi);
    let side = if surface == Surface::Diffuse { 64 } else { 32 };
    let mut rng = Sampler::new(hash_words(&[surface as u64, dist as u64, eta.to_bits(), alpha.to_bits(), mu.to_bits()]));
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
    (1.0 - mean + 2.0 * se).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_bounds_are_the_logs_of_the_ranges() {
        assert_eq!(LN_ALPHA_MIN, 0.005f64.ln());
        assert_eq!(LN_ALPHA_MAX, 4f64.ln());
        assert_eq!(LN_ETA_MAX, 3f64.ln());
    }
}
