//! The invariance-principle idea (Cui et al. 2023: Heitz's random walk with
//! the microsurface heights integrated out) carried as far as it goes on a
//! rough **dielectric** interface.
//!
//! **Why the S_k recursion stops at a refraction.** Work with the optical depth
//! τ = −ln C¹(h) ≥ 0 below the top of the microsurface (C¹ the height CDF; the
//! model does not depend on the height distribution). A downward direction
//! with |Λ| = L travels τ ← τ + X, X ~ Exp(L); an upward one with Λ travels
//! τ ← τ − Y, Y ~ Exp(Λ), and leaves when τ ≤ 0 (probability e^{−Λτ} = G1(ω,h)).
//! Every heights-integrated probability of a one-sided path is then a rational
//! function of the Λ values (Cui's S_k). A refraction sees the surface from the
//! other side: C¹ ↦ 1 − C¹ (Heitz 2016 §3.4, symmetric heights), i.e.
//! e^{−τ} ↦ 1 − e^{−τ}, and the exit probability of the refracted ray becomes
//! (1 − e^{−τ})^{Λ'}. Already for one vertex its expectation is
//! L·B(L, 1 + Λ') (the Beta-function G2 of transmission, Wang eq. 19) — not a
//! rational function of L and Λ', so no recursion of S_k type can produce it;
//! with more vertices the integrals are incomplete-Beta/hypergeometric. So the
//! heights are integrated exactly where a closed form exists and sampled
//! where it does not:
//!
//! **Exact part: the first run.** Until the first refraction the path stays in
//! the medium of ω_i and only reflects, so its directions are monotone (down…
//! down, up… up: a reflection turns an upward ray further up, see
//! `conductor.rs`). For such a run the depth of the current vertex has an
//! exact finite description, [`PieceChain`]: the downward directions stack
//! independent exponential pieces X_0, …, X_{a−1} (rates L_0 … L_{a−1}); an
//! upward jump Y ~ Exp(Λ) eats the pieces from the bottom; by memorylessness a
//! partly eaten piece is again Exp(L_c) and a jump that passes a piece goes on
//! as a fresh Exp(Λ). So given the hits, τ = X_0 + … + X_c with fresh
//! independent pieces and a random index c whose distribution π follows a
//! race between exponential clocks:
//!
//! P(land in piece c' | in piece c) = Λ/(L_{c'}+Λ) · Π_{i=c'+1}^{c} L_i/(L_i+Λ),
//! P(leave | in piece c) = Π_{i=0}^{c} L_i/(L_i+Λ).
//!
//! All terms are positive (stable). The exit probability of a same-side ω_o
//! given the hits is E[e^{−Λ_o τ}] = Σ_c π(c) Π_{i≤c} L_i/(L_i+Λ_o) — the same
//! numbers as Cui's S_k (`recursion.rs`, tested against it) — and the
//! continuation probability of an upward direction is 1 − P(leave).
//!
//! **Sampled part.** Through the interface the exit probability is
//! E[(1 − e^{−τ})^{Λ'}]: exact, L_0·B(L_0, 1+Λ'), for the mass π(0) in the top
//! piece (all of it at the first vertex, so order 1 is deterministic and equals
//! Walter's BTDF with the Beta G2); for c ≥ 1 one τ is drawn from the exact
//! conditional law. When the walk itself refracts, τ is drawn from the exact
//! conditional law of the vertex depth given the whole run, flipped, and the
//! rest of the path is Heitz's walk (`walk::height::eval_from` / `sample_from`) from
//! that height: by the tower property the estimate stays unbiased, and it
//! equals Heitz's walk in expectation (tests/invariance/dielectric.rs).
//!
//! **Estimators.** `eval`: the first run draws visible normals, chooses
//! reflection with probability F (Heitz's phase function), carries the exact
//! hit probabilities in its throughput, and estimates towards ω_o at every
//! vertex with the phase function × the exact exit probability above. Russian
//! roulette as in `conductor.rs`. `sample`: the same walk leaves along an
//! upward direction with the exact probability 1 − H_{m+1}/H_m, so every
//! sample weight is 1 (times Mitsuba's 1/η² for a Radiance-mode transmission).
//! Transport modes as in `src/walk/height.rs` (Importance-mode vertex terms; the
//! Radiance-mode factor applied once per path).

use crate::microfacet::dielectric::{eta_seen, radiance_scale, refract_unit, valid_ior};
use crate::microfacet::Microsurface;
use crate::microfacet::{fresnel, reflect, Microfacet};
use crate::models::posfree::dielectric::l_beta;
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use crate::walk::{height, russian_roulette, vertex_numbers, RR_START};
use glam::DVec3;

/// Exact depth law of the current vertex of a monotone one-sided run entered
/// from above the microsurface (module docs): the rates L_i of the pieces
/// stacked by the downward directions and the distribution π over the index c
/// of the piece the vertex lies in (given that every direction so far hit).
#[derive(Clone, Debug)]
pub struct PieceChain {
    /// L_i = |Λ(d_i)| of the downward directions d_0 … d_{a−1}.
    rates: Vec<f64>,
    /// π(c), normalised; empty until the first upward direction (then the
    /// vertex lies in the bottom piece, c = a − 1, for sure).
    pi: Vec<f64>,
    /// H_m: the probability that every direction so far hits.
    hit: f64,
}

impl PieceChain {
    /// A run entered along d_0 (downward) with |Λ(d_0)| = `l0` (= 1 + Λ(ω_i)).
    pub fn new(l0: f64) -> Self {
        let mut rates = Vec::with_capacity(4);
        rates.push(l0);
        PieceChain { rates, pi: Vec::new(), hit: 1.0 }
    }

    /// H_m, the probability that every direction pushed so far hits.
    pub fn hit_probability(&self) -> f64 {
        self.hit
    }

    fn has_up(&self) -> bool {
        !self.pi.is_empty()
    }

    /// π(c) for c = 0 … a−1 (materialised point mass before the first up).
    fn pi_at(&self, c: usize) -> f64 {
        if self.has_up() {
            self.pi[c]
        } else if c + 1 == self.rates.len() {
            1.0
        } else {
            0.0
        }
    }

    /// Appends a downward direction (|Λ| = `l` ≥ 1; it always hits). Returns
    /// false on a non-monotone run (a downward direction after an upward one),
    /// which a run of reflections never produces.
    pub fn push_down(&mut self, l: f64) -> bool {
        if self.has_up() {
            return false;
        }
        self.rates.push(l);
        true
    }

    /// Appends an upward direction with Λ = `lambda` ≥ 0 and returns the
    /// conditional probability H_{m+1}/H_m that it hits again.
    pub fn push_up(&mut self, lambda: f64) -> f64 {
        let a = self.rates.len();
        if !self.has_up() {
            self.pi = vec![0.0; a];
            self.pi[a - 1] = 1.0;
        }
        if lambda == f64::INFINITY {
            return 1.0; // horizontal: hits at its own depth
        }
        if !(lambda > 0.0) {
            self.hit = 0.0; // vertical (or invalid): always leaves
            return 0.0;
        }
        // carry(c) = Σ_{c'' ≥ c} π(c'') Π_{i=c+1}^{c''} L_i/(L_i+Λ): the mass whose
        // jump reaches piece c; a fraction Λ/(L_c+Λ) of it lands there.
        let mut carry = 0.0;
        let mut cont = 0.0;
        for c in (0..a).rev() {
            let l = self.rates[c];
            if c + 1 < a {
                let ln = self.rates[c + 1];
                carry *= ln / (ln + lambda);
            }
            carry += self.pi[c];
            let land = carry * (lambda / (l + lambda));
            self.pi[c] = land;
            cont += land;
        }
        if !(cont > 0.0) || !cont.is_finite() {
            self.hit = 0.0;
            return 0.0;
        }
        let inv = 1.0 / cont;
        for p in &mut self.pi {
            *p *= inv;
        }
        let cont = cont.min(1.0);
        self.hit *= cont;
        cont
    }

    /// E[e^{−Λ τ}] given the hits: the probability of leaving along an upward
    /// direction with Λ = `lambda` from the current vertex.
    pub fn exit_given_hits(&self, lambda: f64) -> f64 {
        if !(lambda >= 0.0) {
            return 0.0;
        }
        if lambda == f64::INFINITY {
            return 0.0;
        }
        let mut prod = 1.0;
        let mut sum = 0.0;
        for (c, &l) in self.rates.iter().enumerate() {
            prod *= l / (l + lambda);
            sum += self.pi_at(c) * prod;
        }
        sum
    }

    /// Draws the depth τ of the current vertex from its exact law given the
    /// hits, restricted to pieces c ≥ `c_min` (π renormalised over them).
    fn sample_depth_from(&self, c_min: usize, rng: &mut Sampler) -> f64 {
        let a = self.rates.len();
        let c = if self.has_up() {
            let total: f64 = self.pi[c_min..].iter().sum();
            let mut u = rng.next() * total;
            let mut pick = a - 1;
            for c in c_min..a {
                u -= self.pi[c];
                if u < 0.0 {
                    pick = c;
                    break;
                }
            }
            pick
        } else {
            a - 1
        };
        let mut tau = 0.0;
        for &l in &self.rates[..=c] {
            tau += -(1.0 - rng.next()).ln() / l; // L = ∞ (horizontal): no depth
        }
        tau
    }

    /// Draws the depth τ of the current vertex from its exact law given the hits.
    pub fn sample_depth(&self, rng: &mut Sampler) -> f64 {
        self.sample_depth_from(0, rng)
    }

    /// Unbiased estimate of E[(1 − e^{−τ})^{Λ'}] given the hits: the
    /// probability that a ray refracted at the current vertex leaves the other
    /// side along a direction with Λ' = `lambda_t` (Λ of that side's frame).
    /// The top piece's mass is integrated exactly (L_0·B(L_0, 1+Λ')); one depth
    /// drawn from the deeper pieces carries the rest.
    pub fn transmit_exit(&self, lambda_t: f64, rng: &mut Sampler) -> f64 {
        if !(lambda_t >= 0.0) || lambda_t == f64::INFINITY {
            return 0.0;
        }
        let p0 = self.pi_at(0);
        let mut e = p0 * l_beta(self.rates[0], lambda_t);
        let rest = 1.0 - p0;
        if rest > 1e-15 {
            let tau = self.sample_depth_from(1, rng);
            let above = -(-tau).exp_m1(); // 1 − e^{−τ} = 1 − C¹ of the vertex
            e += rest * (lambda_t * above.ln()).exp();
        }
        if e.is_finite() {
            e.clamp(0.0, 1.0)
        } else {
            0.0
        }
    }
}

/// One unbiased estimate of f(ω_i, ω_o)·|cos θ_o| of the rough dielectric
/// (Heitz's microsurface, relative IOR `eta` = η_int/η_ext) with the heights
/// of the first run integrated out (module docs), orders `opts.orders`, at most
/// `opts.max_bounces` vertices. Radiance mode scales a transmission by 1/η_rel².
/// One loop over the vertices: its steps (next event, roulette, scattering,
/// exit bookkeeping) share the walk's state.
pub fn eval(mf: &Microfacet, eta: f64, radiance: bool, wi: DVec3, wo: DVec3, opts: &WalkOptions, rng: &mut Sampler) -> f64 {
    if !wi.is_finite() || !wo.is_finite() || wi.z == 0.0 || wo.z == 0.0 || !valid_ior(eta) {
        return 0.0;
    }
    let Some(last) = opts.last_order() else { return 0.0 };
    let surf = Microsurface::Dielectric { eta, radiance };
    let outside = wi.z > 0.0;
    let same_side = (wo.z > 0.0) == outside;
    let e = eta_seen(eta, outside);
    let wo_l = height::local(wo, outside);
    // Λ of ω_o in the frame of the medium it leaves into.
    let lambda_o = if same_side { mf.lambda(wo_l) } else { mf.lambda(-wo_l) };
    let mut w = height::local(wi, outside); // −d_m, local frame of the first run
    let l0 = mf.abs_lambda(-w);
    if !lambda_o.is_finite() || !l0.is_finite() {
        return 0.0;
    }
    let mut chain = PieceChain::new(l0);
    let mut throughput = 1.0; // Π (H_j/H_{j−1}) / Π q
    let mut result = 0.0;
    for j in 0..last {
        let order = j + 1;
        // Next-event estimation towards ω_o: phase function × exit probability.
        if order >= opts.orders.0 {
            let phase = height::dielectric_phase(mf, w, wo_l, e, same_side);
            if phase > 0.0 {
                let exit = if same_side { chain.exit_given_hits(lambda_o) } else { chain.transmit_exit(lambda_o, rng) };
                result += throughput * phase * exit;
            }
        }
        if order >= last {
            break;
        }
        if j >= RR_START {
            let mut t = Spectrum::splat(throughput);
            if !russian_roulette(&mut t, rng) {
                break;
            }
            throughput = t.0[0];
        }
        // Scatter: visible normal, then reflect with probability F.
        let (u1, u2) = rng.next2();
        let Some(m) = height::visible_normal(mf, w, u1, u2) else { break };
        let c = w.dot(m);
        let f = fresnel::dielectric(c, e);
        if rng.next() >= f {
            if let Some(o) = refract_unit(w, m, c, e) {
                // Leave the exact part: sample the vertex depth, continue as Heitz.
                let tau = chain.sample_depth(rng);
                let state = height::State::after_refraction(outside, o, -tau, Spectrum::splat(throughput), order + 1);
                result += height::eval_from(mf, &surf, wo, state, opts, rng).0[0];
                break;
            }
            // Total internal reflection: reflect (F = 1 in effect).
        }
        let d = reflect(w, m);
        if !d.is_finite() || d.z == 0.0 {
            break;
        }
        if d.z > 0.0 {
            let lambda = mf.lambda(d);
            if lambda.is_nan() {
                break;
            }
            let cont = chain.push_up(lambda);
            throughput *= cont;
            if !(cont > 0.0) {
                break;
            }
        } else {
            let l = mf.abs_lambda(d);
            if !l.is_finite() || !chain.push_down(l) {
                break;
            }
        }
        w = -d;
    }
    let scale = radiance_scale(eta, radiance, outside, wo.z > 0.0);
    let v = result * scale;
    if v.is_finite() && v > 0.0 {
        v
    } else {
        0.0
    }
}

/// Random-walk sampling with the heights of the first run integrated out:
/// leave along an upward direction with the exact conditional exit
/// probability, and at the first refraction draw the vertex depth from its
/// exact law and continue with Heitz's walk. Returns (ω_o, weight, order):
/// weight 1 (Importance mode) or 1/η_rel² (Radiance-mode transmission); None
/// under the truncation of `eval` (more than min(max_bounces, orders.1)
/// vertices, leaving before orders.0) or a degenerate direction. `first` =
/// (u_choice, u1, u2) drives the first vertex (Fresnel choice, visible normal).
pub fn sample(
    mf: &Microfacet,
    eta: f64,
    radiance: bool,
    wi: DVec3,
    first: (f64, f64, f64),
    opts: &WalkOptions,
    rng: &mut Sampler,
) -> Option<(DVec3, f64, u32)> {
    if !wi.is_finite() || wi.z == 0.0 || !valid_ior(eta) {
        return None;
    }
    let last = opts.last_order()?;
    let surf = Microsurface::Dielectric { eta, radiance };
    let outside = wi.z > 0.0;
    let e = eta_seen(eta, outside);
    let mut w = height::local(wi, outside);
    let l0 = mf.abs_lambda(-w);
    if !l0.is_finite() {
        return None;
    }
    let mut chain = PieceChain::new(l0);
    let finish = |wo: DVec3, weight: f64, order: u32| -> Option<(DVec3, f64, u32)> {
        let weight = weight * radiance_scale(eta, radiance, outside, wo.z > 0.0);
        (wo.is_finite() && wo.z != 0.0 && weight.is_finite() && order >= opts.orders.0).then_some((wo, weight, order))
    };
    for j in 0..last {
        let order = j + 1;
        let (u_choice, u1, u2) = vertex_numbers(j, first, rng);
        let m = height::visible_normal(mf, w, u1, u2)?;
        let c = w.dot(m);
        let f = fresnel::dielectric(c, e);
        if u_choice >= f {
            if let Some(o) = refract_unit(w, m, c, e) {
                let tau = chain.sample_depth(rng);
                let state = height::State::after_refraction(outside, o, -tau, Spectrum::ONE, order + 1);
                let (wo, weight, k) = height::sample_from(mf, &surf, state, None, opts, rng)?;
                return finish(wo, weight.0[0], k);
            }
        }
        let d = reflect(w, m);
        if !d.is_finite() || d.z == 0.0 {
            return None;
        }
        if d.z > 0.0 {
            let lambda = mf.lambda(d);
            if lambda.is_nan() {
                return None;
            }
            let cont = chain.push_up(lambda);
            if rng.next() >= cont {
                return finish(height::local(d, outside), 1.0, order);
            }
        } else {
            let l = mf.abs_lambda(d);
            if !l.is_finite() || !chain.push_down(l) {
                return None;
            }
        }
        w = -d;
    }
    None
}
