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
//! **A conductor's order-1 calls in closed form.** Where a conductor call
//! (ω_i above) is reduced, `eval` is [`order_one_eval`] — the walk's first next
//! event, deterministic, in the same arithmetic, so bit-identical to the capped
//! walk — and `pdf`/`sample` are [`order_one_pdf`]/[`order_one_sample`]: the
//! visible-normal reflection density, which the sampler truly draws from (the
//! walk's first reflection, the same numbers), with the weight eval/pdf =
//! F·L_0/(L_0 + Λ_o) in place of the walk's random exit. That density is the
//! exact one of these calls (the walks' MIS density, `mis.rs`, adds a cosine
//! lobe for orders the call does not have). The Dr.Jit engine computes the same
//! (jit/auto.py) and skips the walk in packets whose lanes all reduce
//! (benches/README.md, "`auto` at single's price").
//!
//! **A dielectric's order-1 calls in closed form**, from either side (the
//! rule at the relative IOR seen from ω_i): `eval` is posfree/dielectric.rs
//! `order_one_eval`, the walk's first next event (reflection on ω_i's side,
//! transmission across; Radiance mode's 1/η_r²), bit-identical to the capped
//! walk; `pdf`/`sample` are `order_one_pdf`/`order_one_sample`: the density
//! the walk's first vertex draws from — the visible normal of ω_i, then
//! reflection with probability F or refraction — v/L_0 (v the vertex term,
//! L_0 = 1 + Λ_i), and the walk's first direction (the same numbers) with the
//! weight eval/pdf = L_0/(L_0 + Λ_o) (reflection) or L_0·B(L_0, 1 + Λ_o)
//! (refraction): the probability of the walk's exit there instead of a random
//! exit (tests/auto.rs: bits, χ², expectation against the capped walk;
//! benches/README.md, "`auto` on glass at single's price"). The diffuse
//! microsurface runs the capped walk.
//!
//! **Estimator.** `table.rs` beside this file: an upper bound (T₁ + 2
//! standard errors, 1024 jittered visible normals; 4096 for the diffuse
//! microsurface) of the multiply scattered fraction T₁ of `correlated` at one
//! exact point: α, μ_i = |cos θ_i| and, for dielectrics, the relative IOR seen
//! from ω_i.
//!
//! **Why F = 1 / albedo 1 bounds every material.** A conductor attenuates
//! order j by a product of j Fresnel factors ≤ 1 and a diffuse microsurface
//! by a^j: weights that decrease with the order move energy to order 1, so the
//! omitted fraction can only shrink (measured in tests/auto.rs for copper and
//! albedo 0.5). Tints scale all orders alike.
//!
//! **Rule.** For a tolerance, at each of 65 μ nodes μ_k (uniform in μ² over
//! 0.02² … 1; for dielectrics at the call's own relative IOR, rounded to f32)
//! the largest α*_k in [0.005, 4] whose bound at exactly (α*_k, μ_k) is within
//! the tolerance: a scan up from 0.005 in factors of 2 to the first point above it,
//! then six bisections in ln α between that point and the last one within. Each of the 64 μ cells [μ_k, μ_k+1] accepts α ≤ min(α*_k, α*_k+1).
//! A call compares max(α_u, α_v) with the threshold of its μ cell. Off the
//! grid (μ < 0.02, IOR ratio beyond 1/3 … 3): the full model. Built per
//! (surface, distribution, tolerance, IOR) once per process, on first use, over
//! the available threads (a glass needs two: η and 1/η), at most 32 per process
//! (beyond them the full model, never wrong); the same thresholds reach the
//! Dr.Jit engine through the C ABI (`msx_auto_rule`).
//!
//! **Why this is a bound, and where T₁ is not monotone (measured:
//! `measure_t1_monotonicity` in tests/auto.rs, a 48 × 48 log grid per surface,
//! distribution and 17 IOR rows).** Away from grazing, T₁ grows with α and
//! falls with μ, so every (α ≤ α*_k, μ ≥ μ_k) is bounded by the bound at
//! (α*_k, μ_k). Near grazing it is not: T₁ peaks in α (α ≈ μ; copper Beckmann
//! at μ = 0.02: 0.087 at α ≈ 0.02, 0.008 at α = 0.73; decreases beyond 3σ
//! only at μ ≤ 0.17 in the Beckmann rows, ≤ 0.07 in the GGX ones, none on the
//! diffuse microsurface) and rises with μ towards that ridge, and at large α T₁ rises with μ
//! everywhere (α = 3.5: 0.05 at grazing, 0.97 at normal incidence). Hence the
//! scan from below (α* is the first crossing, never one beyond a peak) and the
//! smaller α* of a cell's two ends (T₁ may rise with μ inside a cell). Checked
//! independently: `rule_is_a_bound_at_random_points` (asserted) and
//! `measure_every_cell_at_its_threshold` (every cell at its threshold and
//! 0.7 × it, ends and three interior μ, tolerances 1, 5 and 20 %; nine cases —
//! conductor, diffuse, glass 1.5 and 1/1.5 with both distributions, glass
//! 1/1.33 with Beckmann — 17 250 independent estimates, none above the
//! tolerance by more than 2σ).
//!
//! **Why at the exact IOR.** T₁ is not monotone in the IOR either: seen from
//! inside, a feature near the critical angle moves with η. The first version
//! of this rule kept the rule before's scheme for the IOR — rows at 13 nodes
//! (log-uniform over 1/3 … 3), a call taking the stricter of the two around its
//! IOR — and failed the cell check at η = 1/1.33 (water from inside): Beckmann
//! α = 0.137, μ = 0.549, T₁ = 0.019 ± 0.0014 at a 1 % tolerance (16 of 640
//! points beyond 3σ); the rule before, coarser, passed it (none of 986 beyond
//! 3σ). At the exact IOR, none beyond 2σ (also at 1.33, 2.4, 1/2.4, 1/1.1,
//! 1/1.2), and a glass builds two rows (η, 1/η) instead of four.
//!
//! **Less conservative than the rule before** (four corners of cells of a 24 ×
//! 16 node table, each query bounded by the node above in α and below in μ):
//! Beckmann α = 0.1 (Mitsuba's material-preview copper), tolerance 1 %: order 1
//! alone from μ_i ≥ 0.354 (before: 0.517; T₁ itself reaches 1 % at ≈ 0.32);
//! the walk fractions in scenes are in benches/README.md.

pub mod table;

use super::posfree::{dielectric, PosFree, Segments};
use super::{Call, Sampled, ScatteringModel};
use crate::config::{Distribution, Estimator, Surface};
use crate::microfacet::dielectric::eta_seen;
use crate::microfacet::{ConductorFresnel, Microfacet, Microsurface};
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};
use table::{eta_covered, eta_key, ms_fraction_bound, ms_fraction_bound_coarse, mu_cell, LN_ALPHA_MAX, LN_ALPHA_MIN, MU};

/// Cells of the rule: one α threshold per μ cell.
pub const CELLS: usize = MU.n - 1;

/// Scan step in ln α of the search from below (a factor of 2; module docs).
const SCAN_STEP: f64 = std::f64::consts::LN_2;
/// Bisections in ln α after the scan: α* to within a factor 2^(1/64), 1.1 %.
/// Measured on Beckmann α = 0.1, tolerance 1 % (the share of μ_i ∈ [0, 1] where
/// order 1 alone is accepted): 0.646; false position in place of bisection
/// gave 0.604 with four steps and 0.625 with six.
const BISECTIONS: usize = 6;

/// The thresholds of one (surface, distribution, tolerance, relative IOR),
/// built once per process and shared by every rule (tests and scenes build
/// many); kept for the process (a row is 512 bytes).
type Row = [f64; CELLS];
type RowCache = Mutex<HashMap<(u32, u32, u64, u64), &'static OnceLock<Row>>>;

/// At most this many rows per process (each costs 0.03–0.8 s to build): a
/// process asking for more distinct (surface, distribution, tolerance, IOR)
/// — a fuzz test, an IOR per call — gets the full model for the rest, which is
/// never wrong, only slower. A scene needs one row per rough material (two
/// per glass); tests/auto.rs needs 20.
const MAX_ROWS: usize = 32;

fn cached_row(surface: Surface, dist: Distribution, tolerance: f64, eta: f64) -> Option<&'static Row> {
    static CACHE: OnceLock<RowCache> = OnceLock::new();
    let slot: &'static OnceLock<Row> = {
        let mut map = CACHE.get_or_init(Default::default).lock().unwrap_or_else(|p| p.into_inner());
        let key = (surface as u32, dist as u32, tolerance.to_bits(), eta.to_bits());
        match map.get(&key) {
            Some(slot) => slot,
            None if map.len() >= MAX_ROWS => return None,
            None => map.entry(key).or_insert_with(|| Box::leak(Box::new(OnceLock::new()))),
        }
    };
    Some(slot.get_or_init(|| build_row(surface, dist, tolerance, eta)))
}

/// The largest α* in [0.005, 4] whose T₁ bound at (α*, μ) is within the
/// tolerance, with every scan point below it also within (0: not even α =
/// 0.005 is; 4: the whole searched range is): scan up from 0.005 in factors of
/// 2 to the first point above the tolerance, then bisect in ln α between it
/// and the last point within. The scan, a guard against T₁ crossing the tolerance more than
/// once (near grazing T₁ peaks in α; module docs), passes a point on a quarter
/// of the samples ([`ms_fraction_bound_coarse`]) or, where that fails, on the
/// full [`ms_fraction_bound`]; α* itself is a point where the full bound was
/// computed and found within the tolerance.
pub fn largest_alpha(surface: Surface, dist: Distribution, eta: f64, mu: f64, tolerance: f64) -> f64 {
    let full = |ln_alpha: f64| ms_fraction_bound(surface, dist, eta, ln_alpha.exp(), mu);
    // The scan's test: within on the coarse estimate, or else on the full one.
    let scan = |ln_alpha: f64| ms_fraction_bound_coarse(surface, dist, eta, ln_alpha.exp(), mu) <= tolerance || full(ln_alpha) <= tolerance;
    let mut lo = LN_ALPHA_MIN;
    if !scan(lo) {
        return 0.0;
    }
    let mut hi = loop {
        let next = (lo + SCAN_STEP).min(LN_ALPHA_MAX);
        if !scan(next) {
            break Some(next);
        }
        if next >= LN_ALPHA_MAX {
            break None;
        }
        lo = next;
    };
    // lo with the full estimator; where it disagrees with the coarse one, step down.
    while full(lo) > tolerance {
        hi = Some(lo);
        if lo <= LN_ALPHA_MIN {
            return 0.0;
        }
        lo = (lo - SCAN_STEP).max(LN_ALPHA_MIN);
    }
    let Some(mut hi) = hi else { return lo.exp() };
    for _ in 0..BISECTIONS {
        let mid = 0.5 * (lo + hi);
        if full(mid) <= tolerance {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo.exp()
}

/// The thresholds at relative IOR `eta`: α* at every μ node (over the
/// available threads), each cell's threshold the smaller of its two ends'
/// (module docs).
fn build_row(surface: Surface, dist: Distribution, tolerance: f64, eta: f64) -> Row {
    let at_nodes: Vec<f64> = crate::tables::build(MU.n, 1, |i, out: &mut [f64]| out[0] = largest_alpha(surface, dist, eta, MU.node(i), tolerance));
    std::array::from_fn(|i| at_nodes[i].min(at_nodes[i + 1]))
}

/// Dielectric rules remember the rows of this many relative IORs (a scene's
/// glass needs two: η and 1/η) without a lock; further IORs are looked up in
/// the process-wide cache.
const SEEN: usize = 4;

/// The order-1 thresholds of one tolerance: per μ cell (and relative IOR for
/// dielectrics), the α below which order 1 alone omits at most `tolerance`
/// (module docs).
pub struct OrderOneRule {
    surface: Surface,
    dist: Distribution,
    tolerance: f64,
    /// Conductors and diffuse microsurfaces: the one row (None: over MAX_ROWS).
    fixed: OnceLock<Option<&'static Row>>,
    /// Dielectrics: (f32-rounded IOR bits, 0 = free; its row) of the IORs seen.
    seen: [(AtomicU64, OnceLock<&'static Row>); SEEN],
}

impl std::fmt::Debug for OrderOneRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "OrderOneRule({:?} {:?}, tolerance {})", self.surface, self.dist, self.tolerance)
    }
}

impl OrderOneRule {
    pub fn new(surface: Surface, dist: Distribution, tolerance: f64) -> Self {
        OrderOneRule { surface, dist, tolerance, fixed: OnceLock::new(), seen: std::array::from_fn(|_| (AtomicU64::new(0), OnceLock::new())) }
    }

    /// The thresholds at relative IOR `eta` (ignored but for dielectrics);
    /// None where the rule does not cover it (or the process has built
    /// MAX_ROWS rows already).
    fn row(&self, eta: f64) -> Option<&'static Row> {
        if self.surface != Surface::Dielectric {
            return *self.fixed.get_or_init(|| cached_row(self.surface, self.dist, self.tolerance, 1.0));
        }
        if !eta_covered(self.surface, eta) {
            return None;
        }
        let eta = eta_key(eta);
        let bits = eta.to_bits();
        for (key, row) in &self.seen {
            if key.load(Ordering::Acquire) == bits {
                if let Some(r) = row.get() {
                    return Some(r);
                }
            }
        }
        let r = cached_row(self.surface, self.dist, self.tolerance, eta)?;
        // Remember it in a free slot (a slot another thread is filling reads as absent until set).
        if !self.seen.iter().any(|(key, _)| key.load(Ordering::Acquire) == bits) {
            for (key, row) in &self.seen {
                if key.compare_exchange(0, bits, Ordering::AcqRel, Ordering::Acquire).is_ok() {
                    let _ = row.set(r);
                    break;
                }
            }
        }
        Some(r)
    }

    /// Whether order 1 alone omits at most the tolerance at (α, μ_i, relative IOR).
    #[inline]
    pub fn order_one_suffices(&self, alpha: f64, mu: f64, eta: f64) -> bool {
        let Some(i) = mu_cell(mu) else { return false };
        let Some(row) = self.row(eta) else { return false };
        alpha <= row[i]
    }

    /// The α thresholds of every μ cell at a relative IOR, 0 where order 1
    /// never suffices (IOR outside 1/3 … 3): what [`Self::order_one_suffices`]
    /// compares α with, for the C ABI (`msx_auto_rule`, read by the Dr.Jit
    /// engine).
    pub fn thresholds(&self, eta: f64) -> [f64; CELLS] {
        self.row(eta).copied().unwrap_or([0.0; CELLS])
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

/// A call reduced to order 1 that takes the closed form (`order_one_*` below and
/// posfree/dielectric.rs `order_one_*`).
enum OrderOne {
    Conductor(ConductorFresnel),
    Dielectric { eta: f64, radiance: bool },
}

impl Auto {
    /// Whether this call is reduced to order 1 and takes the closed form: its counted orders include
    /// order 1 and the rule says order 1 suffices — on a conductor with ω_i above, on a dielectric from
    /// either side (at the relative IOR seen from ω_i, as `capped`). Elsewhere (diffuse microsurfaces
    /// included) the capped walk runs.
    fn closed_order_one(&self, call: &Call, wi: DVec3) -> Option<OrderOne> {
        if !(call.orders.0 <= 1 && call.orders.1 >= 1) {
            return None;
        }
        let alpha = call.mf.alpha_u.max(call.mf.alpha_v);
        match call.surf {
            Microsurface::Conductor(fresnel) if wi.z > 0.0 && self.rule.order_one_suffices(alpha, wi.z, 1.0) => Some(OrderOne::Conductor(fresnel)),
            Microsurface::Dielectric { eta, radiance } if self.rule.order_one_suffices(alpha, wi.z.abs(), eta_seen(eta, wi.z > 0.0)) => {
                Some(OrderOne::Dielectric { eta, radiance })
            }
            _ => None,
        }
    }
}

/// Order 1 of `correlated` in closed form (Walter 2007 with the height-correlated G2): f·cos θ_o =
/// F(ω_i·h)·D(h)/(4 cos θ_i (L_0 + Λ_o)), L_0 = 1 + Λ(ω_i) — the walk's next event at its first vertex,
/// which is deterministic (posfree/conductor.rs `nee_term` with the last factor 1/(L_0 + Λ_o)).
pub fn order_one_eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    let h = wi + wo;
    let len = h.length();
    if len <= 0.0 {
        return Spectrum::ZERO;
    }
    let h = h / len;
    let cos_wh = wi.dot(h);
    if cos_wh <= 0.0 || wo.dot(h) <= 0.0 {
        return Spectrum::ZERO;
    }
    let last = 1.0 / (mf.abs_lambda(-wi) + mf.lambda(wo));
    fresnel.eval(cos_wh) * (mf.d(h) * last / (4.0 * wi.z))
}

/// The density of [`order_one_sample`]: the visible-normal reflection density D_ωi(h)/(4 ω_i·h) for ω_o
/// above, 0 below (where the sampler returns nothing).
pub fn order_one_pdf(mf: &Microfacet, wi: DVec3, wo: DVec3) -> f64 {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return 0.0;
    }
    mf.reflect_pdf(wi, wo)
}

/// ω_o by reflecting ω_i about a visible normal drawn with (u1, u2) (the walk's first vertex, the same
/// numbers), weighted by f·cos θ_o / pdf = F(ω_i·m)·L_0/(L_0 + Λ_o): the expectation of the walk's
/// exit at its first vertex, without its random exit (sample1 is not used).
pub fn order_one_sample(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, u1: f64, u2: f64) -> Option<Sampled> {
    if wi.z <= 0.0 {
        return None;
    }
    let (_, cos_wm, wo) = mf.reflect_visible(wi, u1, u2)?;
    if wo.z <= 0.0 {
        return None;
    }
    let pdf = order_one_pdf(mf, wi, wo);
    if !(pdf > 0.0 && pdf.is_finite()) {
        return None;
    }
    let l0 = mf.abs_lambda(-wi);
    let weight = fresnel.eval(cos_wm) * (l0 / (l0 + mf.lambda(wo)));
    Some(Sampled { wo, weight, order: 1, pdf: Some(pdf) })
}

impl ScatteringModel for Auto {
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum {
        match self.closed_order_one(call, wi) {
            Some(OrderOne::Conductor(fresnel)) => order_one_eval(&call.mf, &fresnel, wi, wo),
            Some(OrderOne::Dielectric { eta, radiance }) => {
                Spectrum::splat(dielectric::order_one_eval(&call.mf, Segments::Correlated, eta, radiance, wi, wo))
            }
            None => self.full.eval(&self.capped(call, wi), wi, wo),
        }
    }

    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64 {
        match self.closed_order_one(call, wi) {
            Some(OrderOne::Conductor(_)) => order_one_pdf(&call.mf, wi, wo),
            Some(OrderOne::Dielectric { eta, .. }) => dielectric::order_one_pdf(&call.mf, eta, wi, wo),
            None => self.full.pdf(call, wi, wo),
        }
    }

    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled> {
        match self.closed_order_one(call, wi) {
            Some(OrderOne::Conductor(fresnel)) => order_one_sample(&call.mf, &fresnel, wi, first.1, first.2),
            Some(OrderOne::Dielectric { eta, radiance }) => {
                let (wo, weight, pdf) = dielectric::order_one_sample(&call.mf, Segments::Correlated, eta, radiance, wi, first)?;
                Some(Sampled { wo, weight: Spectrum::splat(weight), order: 1, pdf: Some(pdf) })
            }
            None => self.full.sample(&self.capped(call, wi), wi, first),
        }
    }
}
