//! `model="auto"` (README.md, model table): model no more than a scene needs.
//!
//! The converged model is the height-correlated position-free model
//! (`correlated`, all orders). For smooth surfaces almost all of its energy is
//! in order 1, which is analytic (Walter 2007 with the height-correlated G2:
//! deterministic, nearly as cheap as `single`). `auto` evaluates order 1 alone
//! where the energy of the orders above — the multiply scattered fraction
//! T₁ — is at most `tolerance` of what the surface scatters, and the full
//! `correlated` model elsewhere, per call (α can be textured, θ_i varies).
//!
//! **Why no intermediate bounce count.** Truncating the walk after k ≥ 2
//! bounces was implemented and measured first (per-order tails of the
//! correlated sampler, benches/models.rs, Cu, GGX α = 0.5 and 1): variance per
//! call within 1 % of the full model and no time saved — Russian roulette
//! already ends the long walks, so a cap of 4–8 bounces removes almost no work,
//! while the table lookup cost ≈ 10 % of an evaluation. Only the step from
//! "walk" to "no walk" pays.
//!
//! **Table.** For each surface (conductor, dielectric, diffuse) and
//! distribution, over α (log grid 0.005 … 4), μ_i = |cos θ_i| (0.02 … 1) and, for
//! dielectrics, the relative IOR seen from ω_i (1/3 … 3): T₁ = 1 − E₁, E₁ the
//! order-1 albedo of the correlated model with F = 1 (conductor), a lossless
//! interface (dielectric) or albedo 1 (diffuse), where the full model's albedo
//! is exactly 1 (tests/furnace.rs, tests/posfree_*). E₁ is the expectation of
//! the first vertex's exit probability over the visible normals (jittered
//! 32 × 32 or 64 × 64 grid, fixed seed): G2 reflection L₀/(L₀ + Λ), Beta
//! transmission L₀·B(L₀, 1 + Λ'), and for the diffuse microsurface one cosine
//! direction per normal. Stored: T₁ + 2 standard errors of the mean.
//!
//! **Why F = 1 / albedo 1 bounds every material.** A conductor attenuates
//! order j by a product of j Fresnel factors ≤ 1 and a diffuse microsurface
//! by a^j: weights that decrease with the order move energy to order 1, so the
//! omitted fraction can only shrink (measured in tests/auto.rs for copper and
//! albedo 0.5). Tints scale all orders alike.
//!
//! **Lookup.** Conservative and cheap: for a tolerance, each μ cell (and IOR
//! node) stores the largest α node below which every grid cell has all four
//! corners within the tolerance (T₁ grows with α, and towards grazing
//! incidence). A call compares its α with the thresholds of its μ cell (of
//! both bracketing IOR rows for dielectrics). Off the grid (α > 4, μ < 0.02,
//! IOR ratio beyond 1/3 … 3): the full model. Anisotropy uses max(α_u, α_v).

use super::posfree::{dielectric as posfree_dielectric, Segments};
use crate::walk::cosine_about;
use crate::microfacet::fresnel::dielectric_full;
use crate::microfacet::{reflect, refract, Distribution, Microfacet};
use crate::rng::{hash_words, Sampler};
use glam::DVec3;
use std::sync::OnceLock;

/// Default tolerance: 1 % of the scattered energy may be omitted.
pub const DEFAULT_TOLERANCE: f64 = 0.01;

const N_ALPHA: usize = 24;
const ALPHA_MIN: f64 = 0.005;
const ALPHA_MAX: f64 = 4.0;
const N_MU: usize = 16;
const MU_MIN: f64 = 0.02;
const N_ETA: usize = 13;
const LN_ETA_MAX: f64 = 1.098_612_288_668_109_8; // ln 3

/// Which microsurface a table describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TableSurface {
    Conductor,
    Dielectric,
    Diffuse,
}

fn alpha_node(j: usize) -> f64 {
    ALPHA_MIN * (ALPHA_MAX / ALPHA_MIN).powf(j as f64 / (N_ALPHA - 1) as f64)
}

/// μ nodes uniform in μ² between MU_MIN² and 1 (denser towards grazing).
fn mu_node(i: usize) -> f64 {
    let t = MU_MIN * MU_MIN + (1.0 - MU_MIN * MU_MIN) * i as f64 / (N_MU - 1) as f64;
    t.sqrt()
}

fn eta_node(e: usize) -> f64 {
    (LN_ETA_MAX * (2.0 * e as f64 / (N_ETA - 1) as f64 - 1.0)).exp()
}

/// Index of the μ cell (between nodes i and i+1) holding μ; None below MU_MIN.
#[inline]
fn mu_cell(mu: f64) -> Option<usize> {
    if !(mu >= MU_MIN) {
        return None;
    }
    let x = (mu.min(1.0) * mu.min(1.0) - MU_MIN * MU_MIN) * ((N_MU - 1) as f64 / (1.0 - MU_MIN * MU_MIN));
    Some((x.max(0.0) as usize).min(N_MU - 2)) // truncation: no libm floor on baseline x86-64
}

/// Multiply scattered energy fraction T₁ (upper bound) of one surface and
/// distribution over the grid. Dielectric rows are computed one IOR node at a
/// time, when a query first needs it (a scene uses one or two IORs).
pub struct MsTable {
    surface: TableSurface,
    dist: Distribution,
    /// Per IOR node: [alpha][mu] T₁ + 2 SE.
    rows: Vec<OnceLock<Vec<f32>>>,
    eta_nodes: [f64; N_ETA],
}

impl MsTable {
    /// The table of a surface and distribution (rows computed on first use).
    pub fn get(surface: TableSurface, dist: Distribution) -> &'static MsTable {
        static TABLES: [OnceLock<MsTable>; 6] = [const { OnceLock::new() }; 6];
        let i = 2 * surface as usize + (dist == Distribution::Ggx) as usize;
        TABLES[i].get_or_init(|| {
            let n_eta = if surface == TableSurface::Dielectric { N_ETA } else { 1 };
            MsTable { surface, dist, rows: (0..n_eta).map(|_| OnceLock::new()).collect(), eta_nodes: std::array::from_fn(eta_node) }
        })
    }

    /// Row `e`, computed on first use over the available threads.
    fn row(&self, e: usize) -> &[f32] {
        self.rows[e].get_or_init(|| {
            let eta = if self.surface == TableSurface::Dielectric { eta_node(e) } else { 1.0 };
            let mut row = vec![0f32; N_ALPHA * N_MU];
            let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).clamp(1, 8);
            let per = N_ALPHA.div_ceil(threads);
            std::thread::scope(|s| {
                for (t, out) in row.chunks_mut(per * N_MU).enumerate() {
                    s.spawn(move || {
                        for (r, alpha_row) in out.chunks_mut(N_MU).enumerate() {
                            let alpha = alpha_node(t * per + r);
                            for (i, v) in alpha_row.iter_mut().enumerate() {
                                *v = ms_fraction_bound(self.surface, self.dist, eta, alpha, mu_node(i)) as f32;
                            }
                        }
                    });
                }
            });
            row
        })
    }

    /// T₁ bound at grid node (IOR e, α a, μ i).
    pub fn node(&self, e: usize, a: usize, i: usize) -> f64 {
        self.row(e)[a * N_MU + i] as f64
    }

    /// The one or two IOR nodes bracketing `eta` (0 for non-dielectrics);
    /// None off the grid.
    fn eta_bracket(&self, eta: f64) -> Option<(usize, usize)> {
        if self.surface != TableSurface::Dielectric {
            return Some((0, 0));
        }
        let nodes = &self.eta_nodes;
        if !(eta >= nodes[0] && eta <= nodes[N_ETA - 1]) {
            return None;
        }
        let above = nodes.partition_point(|&v| v < eta).min(N_ETA - 1); // first node ≥ eta
        if above == 0 || nodes[above] == eta {
            Some((above, above))
        } else {
            Some((above - 1, above))
        }
    }
}

/// Upper bound T₁ + 2 SE of the multiply scattered fraction at one node:
/// 1 − the mean first-vertex exit probability of the correlated model.
fn ms_fraction_bound(surface: TableSurface, dist: Distribution, eta: f64, alpha: f64, mu: f64) -> f64 {
    let mf = Microfacet::new(dist, alpha, alpha);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let l0 = 1.0 + mf.lambda(wi);
    let side = if surface == TableSurface::Diffuse { 64 } else { 32 };
    let mut rng = Sampler::new(hash_words(&[surface as u64, dist as u64, eta.to_bits(), alpha.to_bits(), mu.to_bits()]));
    let leave_up = |d: DVec3, refracted: bool| -> f64 {
        if !(d.z > 0.0) || !d.is_finite() {
            return 0.0; // downward: hits again for sure
        }
        let c = if surface == TableSurface::Dielectric {
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
                    TableSurface::Conductor => leave_up(reflect(wi, m), false),
                    TableSurface::Diffuse => {
                        let (a, b) = rng.next2();
                        leave_up(cosine_about(m, a, b), false)
                    }
                    TableSurface::Dielectric => {
                        let cos_wm = wi.dot(m);
                        let (f, cos_t, _, eta_ti) = dielectric_full(cos_wm, eta);
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

/// The order-1 thresholds of one tolerance: per IOR node and μ cell, the α
/// below which order 1 alone omits at most `tolerance` (module docs).
pub struct OrderOneRule {
    table: &'static MsTable,
    tolerance: f64,
    /// Per IOR node: [mu cell] α threshold (0: never).
    rows: Vec<OnceLock<[f64; N_MU - 1]>>,
}

impl std::fmt::Debug for OrderOneRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "OrderOneRule({:?} {:?}, tolerance {})", self.table.surface, self.table.dist, self.tolerance)
    }
}

impl OrderOneRule {
    pub fn new(surface: TableSurface, dist: Distribution, tolerance: f64) -> Self {
        let table = MsTable::get(surface, dist);
        OrderOneRule { table, tolerance, rows: (0..table.rows.len()).map(|_| OnceLock::new()).collect() }
    }

    fn row(&self, e: usize) -> &[f64; N_MU - 1] {
        self.rows[e].get_or_init(|| {
            std::array::from_fn(|i| {
                // Leading α cells [α_a, α_{a+1}] whose four corners are within tolerance.
                let ok = |a: usize| (a..=a + 1).all(|aa| (i..=i + 1).all(|ii| self.table.node(e, aa, ii) <= self.tolerance));
                let cells = (0..N_ALPHA - 1).take_while(|&a| ok(a)).count();
                if cells == 0 {
                    0.0
                } else {
                    alpha_node(cells)
                }
            })
        })
    }

    /// Whether order 1 alone omits at most the tolerance at (α, μ_i, relative IOR).
    #[inline]
    pub fn order_one_suffices(&self, alpha: f64, mu: f64, eta: f64) -> bool {
        let Some(i) = mu_cell(mu) else { return false };
        let Some((e0, e1)) = self.table.eta_bracket(eta) else { return false };
        alpha <= self.row(e0)[i] && alpha <= self.row(e1)[i]
    }

    /// The bounce cap `auto` runs `correlated` with: 1 or `max_bounces`.
    #[inline]
    pub fn cap(&self, alpha: f64, mu: f64, eta: f64, max_bounces: u32) -> u32 {
        if self.order_one_suffices(alpha, mu, eta) {
            1
        } else {
            max_bounces
        }
    }
}
