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
//! **Table.** `table.rs` beside this file: per surface and
//! distribution, an upper bound of the multiply scattered fraction T₁ of
//! `correlated` over α (0.005 … 4), μ_i = |cos θ_i| (0.02 … 1) and, for
//! dielectrics, the relative IOR seen from ω_i (1/3 … 3).
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

pub mod table;

use super::posfree::{PosFree, Segments};
use super::{Call, Sampled, ScatteringModel};
use crate::config::{Distribution, Estimator, Surface};
use crate::microfacet::Microsurface;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::sync::OnceLock;
use table::{mu_cell, MsTable, ALPHA, MU};

/// The order-1 thresholds of one tolerance: per IOR node and μ cell, the α
/// below which order 1 alone omits at most `tolerance` (module docs).
pub struct OrderOneRule {
    table: &'static MsTable,
    tolerance: f64,
    /// Per IOR node: [mu cell] α threshold (0: never).
    rows: Vec<OnceLock<[f64; MU.n - 1]>>,
}

impl std::fmt::Debug for OrderOneRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "OrderOneRule({:?} {:?}, tolerance {})", self.table.surface, self.table.dist, self.tolerance)
    }
}

impl OrderOneRule {
    pub fn new(surface: Surface, dist: Distribution, tolerance: f64) -> Self {
        let table = MsTable::get(surface, dist);
        OrderOneRule { table, tolerance, rows: (0..table.eta_rows()).map(|_| OnceLock::new()).collect() }
    }

    fn row(&self, e: usize) -> &[f64; MU.n - 1] {
        self.rows[e].get_or_init(|| {
            std::array::from_fn(|i| {
                // Leading α cells [α_a, α_{a+1}] whose four corners are within tolerance.
                let ok = |a: usize| (a..=a + 1).all(|aa| (i..=i + 1).all(|ii| self.table.node(e, aa, ii) <= self.tolerance));
                let cells = (0..ALPHA.n - 1).take_while(|&a| ok(a)).count();
                if cells == 0 {
                    0.0
                } else {
                    ALPHA.node(cells)
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

    /// The α thresholds of every μ cell at a relative IOR (the smaller of the
    /// two bracketing IOR rows), 0 where order 1 never suffices (IOR off the
    /// grid): what [`Self::order_one_suffices`] compares α with, for the C ABI
    /// (`msx_auto_rule`, read by the Dr.Jit engine).
    pub fn thresholds(&self, eta: f64) -> [f64; MU.n - 1] {
        match self.table.eta_bracket(eta) {
            Some((e0, e1)) => std::array::from_fn(|i| self.row(e0)[i].min(self.row(e1)[i])),
            None => [0.0; MU.n - 1],
        }
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

/// `model="auto"`: the position-free `correlated` model (with the configured
/// estimator) whose bounce cap is 1 wherever [`OrderOneRule`] finds order 1
/// alone within the tolerance for the call's roughness, incidence and IOR.
#[derive(Debug)]
pub struct Auto {
    rule: OrderOneRule,
    full: PosFree,
}

impl Auto {
    pub fn new(surface: Surface, dist: Distribution, tolerance: f64, estimator: Estimator) -> Self {
        Auto { rule: OrderOneRule::new(surface, dist, tolerance), full: PosFree { segments: Segments::Correlated, estimator } }
    }

    /// The call with this call's bounce cap: 1 where order 1 suffices.
    fn capped(&self, call: &Call, wi: DVec3) -> Call {
        let eta = match call.surf {
            // Below the macro surface the tables (built for ω_i above) do not apply: the full model.
            Microsurface::Conductor(_) if wi.z < 0.0 => return *call,
            Microsurface::Dielectric { eta, .. } if wi.z > 0.0 => eta,
            Microsurface::Dielectric { eta, .. } => 1.0 / eta,
            _ => 1.0,
        };
        let cap = self.rule.cap(call.mf.alpha_u.max(call.mf.alpha_v), wi.z.abs(), eta, call.max_bounces);
        Call { max_bounces: cap, orders: (call.orders.0, call.orders.1.min(cap)), ..*call }
    }
}

impl ScatteringModel for Auto {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        self.full.eval(&self.capped(call, wi), wi, wo)
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        self.full.pdf(call, wi, wo)
    }

    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled> {
        self.full.sample(&self.capped(call, wi), wi, first)
    }
}
