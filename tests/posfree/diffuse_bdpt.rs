//! Bidirectional estimator of the position-free rough diffuse microsurface
//! (`models::posfree::diffuse::eval_bdpt`) against the PT estimator
//! (`models::posfree::diffuse::eval_pt`), per scattering order and in total, both
//! segment models; white furnace; variance and time per call.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

// Lints relaxed for this test file: per-channel statistics indexed by channel.
#![allow(clippy::needless_range_loop)]

use crate::common::*;
use crate::shared::*;
use msx::models::posfree::diffuse as bd;
use msx::models::posfree::diffuse as pfd;
use msx::models::posfree::{Options, Segments};
use msx::rng::Sampler;
use msx::walk::bdpt::DEFAULT_BDPT_ORDERS;
use msx::walk::WalkOptions;
use msx::{Distribution, Microfacet, Spectrum};
use std::f64::consts::PI;

const MAX_BOUNCES: u32 = 256;

fn opts(segments: Segments, orders: (u32, u32)) -> Options {
    Options { segments, walk: WalkOptions { max_bounces: MAX_BOUNCES, orders } }
}

fn albedo() -> Spectrum {
    Spectrum([0.9, 0.5, 0.2, 1.0])
}

#[test]
fn bdpt_equals_pt_per_order() {
    let mut ck = Checker::new("diffuse bdpt = pt per order (albedo 0.9/0.5/0.2)");
    let n = 40_000;
    let mut seed = 100u64;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for (pname, wi, wo) in pairs() {
            for orders in [(1, 1), (2, 2), (3, 3), (1, MAX_BOUNCES)] {
                let o = opts(seg, orders);
                seed += 2;
                let label = format!("{} {:?} α={alpha} {pname} orders {}..={}", seg_name(seg), dist, orders.0, orders.1);
                let pt = |r: &mut Sampler| pfd::eval_pt(&mf, albedo(), wi, wo, &o, r);
                check_bdpt_equals_pt(&mut ck, &label, &[0, 2], n, seed, pt, |r| bd::eval_bdpt(&mf, albedo(), wi, wo, &o, r));
            }
        }
    }
    ck.finish();
}

#[test]
fn bdpt_tail_and_kb_agree() {
    let mut ck = Checker::new("diffuse bdpt with K_b ∈ {1, 2, 5} = pt");
    let n = 40_000;
    let mut seed = 9000u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        let mf = Microfacet::new(Distribution::Ggx, 1.0, 1.0);
        let (pname, wi, wo) = pairs()[1];
        for kb in [1u32, 2, 5] {
            for orders in [(1, MAX_BOUNCES), (3, 6)] {
                let o = opts(seg, orders);
                seed += 2;
                let label = format!("{} ggx α=1 {pname} K_b={kb} orders {}..={}", seg_name(seg), orders.0, orders.1);
                let pt = |r: &mut Sampler| pfd::eval_pt(&mf, albedo(), wi, wo, &o, r);
                check_bdpt_equals_pt(&mut ck, &label, &[0], n, seed, pt, |r| bd::eval_bdpt_with(&mf, albedo(), wi, wo, &o, kb, r));
            }
        }
    }
    ck.finish();
}

#[test]
fn bdpt_furnace() {
    let mut ck = Checker::new("diffuse bdpt white furnace (albedo 1): ∫ eval dω_o = 1");
    let n = 100_000;
    let mut seed = 5000u64;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for theta in [0.3, 1.2] {
            let wi = dir(theta, 0.3);
            let o = opts(seg, (1, MAX_BOUNCES));
            seed += 1;
            let mut rng = Sampler::new(seed);
            let mut st = Stat::default();
            for _ in 0..n {
                let (u1, u2) = rng.next2();
                let wo = cosine_hemisphere(u1, u2);
                let p = wo.z / PI;
                let v = if p > 0.0 { bd::eval_bdpt(&mf, Spectrum::ONE, wi, wo, &o, &mut rng).0[0] / p } else { 0.0 };
                st.push(v);
            }
            let label = format!("{} {:?} α={alpha} θ_i={theta}", seg_name(seg), dist);
            ck.close(&label, st.est(), exact(1.0), 0.003, 0.0);
        }
    }
    ck.finish();
}

/// Not pass/fail: variance per call and time per call of bdpt vs pt.
#[test]
fn bdpt_vs_pt_variance_and_time() {
    println!("=== diffuse, all orders, channel 0 (albedo 0.9): variance and ns per call, pt vs bdpt (K_b = {}) ===", DEFAULT_BDPT_ORDERS);
    println!(
        "{:<4} {:<9} {:>4} {:<13} {:>11} {:>11} {:>7} {:>7} {:>6} {:>6}",
        "seg", "dist", "α", "pair", "var pt", "var bdpt", "ns pt", "ns bd", "var×", "eff×"
    );
    let n = 40_000;
    let mut seed = 7000u64;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for (pname, wi, wo) in pairs() {
            let o = opts(seg, (1, MAX_BOUNCES));
            seed += 2;
            let _ = run(2000, |r| pfd::eval_pt(&mf, albedo(), wi, wo, &o, r), seed + 77);
            let (pt, t_pt) = run(n, |r| pfd::eval_pt(&mf, albedo(), wi, wo, &o, r), seed);
            let (b, t_bd) = run(n, |r| bd::eval_bdpt(&mf, albedo(), wi, wo, &o, r), seed + 1);
            let costs = cost_columns((pt[0].var(), b[0].var()), (t_pt, t_bd));
            println!("{:<4} {:<9} {:>4} {:<13} {costs}", seg_name(seg), format!("{dist:?}"), alpha, pname);
        }
    }
}
