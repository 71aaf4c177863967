//! Bidirectional estimator of the position-free conductor
//! (`models::posfree::conductor::eval_bdpt`, Wang 2022 eqs. 27–29) against the PT estimator
//! (`models::posfree::conductor::eval_pt`), per scattering order and in total, for both
//! segment models; white furnace; variance and time per call.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

// Lints relaxed for this test file: per-channel statistics indexed by channel.
#![allow(clippy::needless_range_loop)]

use crate::common::*;
use crate::shared::*;
use msx::microfacet::ConductorFresnel;
use msx::models::posfree::conductor as posfree_bdpt;
use msx::models::posfree::{self, Options, Segments};
use msx::rng::Sampler;
use msx::walk::bdpt::DEFAULT_BDPT_ORDERS;
use msx::walk::WalkOptions;
use msx::{Distribution, Microfacet, Spectrum};

const MAX_BOUNCES: u32 = 64;

fn copper() -> ConductorFresnel {
    ConductorFresnel::new(Spectrum([0.200, 0.924, 1.102, 1.0]), Spectrum([3.912, 2.452, 2.142, 1.0]), 3)
}

fn mirror() -> ConductorFresnel {
    ConductorFresnel::new(Spectrum::ZERO, Spectrum::ONE, 3)
}

fn opts(segments: Segments, orders: (u32, u32)) -> Options {
    Options { segments, walk: WalkOptions { max_bounces: MAX_BOUNCES, orders } }
}

// ---------------------------------------------------------------------------

#[test]
fn bdpt_equals_pt_per_order() {
    let mut ck = Checker::new("bdpt = pt per order (copper, 3 channels)");
    let n = 40_000;
    let fr = copper();
    let mut seed = 100u64;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for (pname, wi, wo) in pairs() {
            for orders in [(1, 1), (2, 2), (3, 3), (1, MAX_BOUNCES)] {
                let o = opts(seg, orders);
                seed += 2;
                let label = format!("{} {} α={alpha} {pname} orders {}..={}", seg_name(seg), dist_name(dist), orders.0, orders.1);
                let pt = |r: &mut Sampler| posfree::conductor::eval_pt(&mf, &fr, wi, wo, &o, r);
                check_bdpt_equals_pt(&mut ck, &label, &[0, 1, 2], n, seed, pt, |r| posfree_bdpt::eval_bdpt(&mf, &fr, wi, wo, &o, r));
            }
        }
    }
    ck.finish();
}

/// The tail beyond the bidirectional orders (PT continuation) joins without bias:
/// a small K_b with all orders equals PT.
#[test]
fn bdpt_tail_and_cap_agree() {
    let mut ck = Checker::new("bdpt with K_b ∈ {1, 2, 6} (PT tail) = pt");
    let n = 40_000;
    let fr = copper();
    let mut seed = 9000u64;
    for seg in [Segments::Uncorrelated, Segments::Correlated] {
        let mf = Microfacet::new(Distribution::Ggx, 1.0, 1.0);
        let (pname, wi, wo) = pairs()[1];
        for kb in [1u32, 2, 6] {
            for orders in [(1, MAX_BOUNCES), (3, 6)] {
                let o = opts(seg, orders);
                seed += 2;
                let label = format!("{} ggx α=1 {pname} K_b={kb} orders {}..={}", seg_name(seg), orders.0, orders.1);
                let pt = |r: &mut Sampler| posfree::conductor::eval_pt(&mf, &fr, wi, wo, &o, r);
                check_bdpt_equals_pt(&mut ck, &label, &[0, 1, 2], n, seed, pt, |r| posfree_bdpt::eval_bdpt_with(&mf, &fr, wi, wo, &o, kb, r));
            }
        }
    }
    ck.finish();
}

#[test]
fn bdpt_furnace() {
    let mut ck = Checker::new("bdpt white furnace (F = 1): ∫ eval dω_o = 1");
    let n = 100_000;
    let fr = mirror();
    let mut seed = 5000u64;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for theta in [0.3, 1.2] {
            let wi = dir(theta, 0.3);
            let prop = VndfOutProposal::new(mf, wi, alpha.clamp(0.3, 0.8));
            let o = opts(seg, (1, MAX_BOUNCES));
            seed += 1;
            let mut rng = Sampler::new(seed);
            let mut st = Stat::default();
            for _ in 0..n {
                let wo = prop.sample(&mut rng);
                let v = if wo.z > 0.0 {
                    let p = prop.pdf(wo);
                    if p > 0.0 {
                        posfree_bdpt::eval_bdpt(&mf, &fr, wi, wo, &o, &mut rng).0[0] / p
                    } else {
                        0.0
                    }
                } else {
                    0.0
                };
                st.push(v);
            }
            let label = format!("{} {} α={alpha} θ_i={theta}", seg_name(seg), dist_name(dist));
            ck.close(&label, st.est(), exact(1.0), 0.003, 0.0);
        }
    }
    ck.finish();
}

/// Not pass/fail: variance per call and time per call of bdpt vs pt.
#[test]
fn bdpt_vs_pt_variance_and_time() {
    println!(
        "=== variance per call (channel 0 = red, copper) and ns per call, all orders; bdpt = default K_b = {}, bdpt6 = K_b = 6 ===",
        DEFAULT_BDPT_ORDERS
    );
    println!(
        "{:<4} {:<9} {:>4} {:<13} {:>11} {:>11} {:>11} {:>7} {:>7} {:>7} {:>6} {:>6} {:>6} {:>6}",
        "seg", "dist", "α", "pair", "var pt", "var bdpt", "var bdpt6", "ns pt", "ns bd", "ns bd6", "var×", "eff×", "var×6", "eff×6"
    );
    let n = 60_000;
    let fr = copper();
    let mut seed = 7000u64;
    let mut wins_off = 0;
    let mut total_off = 0;
    for (seg, dist, alpha, mf) in bdpt_surfaces() {
        for (pname, wi, wo) in pairs() {
            let o = opts(seg, (1, MAX_BOUNCES));
            seed += 2;
            // Warm-up so that the timing excludes first-touch effects.
            let _ = run(2000, |r| posfree::conductor::eval_pt(&mf, &fr, wi, wo, &o, r), seed + 77);
            let (pt, t_pt) = run(n, |r| posfree::conductor::eval_pt(&mf, &fr, wi, wo, &o, r), seed);
            let (bd, t_bd) = run(n, |r| posfree_bdpt::eval_bdpt(&mf, &fr, wi, wo, &o, r), seed + 1);
            let (bd6, t_bd6) = run(n / 3, |r| posfree_bdpt::eval_bdpt_with(&mf, &fr, wi, wo, &o, 6, r), seed + 5001);
            let (vp, vb, vb6) = (pt[0].var(), bd[0].var(), bd6[0].var());
            let ratio = vp / vb;
            let eff = (vp * t_pt) / (vb * t_bd);
            let (ratio6, eff6) = (vp / vb6, (vp * t_pt) / (vb6 * t_bd6));
            if pname == "off-specular" {
                total_off += 1;
                if vb < vp {
                    wins_off += 1;
                }
            }
            println!(
                "{:<4} {:<9} {:>4} {:<13} {:>11.3e} {:>11.3e} {:>11.3e} {:>7.0} {:>7.0} {:>7.0} {:>6.2} {:>6.2} {:>6.2} {:>6.2}",
                seg_name(seg),
                dist_name(dist),
                alpha,
                pname,
                vp,
                vb,
                vb6,
                t_pt,
                t_bd,
                t_bd6,
                ratio,
                eff,
                ratio6,
                eff6
            );
        }
    }
    println!("off-specular: bdpt has lower variance per call in {wins_off}/{total_off} configurations (var× = var pt / var bdpt; eff× = (var·time) pt / bdpt; timings are noisy while other tests run)");
}
