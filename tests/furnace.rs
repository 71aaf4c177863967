//! White furnace: a perfect mirror (F = 1) microsurface reflects all the light,
//! so the directional albedo ∫ f(ω_i, ω_o) cos θ_o dω_o of the multiple-scattering
//! models is 1. Checked two independent ways:
//!
//! * `eval` integration: Σ eval(ω_i, ω_o)/q(ω_o) with ω_o from `common::VndfOutProposal`
//!   (reflection about visible normals, density `reflect_pdf`, both validated by
//!   tests/microfacet.rs, mixed with a cosine lobe that covers the whole hemisphere);
//! * the mean `sample` weight (a failed sample counts 0).
//!
//! Tolerance: z·σ + 0.3 % (z = family-wise 3σ level, see `common`), σ the Monte
//! Carlo standard error. `single` only has to stay ≤ 1.
//!
//! Caveat, measured: at α = 0.05 the multiply scattered energy (≈ 0.3 %) leaves
//! in narrow lobes that the proposal rarely hits, so the eval-integrated order
//! ≥ 2 part is heavy-tailed (its sample σ underestimates the error) — at small α
//! this test is only as strong as the 0.3 % allowance.

mod common;

use common::*;
use msx::rng::Sampler;
use msx::{Bsdf, Distribution};
use msx::{Config, Material, Model};

// Issue 2 asks for {0.05, 0.3, 0.6, 1.0, 1.5}; the model-family issue adds 0.1 and 2.0.
const ALPHAS: [f64; 7] = [0.05, 0.1, 0.3, 0.6, 1.0, 1.5, 2.0];
const THETAS: [f64; 3] = [0.0, 1.0, 1.45];
const N_EVAL: usize = 500_000;
const N_SAMPLE: usize = 100_000;

/// Weight of the cosine lobe in the proposal: multiply scattered energy grows with α.
fn lobe_weight(alpha: f64) -> f64 {
    alpha.clamp(0.02, 0.8)
}

/// (eval-integrated albedo, mean sample weight), each (mean, σ).
fn albedo(bsdf: &Bsdf, alpha: f64, theta: f64, seed: u64) -> ((f64, f64), (f64, f64)) {
    let mat = Material::mirror(alpha);
    let wi = dir(theta, 0.3);
    let prop = VndfOutProposal::new(msx::Microfacet::new(bsdf.config().distribution, alpha, alpha), wi, lobe_weight(alpha));
    let mut rng = Sampler::new(seed);
    let mut s_eval = Stat::default();
    for i in 0..N_EVAL {
        let wo = prop.sample(&mut rng);
        let v = if wo.z > 0.0 { bsdf.eval(&mat, wi, wo, i as u64).0[0] / prop.pdf(wo) } else { 0.0 };
        s_eval.push(v);
    }
    let mut s_smp = Stat::default();
    for _ in 0..N_SAMPLE {
        let s1 = rng.next();
        let u = rng.next2();
        let w = match bsdf.sample(&mat, wi, s1, u) {
            Some(s) => s.weight.0[0],
            None => 0.0,
        };
        s_smp.push(w);
    }
    (s_eval.est(), s_smp.est())
}

fn furnace(dist: Distribution, model: Model, seed: u64) {
    let bsdf = Bsdf::new(Config { distribution: dist, model, ..Config::default() }).unwrap();
    let mut ck = Checker::new(&format!("white furnace {dist:?} {model:?}"));
    let mut table = Vec::new();
    for (ai, &alpha) in ALPHAS.iter().enumerate() {
        for (ti, &theta) in THETAS.iter().enumerate() {
            let (e, s) = albedo(&bsdf, alpha, theta, seed + 10 * ai as u64 + ti as u64);
            let tag = format!("{dist:?} {model:?} α={alpha} θ_i={theta}");
            ck.close(&format!("{tag}: eval-integrated albedo"), e, exact(1.0), 0.003, 0.0);
            ck.close(&format!("{tag}: mean sample weight"), s, exact(1.0), 0.003, 0.0);
            table.push((alpha, theta, e, s));
        }
    }
    println!("{dist:?} {model:?}: α, θ_i, albedo(eval) ± σ, albedo(sample) ± σ");
    for (a, t, e, s) in table {
        println!("  {a:5} {t:5}  {:.5} ± {:.5}  {:.5} ± {:.5}", e.0, e.1, s.0, s.1);
    }
    ck.finish();
}

#[test]
fn furnace_ggx_uncorrelated() {
    furnace(Distribution::Ggx, Model::Uncorrelated, 100);
}

#[test]
fn furnace_ggx_correlated() {
    furnace(Distribution::Ggx, Model::Correlated, 200);
}

#[test]
fn furnace_beckmann_uncorrelated() {
    furnace(Distribution::Beckmann, Model::Uncorrelated, 300);
}

#[test]
fn furnace_beckmann_correlated() {
    furnace(Distribution::Beckmann, Model::Correlated, 400);
}

/// Single scattering loses energy: its albedo stays ≤ 1 (+ z·σ).
#[test]
fn single_albedo_at_most_one() {
    let mut ck = Checker::new("single-scattering albedo ≤ 1");
    println!("single: dist, α, θ_i, albedo(eval) ± σ, albedo(sample) ± σ");
    for (di, dist) in [Distribution::Ggx, Distribution::Beckmann].into_iter().enumerate() {
        let bsdf = Bsdf::new(Config { distribution: dist, model: Model::Single, ..Config::default() }).unwrap();
        for (ai, &alpha) in ALPHAS.iter().enumerate() {
            for (ti, &theta) in THETAS.iter().enumerate() {
                let (e, s) = albedo(&bsdf, alpha, theta, 500 + 100 * di as u64 + 10 * ai as u64 + ti as u64);
                let tag = format!("single {dist:?} α={alpha} θ_i={theta}");
                ck.at_most(&format!("{tag}: eval-integrated albedo"), e, 1.0);
                ck.at_most(&format!("{tag}: mean sample weight"), s, 1.0);
                // The two estimators of the same integral agree. For Beckmann, Mitsuba's
                // sample weight uses the rational G1 (< 0.35 % from the exact one, Walter
                // 2007) while its sampler draws the exact visible normals: 0.35 % allowance.
                let allow = if dist == Distribution::Beckmann { 0.0035 } else { 0.0 };
                ck.close(&format!("{tag}: eval vs sample albedo"), e, s, allow, 0.0);
            }
        }
    }
    ck.finish();
}
