//! The bidirectional estimator of a BSDF defined by a position-free path
//! integral (Wang et al. 2022 §4.2, eqs. 27–29), written once for every
//! surface and segment model: a surface supplies its vertex terms through
//! [`BdptSurface`], this module supplies the subpaths, the strategies, the
//! balance heuristic and the hand-over to path tracing.
//!
//! # Paths and strategies
//! A path of order k is d_0 = −ω_i, d_1, …, d_k = ω_o; the integration
//! variables are the k − 1 inner directions (solid angle each, eq. 4). The
//! camera subpath starts from d_0 and samples d_1, d_2, … forward; the light
//! subpath starts from e_0 = d_k = ω_o and samples e_1 = d_{k−1}, e_2, …
//! backward (the reversed ray scatters with the same sampler). Strategy
//! s ∈ {0, …, k−1} of order k takes d_1..d_s from the camera and
//! d_{s+1}..d_{k−1} (t = k−1−s directions) from the light and evaluates the
//! connecting vertex s deterministically; its density is
//!
//!   p_s = Π_{j=0}^{s−1} pf_j · Π_{j=s+1}^{k−1} pr_j        (eq. 27)
//!
//! with pf_j the density of the camera step at vertex j (d_{j+1} given d_j)
//! and pr_j that of the light step (d_j given d_{j+1}). s = k−1 is path
//! tracing with next-event estimation towards ω_o (eq. 25), s = 0 light
//! tracing connected to ω_i. The contribution of every strategy is the
//! *forward* (ω_i → ω_o) path contribution: a model need not be reciprocal.
//!
//! # Balance heuristic (eq. 28)
//! w_s = p_s / Σ_{s'} p_{s'}, from the ratios p_{s−1}/p_s = pr_s/pf_{s−1} and
//! p_{s+1}/p_s = pf_s/pr_{s+1}:
//!
//!   Σ_{s'<s} p_{s'}/p_s = a_s(1 + a_{s−1}(1 + … (1 + a_1))),   a_u = pr_u/pf_{u−1},
//!   Σ_{s'>s} p_{s'}/p_s = b_s(1 + b_{s+1}(1 + … (1 + b_{k−2}))), b_u = pf_u/pr_{u+1},
//!
//! whose inner parts are accumulated along each subpath ([`Mis`]: a_u
//! with u < s only involves camera directions, b_u with u > s only light
//! directions); a_s and b_s involve the connection and come from
//! [`BdptSurface::connect`]. A surface may report surrogate densities (any
//! positive function of the path's directions): the weights then still sum to
//! one over the strategies and the estimate stays unbiased.
//!
//! # Lengths, roulette and unbiasedness
//! The balance heuristic above is exact only if every strategy's density is
//! p_s as written, so the subpaths used for orders 1..=K_b are sampled with
//! fixed length (K_b − 1 directions each) and **no** Russian roulette;
//! K_b = min(orders.1, max_bounces, bdpt_orders). All k strategies of every
//! order k ≤ K_b are then always available. Orders K_b < k ≤ min(orders.1,
//! max_bounces) are estimated by continuing the camera subpath with the
//! surface's path tracer ([`BdptSurface::pt_tail`]: one strategy, weight 1,
//! roulette allowed): the sum of an unbiased BDPT estimate of the low orders
//! and an unbiased PT estimate of the high orders is unbiased. Subpaths stop
//! early only on measure-zero events (a direction that sees no microfacet,
//! Λ = 0 exactly).

use crate::rng::Sampler;
use std::ops::AddAssign;

/// Default number of orders handled bidirectionally (higher orders: PT).
/// Each subpath costs K_b − 1 visible-normal samples (no roulette) and there
/// are K_b(K_b+1)/2 connections. Measured (release, copper, all orders, three
/// direction pairs, α ∈ {0.5, 1, 2}): the variance per call falls 2–26× vs PT
/// and stops improving beyond K_b ≈ 4 for α ≤ 1; (variance × time) is best at
/// K_b = 3 for GGX and K_b = 2 for Beckmann (whose VNDF sampler is a Newton
/// solve, ≈ 3–5× dearer than GGX's).
pub const DEFAULT_BDPT_ORDERS: u32 = 3;
/// Largest K_b (stack arrays).
pub const MAX_BDPT_ORDERS: u32 = 32;

/// One sampled step of a subpath: the new vertex, the density with which the
/// step sampled it (`p_in`) and the density of the same step sampled from the
/// other subpath (`p_rev`: pr for a camera step, pf for a light step). A
/// surface computes `p_rev` only where it is used (camera steps from vertex
/// s ≥ 1, light steps from vertex t ≥ 1) and may return 0 elsewhere.
pub struct Step<V> {
    pub vertex: V,
    pub p_in: f64,
    pub p_rev: f64,
}

/// A connection of camera vertex s with light vertex t, before its MIS
/// weight: `pr` = pr_s (density of the connecting direction sampled from the
/// light side, used when s ≥ 1), `pf` = pf_s (sampled from the camera side,
/// used when t ≥ 1), and what [`BdptSurface::weighted`] needs.
pub struct Connection<C> {
    pub pr: f64,
    pub pf: f64,
    pub data: C,
}

/// The vertex terms of one surface and segment model.
pub trait BdptSurface {
    /// A camera vertex: d_s and the prefix throughput f/p.
    type Cam: Clone + Default;
    /// A light vertex: e_t = d_{k−t} and the suffix weight.
    type Light: Clone + Default;
    /// What a connection hands to `weighted`.
    type Conn;
    /// Per-channel value (`Spectrum`) or one value for every channel (`f64`).
    type Value: Copy + AddAssign + Default;

    /// The camera vertex of d_0 = −ω_i.
    fn camera_start(&self) -> Self::Cam;
    /// Whether a subpath can go on from (or connect at) this camera vertex.
    fn camera_ready(&self, v: &Self::Cam) -> bool;
    /// Samples d_{s+1} from camera vertex s (which may record what it drew).
    fn camera_step(&self, v: &mut Self::Cam, s: usize, rng: &mut Sampler) -> Option<Step<Self::Cam>>;
    /// Prepares the last camera vertex used only by connections.
    fn camera_last(&self, _v: &mut Self::Cam, _rng: &mut Sampler) {}

    /// The light vertex of e_0 = ω_o.
    fn light_start(&self) -> Self::Light;
    /// Whether the light subpath can go on from this vertex.
    fn light_ready(&self, v: &Self::Light) -> bool;
    /// Samples e_{t+1} from light vertex t.
    fn light_step(&self, v: &Self::Light, t: usize, rng: &mut Sampler) -> Option<Step<Self::Light>>;

    /// The connection of camera vertex s with light vertex t (order s+t+1),
    /// None when it carries nothing. `cam` = vertices 0..=s of the camera
    /// subpath, `light` = vertices 0..=t of the light subpath (a surface whose
    /// segment term depends on whole paths reads them all; the others the last).
    fn connect(&self, cam: &[Self::Cam], light: &[Self::Light]) -> Option<Connection<Self::Conn>>;
    /// The weighted contribution of a connection, `denom` = Σ_{s'} p_{s'}/p_s;
    /// None when it is not finite.
    fn weighted(&self, conn: &Connection<Self::Conn>, cam: &Self::Cam, light: &Self::Light, denom: f64) -> Option<Self::Value>;

    /// Orders above K_b by path tracing from the end of the camera subpath
    /// `cam` (vertices 0..=K_b; order K_b + 1 next), orders `orders`.
    fn pt_tail(&self, cam: &[Self::Cam], kb: u32, orders: (u32, u32), rng: &mut Sampler) -> Self::Value;
}

/// What the balance heuristic keeps of a subpath vertex: the density with
/// which the subpath sampled it (pf_{s−1}, or pr of e_t) and the accumulated
/// ratio chain (camera: B_{s−1} = a_{s−1}(1 + a_{s−2}(1 + …)); light: E_{t−1}
/// likewise with b; 0 for s, t ≤ 1).
#[derive(Clone, Copy, Default)]
struct Mis {
    p_in: f64,
    chain: f64,
}

impl Mis {
    /// The ratio chain extended by one step: `p_rev / p_in · (1 + chain)`
    /// (a_s(1 + B_{s−1}) for the camera, b likewise).
    #[inline]
    fn extend(&self, p_rev: f64) -> f64 {
        p_rev / self.p_in * (1.0 + self.chain)
    }
}

/// The BDPT estimate of f(ω_i, ω_o)·|cos θ_o| over the orders
/// `orders` = (lo, hi) (1 ≤ lo ≤ hi, hi within the bounce cap): orders up to
/// `bdpt_orders` (clamped to 1..=[`MAX_BDPT_ORDERS`]) bidirectionally, the
/// rest by the surface's path tracer.
pub fn estimate<S: BdptSurface>(surface: &S, orders: (u32, u32), bdpt_orders: u32, rng: &mut Sampler) -> S::Value {
    // The subpaths live on the stack, sized for the orders at hand: filling 33
    // vertices per call, as K_b ≤ 32 would need, cost more than the rest of
    // the default K_b = 3 estimate.
    let kb = orders.1.min(bdpt_orders.clamp(1, MAX_BDPT_ORDERS));
    if kb <= 4 {
        estimate_on::<S, 5>(surface, orders, kb, rng)
    } else if kb <= 8 {
        estimate_on::<S, 9>(surface, orders, kb, rng)
    } else {
        estimate_on::<S, { MAX_BDPT_ORDERS as usize + 1 }>(surface, orders, kb, rng)
    }
}

/// `estimate` with subpaths of at most N vertices (K_b < N).
fn estimate_on<S: BdptSurface, const N: usize>(surface: &S, orders: (u32, u32), kb: u32, rng: &mut Sampler) -> S::Value {
    let (o_lo, o_hi) = orders;
    let mut result = S::Value::default();
    if o_lo > o_hi {
        return result;
    }
    let pt_tail = o_hi > kb; // orders ≤ kb: bidirectional

    // ---- camera subpath d_0..d_{n_c} (n_c = kb − 1, or kb if the PT tail needs d_kb)
    let n_c_target = if pt_tail { kb } else { kb - 1 } as usize;
    let mut cam: [S::Cam; N] = std::array::from_fn(|_| S::Cam::default());
    let mut cam_mis = [Mis::default(); N];
    cam[0] = surface.camera_start();
    let mut n_c = 0usize;
    loop {
        let s = n_c;
        if !surface.camera_ready(&cam[s]) {
            break;
        }
        if s == n_c_target {
            if !pt_tail {
                surface.camera_last(&mut cam[s], rng);
            }
            break;
        }
        let Some(step) = surface.camera_step(&mut cam[s], s, rng) else { break };
        let chain = if s >= 1 { cam_mis[s].extend(step.p_rev) } else { 0.0 };
        cam[s + 1] = step.vertex;
        cam_mis[s + 1] = Mis { p_in: step.p_in, chain };
        n_c += 1;
    }

    if o_lo <= kb {
        // ---- light subpath e_0 = ω_o, e_1 = d_{k−1}, … (n_l = kb − 1 sampled)
        let mut lig: [S::Light; N] = std::array::from_fn(|_| S::Light::default());
        let mut lig_mis = [Mis::default(); N];
        lig[0] = surface.light_start();
        let mut n_l = 0usize;
        while n_l + 1 < kb as usize {
            let t = n_l;
            if !surface.light_ready(&lig[t]) {
                break;
            }
            let Some(step) = surface.light_step(&lig[t], t, rng) else { break };
            let chain = if t >= 1 { lig_mis[t].extend(step.p_rev) } else { 0.0 };
            lig[t + 1] = step.vertex;
            lig_mis[t + 1] = Mis { p_in: step.p_in, chain };
            n_l += 1;
        }

        // ---- connections: order k, strategy s, t = k − 1 − s
        for k in o_lo as usize..=kb as usize {
            for s in 0..k {
                let t = k - 1 - s;
                if s > n_c || t > n_l {
                    continue;
                }
                let Some(conn) = surface.connect(&cam[..=s], &lig[..=t]) else { continue };
                let mut denom = 1.0;
                if s >= 1 {
                    denom += cam_mis[s].extend(conn.pr);
                }
                if t >= 1 {
                    denom += lig_mis[t].extend(conn.pf);
                }
                if let Some(v) = surface.weighted(&conn, &cam[s], &lig[t], denom) {
                    result += v;
                }
            }
        }
    }

    // ---- orders kb+1 ..= o_hi: the camera subpath continues as PT with NEE.
    if pt_tail && n_c == kb as usize {
        result += surface.pt_tail(&cam[..=kb as usize], kb, (o_lo, o_hi), rng);
    }
    result
}
