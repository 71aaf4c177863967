//! The invariance-principle model (Cui et al. 2023) beyond conductors: the
//! *diffuse* microsurface (Lambertian facets, Heitz 2016 §3.3), whose paths are
//! not monotone in z (after a Lambertian bounce a direction can go up and the
//! next one down again), so the complete S_k recursion of docs/paper-notes.md is needed.
//!
//! **Path contribution.** As in `recursion.rs`: a path d_0 = −ω_i, d_1, …,
//! d_k = ω_o contributes (Π_{j<k} v_j)·S_k(d_0..d_k) to f·cos θ_o, with
//! v_j = L_j·p(−d_j → d_{j+1}) (L_j = |Λ(d_j)|, p Heitz's diffuse phase function,
//! see `src/models/posfree/diffuse.rs`). With p_exit(d_0..d_k) = (Π_{j<k} L_j)·S_k (Cui
//! eq. 7) this is Π_j p(−d_j → d_{j+1}) · p_exit(d_0..d_k): Heitz's random walk
//! with the heights integrated out exactly.
//!
//! **Complete recursion, scaled.** With p(i,j) = (Π_{l=i}^{j−1} L_l)·S(d_i..d_j),
//!
//! p(i,j) = S_1(d_i,d_j)·Σ_{l=i}^{j−1} L_l·p(i,l)·p(l+1,j),   p(i,i) = 1,
//!
//! S_1(a,b) = 1/(|Λ(a)| + Λ(b)) for a down and b up, 0 otherwise. [`ExitTable`]
//! stores the triangle p(i,j) of the directions pushed so far; a new direction
//! adds one column in O(m²) (every j-term of the sum is kept: no monotonicity
//! is assumed), and p_exit(d_0..d_m, x) for a virtual upward x is one more
//! column, not stored. H_m = p_exit(d_0..d_m, ẑ) (Λ(ẑ) = 0) is the probability
//! that d_0..d_m all hit the microsurface.
//!
//! **Estimators.** `eval`: d_{j+1} is drawn from the diffuse phase function
//! (visible normal m of −d_j, cosine lobe about m: density p/a); at each vertex
//! the NEE towards ω_o uses the unbiased phase estimate (a/π)⟨ω_o, m⟩⁺ with the
//! same m and the exact conditional exit probability p_exit(d_0..d_m, ω_o)/H_m
//! (≤ 1: the NEE is bounded by a/π times the throughput). The throughput
//! carries Π a · H_{m}/H_0 and Russian roulette. `sample`: the same walk, which
//! at an upward d_{m+1} continues with probability H_{m+1}/H_m and otherwise
//! leaves along d_{m+1}; the exit density is then exactly the path contribution
//! divided by a^k, so the weight is a^k (Π albedo), no roulette.
//!
//! **Dielectrics are handled elsewhere** (zero / None here): across a
//! refraction Heitz's walk flips the height (C¹ ↦ 1 − C¹), the heights-integrated
//! exit probabilities are no longer rational functions of the Λ values (already
//! order 1 is a Beta function), so the S_k recursion above does not apply;
//! `dielectric.rs` integrates the heights exactly up to the first
//! refraction and samples them after it.

use crate::microfacet::Microfacet;
use crate::microfacet::Microsurface;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use crate::walk::{cosine_about, russian_roulette, vertex_numbers, RR_START};
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// Incremental exit probabilities of an arbitrary direction sequence
/// d_0..d_m (d_0 downward), the complete invariance recursion in scaled form
/// (module docs). O(m²) per pushed direction and per exit query.
#[derive(Clone, Debug)]
pub struct ExitTable {
    /// L_i = |Λ(d_i)|.
    l: Vec<f64>,
    /// d_i points down.
    down: Vec<bool>,
    /// Column j (p(0,j)..p(j,j)) starts at j(j+1)/2.
    p: Vec<f64>,
    /// Scratch column for virtual directions.
    scratch: Vec<f64>,
    /// H_m = probability that d_0..d_m all hit.
    hit: f64,
}

impl ExitTable {
    /// Starts a path with the downward d_0 of |Λ(d_0)| = `l0` (= 1 + Λ(ω_i)).
    pub fn new(l0: f64) -> Self {
        let mut t = ExitTable {
            l: Vec::with_capacity(16),
            down: Vec::with_capacity(16),
            p: Vec::with_capacity(136),
            scratch: Vec::with_capacity(17),
            hit: 1.0,
        };
        t.l.push(l0);
        t.down.push(true);
        t.p.push(1.0);
        t
    }

    /// Number of directions pushed (m + 1).
    pub fn len(&self) -> usize {
        self.l.len()
    }

    pub fn is_empty(&self) -> bool {
        self.l.is_empty()
    }

    /// H_m: the probability that every direction pushed so far hits.
    pub fn hit_probability(&self) -> f64 {
        self.hit
    }

    /// p(i, x) for i = 0..=n into `scratch` (n = number of directions pushed),
    /// x a direction appended after d_{n−1} with |Λ(x)| = `lx`, pointing down
    /// when `x_down`. Returns p(0, x).
    fn column(&mut self, lx: f64, x_down: bool) -> f64 {
        let n = self.l.len();
        self.scratch.clear();
        self.scratch.resize(n + 1, 0.0);
        self.scratch[n] = 1.0;
        if x_down {
            // S = 0 whenever the last direction points down.
            return if n == 0 { 1.0 } else { 0.0 };
        }
        for i in (0..n).rev() {
            if !self.down[i] {
                continue; // first direction up: 0
            }
            let mut sum = 0.0;
            for l in i..n {
                let c = self.scratch[l + 1];
                if c == 0.0 {
                    continue;
                }
                let pil = self.p[l * (l + 1) / 2 + i];
                sum += self.l[l] * pil * c;
            }
            self.scratch[i] = sum / (self.l[i] + lx);
        }
        self.scratch[0]
    }

    /// p_exit(d_0..d_m, x) for an upward x with Λ(x) = `lambda` ≥ 0.
    pub fn exit_probability(&mut self, lambda: f64) -> f64 {
        self.column(lambda, false)
    }

    /// p_exit(d_0..d_m, x)/H_m: the probability of leaving along x given that
    /// d_0..d_m all hit.
    pub fn exit_given_hits(&mut self, lambda: f64) -> f64 {
        if !(self.hit > 0.0) {
            return 0.0;
        }
        self.exit_probability(lambda) / self.hit
    }

    /// Appends d_{m+1} (|Λ| = `l`, pointing down when `down`) and returns the
    /// conditional probability H_{m+1}/H_m that it hits (1 for a downward one).
    pub fn push(&mut self, l: f64, down: bool) -> f64 {
        self.column(l, down);
        self.p.extend_from_slice(&self.scratch);
        self.l.push(l);
        self.down.push(down);
        let h = self.column(0.0, false);
        let cont = if self.hit > 0.0 { h / self.hit } else { 0.0 };
        self.hit = h;
        cont
    }
}

/// p_exit(d_0..d_k) = (Π_{j<k}|Λ(d_j)|)·S_k(d_0..d_k) through [`ExitTable`]
/// (for tests against `invariance::segment_term`). 0 unless d_0 is down and
/// d_k up; 1 for a single direction.
pub fn p_exit_incremental(mf: &Microfacet, dirs: &[DVec3]) -> f64 {
    let n = dirs.len();
    if n == 0 {
        return 0.0;
    }
    if n == 1 {
        return 1.0;
    }
    if !(dirs[0].z < 0.0) || !(dirs[n - 1].z > 0.0) {
        return 0.0;
    }
    let mut t = ExitTable::new(mf.abs_lambda(dirs[0]));
    for &d in &dirs[1..n - 1] {
        t.push(mf.abs_lambda(d), d.z < 0.0);
    }
    t.exit_probability(mf.lambda(dirs[n - 1]))
}

/// |Λ(d)| and whether d points down; None for degenerate directions (Λ = ∞,
/// horizontal, or non-finite).
#[inline]
fn lam(mf: &Microfacet, d: DVec3) -> Option<(f64, bool)> {
    if !d.is_finite() || d.z == 0.0 {
        return None;
    }
    let l = mf.abs_lambda(d);
    if !l.is_finite() {
        return None;
    }
    Some((l, d.z < 0.0))
}

/// One unbiased estimate of f(ω_i, ω_o)·cos θ_o of the invariance model on the
/// diffuse microsurface, orders `opts.orders`, at most `opts.max_bounces`
/// vertices. Zero for conductors and dielectrics, whose walks are
/// `conductor.rs` and `dielectric.rs`.
pub fn eval(mf: &Microfacet, surf: &Microsurface, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> Spectrum {
    let Microsurface::Diffuse { albedo } = *surf else { return Spectrum::ZERO };
    if !(wi.z > 0.0) || !(wo.z > 0.0) || !wi.is_finite() || !wo.is_finite() {
        return Spectrum::ZERO;
    }
    let Some(last) = opts.last_order() else { return Spectrum::ZERO };
    let lambda_o = mf.lambda(wo);
    let l0 = mf.abs_lambda(-wi);
    if !lambda_o.is_finite() || !l0.is_finite() {
        return Spectrum::ZERO;
    }
    let mut w = wi; // −d_m
    let mut table = ExitTable::new(l0);
    let mut throughput = Spectrum::ONE; // Π a · H_m/H_0 / Π q
    let mut result = Spectrum::ZERO;
    for j in 0..last {
        let order = j + 1;
        let (u1, u2) = rng.next2();
        let Some(m) = mf.sample_visible(w, u1, u2) else { break };
        if order >= opts.orders.0 {
            let c = wo.dot(m);
            if c > 0.0 {
                let exit = table.exit_given_hits(lambda_o);
                if exit > 0.0 {
                    result += throughput * albedo * (c * FRAC_1_PI * exit);
                }
            }
        }
        if order >= last {
            break;
        }
        if j >= RR_START && !russian_roulette(&mut throughput, rng) {
            break;
        }
        let (u3, u4) = rng.next2();
        let d = cosine_about(m, u3, u4);
        let Some((l, down)) = lam(mf, d) else { break };
        throughput *= albedo;
        let cont = table.push(l, down);
        throughput *= cont;
        if !(cont > 0.0) || !(throughput.max_value() > 0.0) {
            break;
        }
        w = -d;
    }
    result
}

/// Random-walk sampling of the invariance model on the diffuse microsurface:
/// phase-function directions, and at each upward d_{m+1} exit with probability
/// 1 − H_{m+1}/H_m. Returns (ω_o, weight = Π albedo, order); None when the walk
/// needs more than min(max_bounces, orders.1) vertices, leaves before
/// orders.0, or meets a degenerate direction (the truncation of `eval`, so
/// E[weight·g(ω_o)] = ∫ g·eval). `first` = (u_exit, u1, u2) drives the first
/// vertex (visible normal and exit decision); the cosine lobe and later
/// vertices use `rng`. None for conductors and dielectrics.
pub fn sample(
    mf: &Microfacet,
    surf: &Microsurface,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    let Microsurface::Diffuse { albedo } = *surf else { return None };
    if !(wi.z > 0.0) || !wi.is_finite() {
        return None;
    }
    let last = opts.last_order()?;
    let l0 = mf.abs_lambda(-wi);
    if !l0.is_finite() {
        return None;
    }
    let mut w = wi;
    let mut table = ExitTable::new(l0);
    let mut weight = Spectrum::ONE;
    for j in 0..last {
        let (u_exit, u1, u2) = vertex_numbers(j, first, rng);
        let m = mf.sample_visible(w, u1, u2)?;
        let (u3, u4) = rng.next2();
        let d = cosine_about(m, u3, u4);
        let (l, down) = lam(mf, d)?;
        weight *= albedo;
        let cont = table.push(l, down);
        if !down && u_exit >= cont {
            let order = j + 1;
            if order < opts.orders.0 {
                return None;
            }
            return Some((d, weight, order));
        }
        if !(cont > 0.0) {
            return None;
        }
        w = -d;
    }
    None
}
