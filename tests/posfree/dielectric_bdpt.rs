//! Bidirectional estimator of the position-free rough dielectric
//! (`models::posfree::dielectric::eval_bdpt`) against the PT estimator
//! (`models::posfree::dielectric::eval_pt`), per scattering order and in total,
//! reflection and transmission, from outside and inside, both segment models;
//! furnace E_r + E_t = 1 (Importance mode); variance and time per call.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

use crate::common::*;
use crate::shared::*;
use glam::DVec3;
use msx::microfacet::fresnel::dielectric_full;
use msx::models::posfree::dielectric as bd;
use msx::models::posfree::dielectric as pfd;
use msx::models::posfree::{Options, Segments};
use msx::rng::Sampler;
use msx::walk::bdpt::DEFAULT_BDPT_ORDERS;
use msx::walk::WalkOptions;
use msx::{Distribution, Microfacet};
use std::f64::consts::PI;

const MAX_BOUNCES: u32 = 64;
const ETA: f64 = 1.5;

fn opts(segments: Segments, orders: (u32, u32)) -> Options {
    Options { segments, walk: WalkOptions { max_bounces: MAX_BOUNCES, orders } }
}

fn flip(d: DVec3) -> DVec3 {
    DVec3::new(d.x, d.y, -d.z)
}

/// (name, ω_i, ω_o): reflection / transmission, from outside / inside.
fn pairs() -> [(&'static str, DVec3, DVec3); 6] {
    [
        ("out-refl", dir(0.3, 0.0), dir(1.1, 2.0)),
        ("out-trans", dir(0.6, 0.0), flip(dir(0.4, PI - 0.3))),
        ("in-refl", flip(dir(0.3, 0.0)), flip(dir(0.9, 2.5))),
        ("in-trans", flip(dir(0.3, 0.0)), dir(0.8, PI)),
        ("in-refl-tir", flip(dir(1.0, 0.0)), flip(dir(1.0, PI))),
        ("out-grazing", dir(1.45, 0.0), flip(dir(1.3, PI - 0.4))),
    ]
}

#[test]
fn bdpt_equals_pt_per_order() {
    let mut ck = Checker::new("dielectric bdpt = pt per order (η = 1.5, GGX)");
    let n = 80_000;
    let mut seed = 100u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        for alpha in [0.5, 1.0] {
            let mf = Microfacet::new(Distribution::Ggx, alpha, alpha);
            for (pname, wi, wo) in pairs() {
                for orders in [(1, 1), (2, 2), (3, 3), (1, MAX_BOUNCES)] {
                    for radiance in [false, true] {
                        if radiance && orders != (1, MAX_BOUNCES) {
                            continue;
                        }
                        let o = opts(seg, orders);
                        seed += 2;
                        let (pt, _) = run_scalar(n, |r| pfd::eval_pt(&mf, ETA, radiance, wi, wo, &o, r), seed);
                        let (b, _) = run_scalar(n, |r| bd::eval_bdpt(&mf, ETA, radiance, wi, wo, &o, r), seed + 1);
                        let label = format!(
                            "{} ggx α={alpha} {pname} orders {}..={}{}",
                            seg_name(seg),
                            orders.0,
                            orders.1,
                            if radiance { " radiance" } else { "" }
                        );
                        ck.close(&label, b.est(), pt.est(), 0.0, 1e-12);
                    }
                }
            }
        }
    }
    ck.finish();
}

/// Small and large K_b (PT tail / more bidirectional orders) join without bias.
#[test]
fn bdpt_tail_and_kb_agree() {
    let mut ck = Checker::new("dielectric bdpt with K_b ∈ {1, 2, 5} = pt");
    let n = 80_000;
    let mut seed = 9000u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        let mf = Microfacet::new(Distribution::Ggx, 1.0, 1.0);
        for (pname, wi, wo) in [pairs()[0], pairs()[3]] {
            for kb in [1u32, 2, 5] {
                for orders in [(1, MAX_BOUNCES), (3, 6)] {
                    let o = opts(seg, orders);
                    seed += 2;
                    let (pt, _) = run_scalar(n, |r| pfd::eval_pt(&mf, ETA, false, wi, wo, &o, r), seed);
                    let (b, _) = run_scalar(n, |r| bd::eval_bdpt_with(&mf, ETA, false, wi, wo, &o, kb, r), seed + 1);
                    let label = format!("{} ggx α=1 {pname} K_b={kb} orders {}..={}", seg_name(seg), orders.0, orders.1);
                    ck.close(&label, b.est(), pt.est(), 0.0, 1e-12);
                }
            }
        }
    }
    ck.finish();
}

/// Proposal on the whole sphere: single-scattering sampling (m ~ D_{ω_i},
/// reflect with probability F, else refract; density = vertex term / |Λ(−ω_i)|
/// in ω_i's frame) mixed with a cosine lobe on each side.
struct Proposal {
    mf: Microfacet,
    wi: DVec3,
    k: f64,
}

impl Proposal {
    fn side(&self) -> f64 {
        if self.wi.z > 0.0 {
            1.0
        } else {
            -1.0
        }
    }
    fn eta_f(&self) -> f64 {
        if self.wi.z > 0.0 {
            ETA
        } else {
            1.0 / ETA
        }
    }
    fn sample(&self, rng: &mut Sampler) -> DVec3 {
        let c = rng.next();
        let u = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.k {
            let d = cosine_hemisphere(u1, u2);
            return if u < 0.5 { d } else { flip(d) };
        }
        let s = self.side();
        let w = s * self.wi;
        let Some(m) = self.mf.sample_visible(w, u1, u2) else { return DVec3::Z };
        let cw = w.dot(m);
        let (f, cos_t, _, eta_ti) = dielectric_full(cw, self.eta_f());
        let o = if u < f { msx::microfacet::reflect(w, m) } else { msx::microfacet::refract(w, m, cos_t, eta_ti) };
        (s * o).normalize()
    }
    fn pdf(&self, wo: DVec3) -> f64 {
        let s = self.side();
        let w = s * self.wi;
        let o = s * wo;
        // Both branches can reach any direction (a reflection may go down, a
        // refraction up, in ω_i's frame).
        let v = pfd::vertex_reflect(&self.mf, self.eta_f(), w, o) + pfd::vertex_transmit(&self.mf, self.eta_f(), w, o);
        let l = self.mf.abs_lambda(-w);
        self.k * wo.z.abs() / (2.0 * PI) + (1.0 - self.k) * v / l
    }
}

#[test]
fn bdpt_furnace() {
    let mut ck = Checker::new("dielectric bdpt furnace (Importance): E_r + E_t = 1");
    let n = 150_000;
    let mut seed = 5000u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        for alpha in [0.5, 1.0] {
            let mf = Microfacet::new(Distribution::Ggx, alpha, alpha);
            for (side, theta) in [("out", 0.3), ("out", 1.2), ("in", 0.5)] {
                let wi = if side == "out" { dir(theta, 0.3) } else { flip(dir(theta, 0.3)) };
                let prop = Proposal { mf, wi, k: 0.3 };
                let o = opts(seg, (1, MAX_BOUNCES));
                seed += 1;
                let mut rng = Sampler::new(seed);
                let (mut er, mut et) = (0.0, 0.0);
                let mut st = Stat::default();
                for _ in 0..n {
                    let wo = prop.sample(&mut rng);
                    let p = prop.pdf(wo);
                    let v = if p > 0.0 && wo.z != 0.0 { bd::eval_bdpt(&mf, ETA, false, wi, wo, &o, &mut rng) / p } else { 0.0 };
                    if wo.z * wi.z > 0.0 {
                        er += v;
                    } else {
                        et += v;
                    }
                    st.push(v);
                }
                let label = format!("{} ggx α={alpha} {side} θ_i={theta} (E_r {:.4}, E_t {:.4})", seg_name(seg), er / n as f64, et / n as f64);
                ck.close(&label, st.est(), exact(1.0), 0.003, 0.0);
            }
        }
    }
    ck.finish();
}

/// Not pass/fail: variance per call and time per call of bdpt vs pt.
#[test]
fn bdpt_vs_pt_variance_and_time() {
    println!("=== dielectric η = 1.5, GGX, all orders: variance and ns per call, pt vs bdpt (K_b = {}) ===", DEFAULT_BDPT_ORDERS);
    println!("{:<4} {:>4} {:<12} {:>11} {:>11} {:>7} {:>7} {:>6} {:>6}", "seg", "α", "pair", "var pt", "var bdpt", "ns pt", "ns bd", "var×", "eff×");
    let n = 40_000;
    let mut seed = 7000u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        for alpha in [0.5, 1.0] {
            let mf = Microfacet::new(Distribution::Ggx, alpha, alpha);
            for (pname, wi, wo) in [pairs()[0], pairs()[1], pairs()[3]] {
                let o = opts(seg, (1, MAX_BOUNCES));
                seed += 2;
                let _ = run_scalar(2000, |r| pfd::eval_pt(&mf, ETA, false, wi, wo, &o, r), seed + 77);
                let (pt, t_pt) = run_scalar(n, |r| pfd::eval_pt(&mf, ETA, false, wi, wo, &o, r), seed);
                let (b, t_bd) = run_scalar(n, |r| bd::eval_bdpt(&mf, ETA, false, wi, wo, &o, r), seed + 1);
                println!("{:<4} {:>4} {:<12} {}", seg_name(seg), alpha, pname, cost_columns((pt.var(), b.var()), (t_pt, t_bd)));
            }
        }
    }
}
