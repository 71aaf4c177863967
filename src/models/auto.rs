//! `model="auto"` (DESIGN §6): model no more than a scene needs.
//!
//! The converged model is the height-correlated position-free model
//! (`correlated`, all orders). Its scattering orders carry less and less
//! energy, and for smooth surfaces almost all of it is in order 1, which is
//! analytic (Walter 2007 with G2: deterministic, as cheap as `single`). `auto`
//! evaluates `correlated` truncated after the fewest bounces k whose omitted
//! energy — the orders above k — is at most `tolerance` of the energy the
//! surface scatters, per call (α can be textured, θ_i varies), read from
//! per-order energy tables this module computes on first use.
//!
//! **Tables.** For each surface (conductor, dielectric, diffuse) and
//! distribution, over α (log grid 0.005 … 4), μ_i = |cos θ_i| (0.02 … 1) and, for
//! dielectrics, the relative IOR seen from ω_i (1/3 … 3): the tail
//! T_k = P(order > k) of the correlated random-walk sampler (`sample_walk` of
//! `posfree*.rs`: its weights are 1 with F = 1, a lossless interface or albedo 1,
//! so T_k is the fraction of the energy in orders above k), from N walks with a
//! jittered-stratified first vertex and a fixed seed, stored as the upper end
//! of the two-sided Wilson score interval (z = 2; ≈ T_k + 2√(T_k(1−T_k)/N),
//! and ≈ 4/N instead of 0 when no walk went above k). Dielectric tables are
//! built one IOR row at a time, on first use of that row.
//!
//! **Why F = 1 / albedo 1 bounds every material.** A conductor attenuates
//! order j by a product of j Fresnel factors ≤ 1 and a diffuse microsurface
//! by a^j: weights that decrease with the order move energy to the low orders,
//! so the omitted fraction Σ_{j>k}E_j/Σ_j E_j can only shrink (measured in
//! tests/auto.rs for copper and albedo 0.5). Tints (specular_reflectance,
//! transmittance) scale all orders alike.
//!
//! **Lookup.** Conservative: T_k is the largest value over the grid cells
//! around the query (2 per dimension; T grows with α and towards grazing
//! incidence, so the corner maxima bound the values between nodes). Anisotropy
//! uses max(α_u, α_v). Outside the grid (α > 4, μ < 0.02, IOR ratio beyond
//! 1/3 … 3) and when no k ≤ 24 is enough, the full model runs. α below the
//! grid uses the smallest α (less roughness, less multiple scattering).

use super::posfree::Segments;
use super::{posfree, posfree_dielectric, posfree_diffuse, ConductorFresnel, WalkOptions};
use crate::microfacet::{Distribution, Microfacet};
use crate::rng::{hash_words, Sampler};
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::sync::OnceLock;

/// Tail values stored per cell: T_1 … T_K.
pub const K_TABLE: usize = 24;
/// Default tolerance: 1 % of the scattered energy may be omitted.
pub const DEFAULT_TOLERANCE: f64 = 0.01;

const N_ALPHA: usize = 24;
const ALPHA_MIN: f64 = 0.005;
const ALPHA_MAX: f64 = 4.0;
const N_MU: usize = 16;
const MU_MIN: f64 = 0.02;
const N_ETA: usize = 13;
const LN_ETA_MAX: f64 = 1.098_612_288_668_109_8; // ln 3
/// Walks per cell.
const WALKS: usize = 2048;
const WALKS_DIELECTRIC: usize = 1024;

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

/// The two grid indices bracketing x (given the node coordinate x_c of x in
/// [0, n−1]); None outside the grid.
fn bracket(xc: f64, n: usize) -> Option<(usize, usize)> {
    if !(xc >= -1e-9) || !(xc <= (n - 1) as f64 + 1e-9) {
        return None;
    }
    let lo = (xc.floor().max(0.0) as usize).min(n - 1);
    let hi = (xc.ceil().max(0.0) as usize).min(n - 1);
    Some((lo, hi))
}

/// Per-order energy tails of the correlated model for one surface and
/// distribution (module docs). Dielectric tables are built one IOR row at a
/// time, when a query first needs it (a scene uses one or two IORs).
pub struct OrderTable {
    surface: TableSurface,
    dist: Distribution,
    /// Per IOR node: [alpha][mu][k−1], T_k with its margin.
    rows: Vec<OnceLock<Vec<f32>>>,
}

impl OrderTable {
    /// The table of a surface and distribution (rows computed on first use).
    pub fn get(surface: TableSurface, dist: Distribution) -> &'static OrderTable {
        static TABLES: [OnceLock<OrderTable>; 6] = [const { OnceLock::new() }; 6];
        let i = 2 * surface as usize + (dist == Distribution::Ggx) as usize;
        TABLES[i].get_or_init(|| {
            let n_eta = if surface == TableSurface::Dielectric { N_ETA } else { 1 };
            OrderTable { surface, dist, rows: (0..n_eta).map(|_| OnceLock::new()).collect() }
        })
    }

    /// Row `e` of the table, computed on first use over the available threads.
    fn row(&self, e: usize) -> &[f32] {
        self.rows[e].get_or_init(|| {
            let eta = if self.surface == TableSurface::Dielectric { eta_node(e) } else { 1.0 };
            let mut row = vec![0f32; N_ALPHA * N_MU * K_TABLE];
            let threads = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1).clamp(1, 8);
            let per = N_ALPHA.div_ceil(threads);
            std::thread::scope(|s| {
                for (t, out) in row.chunks_mut(per * N_MU * K_TABLE).enumerate() {
                    s.spawn(move || {
                        for (r, cell_row) in out.chunks_mut(N_MU * K_TABLE).enumerate() {
                            let alpha = alpha_node(t * per + r);
                            for (i, cell) in cell_row.chunks_mut(K_TABLE).enumerate() {
                                cell.copy_from_slice(&cell_tails(self.surface, self.dist, eta, alpha, mu_node(i)));
                            }
                        }
                    });
                }
            });
            row
        })
    }

    /// Conservative T_k (energy fraction above order k, plus margin) at
    /// (α, μ, relative IOR); None outside the grid.
    pub fn tail(&self, alpha: f64, mu: f64, eta: f64, k: usize) -> Option<f64> {
        let cells = self.cells(alpha, mu, eta)?;
        Some(self.tail_in(&cells, k))
    }

    fn tail_in(&self, cells: &Cells, k: usize) -> f64 {
        if k == 0 || k > K_TABLE {
            return 1.0;
        }
        let mut t = 0f32;
        for &e in &[cells.e.0, cells.e.1] {
            let row = self.row(e);
            for &a in &[cells.a.0, cells.a.1] {
                for &i in &[cells.i.0, cells.i.1] {
                    t = t.max(row[(a * N_MU + i) * K_TABLE + k - 1]);
                }
            }
        }
        t as f64
    }

    fn cells(&self, alpha: f64, mu: f64, eta: f64) -> Option<Cells> {
        if !(alpha > 0.0) || !(mu > 0.0) {
            return None;
        }
        let ac = ((alpha.max(ALPHA_MIN) / ALPHA_MIN).ln() / (ALPHA_MAX / ALPHA_MIN).ln() * (N_ALPHA - 1) as f64).max(0.0);
        let a = bracket(ac, N_ALPHA)?;
        let t = mu.min(1.0).powi(2);
        let ic = (t - MU_MIN * MU_MIN) / (1.0 - MU_MIN * MU_MIN) * (N_MU - 1) as f64;
        let i = bracket(ic, N_MU)?;
        let e = if self.surface == TableSurface::Dielectric {
            if !(eta > 0.0) {
                return None;
            }
            let ec = (eta.ln() / LN_ETA_MAX + 1.0) * 0.5 * (N_ETA - 1) as f64;
            bracket(ec, N_ETA)?
        } else {
            (0, 0)
        };
        Some(Cells { e, a, i })
    }

    /// The fewest bounces k ≤ K_TABLE whose omitted energy is at most
    /// `tolerance`; None when the query is off the grid or no k suffices.
    pub fn bounces_needed(&self, alpha: f64, mu: f64, eta: f64, tolerance: f64) -> Option<u32> {
        let cells = self.cells(alpha, mu, eta)?;
        (1..=K_TABLE).find(|&k| self.tail_in(&cells, k) <= tolerance).map(|k| k as u32)
    }
}

struct Cells {
    e: (usize, usize),
    a: (usize, usize),
    i: (usize, usize),
}

/// T_k + 2 SE for k = 1 … K_TABLE at one grid node, from the correlated
/// sampler's exit orders (weights 1) with a jittered-stratified first vertex.
fn cell_tails(surface: TableSurface, dist: Distribution, eta: f64, alpha: f64, mu: f64) -> [f32; K_TABLE] {
    let mf = Microfacet::new(dist, alpha, alpha);
    let wi = DVec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let opts = WalkOptions { segments: Segments::Correlated, max_bounces: K_TABLE as u32 + 1, orders: (1, K_TABLE as u32 + 1) };
    let n = if surface == TableSurface::Dielectric { WALKS_DIELECTRIC } else { WALKS };
    let side = (n as f64).sqrt().round() as usize;
    let mut rng = Sampler::new(hash_words(&[surface as u64, dist as u64, eta.to_bits(), alpha.to_bits(), mu.to_bits()]));
    let mirror = ConductorFresnel::new(Spectrum::ZERO, Spectrum::ONE, 1);
    // above[k] = number of walks that did not leave within k bounces.
    let mut above = [0usize; K_TABLE + 1];
    for s in 0..n {
        let (gx, gy) = (s % side, (s / side) % side);
        let u1 = (gx as f64 + rng.next()) / side as f64;
        let u2 = (gy as f64 + rng.next()) / side as f64;
        let first = (rng.next(), u1.min(1.0 - f64::EPSILON), u2.min(1.0 - f64::EPSILON));
        let order = match surface {
            TableSurface::Conductor => posfree::sample_walk(&mf, &mirror, wi, first, &opts, &mut rng).map(|r| r.2),
            TableSurface::Dielectric => posfree_dielectric::sample_walk(&mf, eta, false, wi, first, &opts, &mut rng).map(|r| r.2),
            TableSurface::Diffuse => posfree_diffuse::sample_walk(&mf, Spectrum::ONE, wi, first, &opts, &mut rng).map(|r| r.2),
        };
        let order = order.map(|o| o as usize).unwrap_or(K_TABLE + 1);
        for a in above.iter_mut().take(order.min(K_TABLE + 1)).skip(1) {
            *a += 1;
        }
    }
    let mut out = [0f32; K_TABLE];
    for k in 1..=K_TABLE {
        out[k - 1] = wilson_upper(above[k] as f64 / n as f64, n as f64) as f32;
    }
    out
}

/// Upper end of the Wilson score interval (z = 2) of a proportion t from n
/// trials: ≈ t + 2 SE, and 4/n rather than 0 when no trial was above.
fn wilson_upper(t: f64, n: f64) -> f64 {
    const Z2: f64 = 4.0;
    let centre = t + Z2 / (2.0 * n);
    let spread = (Z2 * (t * (1.0 - t) / n + Z2 / (4.0 * n * n))).sqrt();
    ((centre + spread) / (1.0 + Z2 / n)).min(1.0)
}

/// Bounce cap for `auto`: the fewest bounces whose omitted energy stays under
/// `tolerance` at (α, μ_i, relative IOR), at most `max_bounces`; `max_bounces`
/// (the full model) off the tables.
pub fn bounce_cap(surface: TableSurface, dist: Distribution, alpha: f64, mu: f64, eta: f64, tolerance: f64, max_bounces: u32) -> u32 {
    OrderTable::get(surface, dist)
        .bounces_needed(alpha, mu, eta, tolerance)
        .map_or(max_bounces, |k| k.min(max_bounces))
}
