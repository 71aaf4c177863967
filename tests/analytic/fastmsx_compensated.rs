//! Fast-MSX (Rosales 2023) and energy compensation (Turquin 2019 + Kulla-Conty
//! 2017): the analytic comparison rows. Neither is energy conserving by
//! construction in general, so their furnace albedo is measured and printed
//! (their measured albedo is reported); what is asserted is what
//! they promise: Fast-MSX = single + a non-negative second-bounce lobe (its
//! albedo exceeds 1 at low and moderate roughness: printed, see the notes), the
//! compensation table equals an independent Monte Carlo estimate of the
//! single-scattering albedo, the compensated furnace albedo is 1 up to the
//! table's interpolation error, sample weights equal eval/pdf.

// Lints relaxed for this test file: angles near 2π on purpose.
#![allow(clippy::approx_constant)]

use crate::common::{Checker, Stat, VndfOutProposal};
use glam::DVec3;
use msx::models::analytic::compensated::{self, AlbedoTable};
use msx::rng::Sampler;
use msx::{Bsdf, Config, Distribution, Material, Model, Spectrum};

fn bsdf(model: Model, dist: Distribution) -> Bsdf {
    Bsdf::new(Config { model, distribution: dist, ..Default::default() }).unwrap()
}

fn copper(alpha: f64) -> Material {
    Material { eta: Spectrum([0.200, 0.924, 1.102, 1.0]), k: Spectrum([3.912, 2.452, 2.142, 1.0]), ..Material::mirror(alpha) }
}

/// Albedo ∫ eval dω_o estimated with a visible-normal + cosine proposal.
fn albedo(b: &Bsdf, mat: &Material, wi: DVec3, n: usize, seed: u64) -> (f64, f64) {
    let mf = msx::Microfacet::new(b.config().distribution, mat.alpha_u, mat.alpha_v);
    let prop = VndfOutProposal::new(mf, wi, 0.2);
    let mut rng = Sampler::new(seed);
    let mut st = Stat::default();
    for i in 0..n {
        let wo = prop.sample(&mut rng);
        let p = prop.pdf(wo);
        st.push(if p > 0.0 { b.eval(mat, wi, wo, i as u64).0[0] / p } else { 0.0 });
    }
    st.est()
}

#[test]
fn fastmsx_is_single_plus_a_nonnegative_second_bounce() {
    let mut c = Checker::new("fastmsx");
    let single = bsdf(Model::Single, Distribution::Ggx);
    let fast = bsdf(Model::FastMsx, Distribution::Ggx);
    let mut rng = Sampler::new(11);
    let mut worst_weight = 0.0f64;
    for &alpha in &[0.1, 0.3, 0.6, 1.0] {
        for mat in [Material::mirror(alpha), copper(alpha)] {
            for _ in 0..300 {
                let wi = crate::common::cosine_hemisphere(rng.next(), rng.next());
                let wo = crate::common::cosine_hemisphere(rng.next(), rng.next());
                let s = single.eval(&mat, wi, wo, 0);
                let f = fast.eval(&mat, wi, wo, 0);
                c.assert("fastmsx ≥ single per channel", (0..3).all(|k| f.0[k] >= s.0[k] - 1e-15));
                c.assert("pdf equals single's", fast.pdf(&mat, wi, wo) == single.pdf(&mat, wi, wo));
                // Sample weight = eval/pdf at the sampled direction (same sampler as single).
                let (a, b2) = rng.next2();
                if let Some(smp) = fast.sample(&mat, wi, 0.5, (a, b2)) {
                    let e = fast.eval(&mat, wi, smp.wo, 0);
                    let rel = (smp.weight.0[0] - e.0[0] / smp.pdf).abs() / (e.0[0] / smp.pdf).max(1e-12);
                    worst_weight = worst_weight.max(rel);
                }
            }
        }
    }
    println!("worst relative |weight − eval/pdf| = {worst_weight:.2e}");
    c.assert("weight = eval/pdf", worst_weight < 1e-9);
    // Measured furnace albedo and non-reciprocity (reported, not asserted: the
    // paper states Fast-MSX is neither energy conserving nor reciprocal).
    println!("Fast-MSX furnace albedo (F = 1), GGX:");
    for &alpha in &[0.1, 0.5, 1.0, 2.0] {
        for &theta in &[0.0f64, 1.0, 1.45] {
            let wi = crate::common::dir(theta, 0.0);
            let (a, se) = albedo(&fast, &Material::mirror(alpha), wi, 100_000, 5);
            let (s, _) = albedo(&single, &Material::mirror(alpha), wi, 100_000, 5);
            println!("  α = {alpha:<4} θ_i = {theta:<4}: fastmsx {a:.4} ± {se:.4}   (single {s:.4})");
            c.assert("fastmsx albedo finite and ≥ single's", a.is_finite() && a >= s);
        }
    }
    let (wi, wo) = (crate::common::dir(0.3, 0.0), crate::common::dir(1.2, 2.0));
    let m = Material::mirror(1.0);
    let r = (fast.eval(&m, wi, wo, 0).0[0] / wo.z) / (fast.eval(&m, wo, wi, 0).0[0] / wi.z) - 1.0;
    println!("Fast-MSX non-reciprocity f(i,o)/f(o,i) − 1 at θ 0.3 → 1.2, α = 1: {r:+.3}");
    c.finish();
}

#[test]
fn compensation_table_matches_monte_carlo_and_restores_energy() {
    let mut c = Checker::new("compensated");
    // 1. The table (deterministic 48×48 stratified quadrature, bilinear in
    //    (μ², √α)) equals an independent MC estimate of single's F = 1 albedo.
    //    Allowance: 1 % for interpolation between nodes (measured max printed).
    let mut rng = Sampler::new(3);
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        let single = bsdf(Model::Single, dist);
        let table = AlbedoTable::get(dist);
        for _ in 0..12 {
            let alpha = (rng.gen_range((0.02f64).ln(), (3.0f64).ln())).exp();
            let mu = rng.gen_range(0.15, 1.0);
            let wi = DVec3::new((1.0 - mu * mu).sqrt(), 0.0, mu);
            let est = albedo(&single, &Material::mirror(alpha), wi, 60_000, rng.next().to_bits());
            c.close(&format!("{dist:?} E(μ={mu:.3}, α={alpha:.3}) table vs MC"), (table.e(alpha, mu), 0.0), est, 0.01, 0.0);
        }
    }
    // 2. Furnace: compensated albedo with F = 1 is 1 up to the same allowance.
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        let comp = bsdf(Model::Compensated, dist);
        for &alpha in &[0.1, 0.5, 1.0, 2.0] {
            for &theta in &[0.0f64, 1.0, 1.45] {
                let wi = crate::common::dir(theta, 0.0);
                let est = albedo(&comp, &Material::mirror(alpha), wi, 60_000, 17);
                println!("  {dist:?} α = {alpha:<4} θ_i = {theta:<4}: compensated albedo {:.4} ± {:.4}", est.0, est.1);
                c.close(&format!("{dist:?} compensated furnace α={alpha} θ={theta}"), est, (1.0, 0.0), 0.01, 0.0);
            }
        }
    }
    // 3. With Fresnel, the scale adds energy and never reduces it; weight = eval/pdf.
    let comp = bsdf(Model::Compensated, Distribution::Ggx);
    let single = bsdf(Model::Single, Distribution::Ggx);
    for &alpha in &[0.2, 1.0] {
        let mat = copper(alpha);
        for _ in 0..200 {
            let wi = crate::common::cosine_hemisphere(rng.next(), rng.next());
            let wo = crate::common::cosine_hemisphere(rng.next(), rng.next());
            let (s, f) = (single.eval(&mat, wi, wo, 0), comp.eval(&mat, wi, wo, 0));
            c.assert("compensated ≥ single", (0..3).all(|k| f.0[k] >= s.0[k]));
            if let Some(smp) = comp.sample(&mat, wi, 0.5, (rng.next(), rng.next())) {
                let e = comp.eval(&mat, wi, smp.wo, 0).0[1] / smp.pdf;
                c.assert("compensated weight = eval/pdf", (smp.weight.0[1] - e).abs() <= 1e-9 * e.max(1e-12));
            }
        }
    }
    let f_avg = compensated::fresnel_average(&msx::microfacet::ConductorFresnel::new(copper(0.5).eta, copper(0.5).k, 3));
    println!("copper F_avg (RGB) = {:.4} {:.4} {:.4}", f_avg.0[0], f_avg.0[1], f_avg.0[2]);
    c.assert("F_avg in (0, 1]", (0..3).all(|k| f_avg.0[k] > 0.0 && f_avg.0[k] <= 1.0));
    c.finish();
}

#[test]
fn analytic_models_are_robust() {
    let mut rng = Sampler::new(99);
    for (model, dists) in [(Model::FastMsx, &[Distribution::Ggx][..]), (Model::Compensated, &[Distribution::Ggx, Distribution::Beckmann][..])] {
        for &dist in dists {
            let b = bsdf(model, dist);
            for _ in 0..3000 {
                let a = (rng.gen_range((1e-4f64).ln(), (4.0f64).ln())).exp();
                let ratio = (rng.gen_range(0.0, (100.0f64).ln())).exp();
                let mat = Material { alpha_u: a, alpha_v: a * ratio, ..copper(a) };
                let th = rng.gen_range(0.0, std::f64::consts::FRAC_PI_2 - 1e-6);
                let wi = crate::common::dir(th, rng.gen_range(0.0, 6.28));
                let wo = crate::common::uniform_sphere(rng.next(), rng.next());
                let v = b.eval(&mat, wi, wo, 0);
                assert!(v.0.iter().all(|x| x.is_finite() && *x >= 0.0), "{model:?} {dist:?} eval {v:?}");
                let p = b.pdf(&mat, wi, wo);
                assert!(p.is_finite() && p >= 0.0);
                if let Some(s) = b.sample(&mat, wi, rng.next(), (rng.next(), rng.next())) {
                    assert!(s.weight.0.iter().all(|x| x.is_finite() && *x >= 0.0) && s.pdf > 0.0 && (s.wo.length() - 1.0).abs() < 1e-9);
                }
            }
        }
    }
}
