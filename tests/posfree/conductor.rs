//! Properties of the position-free models (Wang et al. 2022, conductors):
//! single-scattering limit, reciprocity, sampled-direction moments (Heitz 2016
//! supplement §4.4.4), per-bounce energy, and pdf/sample consistency.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

use crate::common::*;
use glam::DVec3;
use msx::microfacet::{fresnel, mitsuba};
use msx::rng::Sampler;
use msx::{Bsdf, Distribution, Microfacet, Spectrum};
use msx::{Config, Material, Model};
use std::f64::consts::PI;

fn bsdf(dist: Distribution, model: Model) -> Bsdf {
    Bsdf::new(Config { distribution: dist, model, ..Config::default() }).unwrap()
}

fn copper(ax: f64, ay: f64) -> Material {
    Material {
        alpha_u: ax,
        alpha_v: ay,
        eta: Spectrum([0.200, 0.924, 1.102, 1.0]),
        k: Spectrum([3.912, 2.452, 2.142, 1.0]),
        specular_reflectance: Spectrum([0.9, 0.8, 0.7, 1.0]),
        ..Material::mirror(ax)
    }
}

fn upper(rng: &mut Sampler, max_theta: f64) -> DVec3 {
    dir(max_theta * rng.next(), 2.0 * PI * rng.next())
}

// ---------------------------------------------------------------------------
// Order 1 = Walter 2007 (deterministic).

#[test]
fn order1_is_walter() {
    let mut ck = Checker::new("order 1 of the position-free models = Walter 2007 (deterministic)");
    let mut rng = Sampler::new(1);
    let alphas = [(0.05, 0.05), (0.3, 0.3), (1.0, 1.0), (1.5, 1.5), (0.2, 0.7)];
    let mut worst_unc = 0.0f64;
    let mut worst_cor = 0.0f64;
    let mut worst_single_ggx = 0.0f64;
    let mut worst_single_beck = 0.0f64;
    let mut worst_g1_beck = 0.0f64;
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        let unc = bsdf(dist, Model::Uncorrelated);
        let cor = bsdf(dist, Model::Correlated);
        let single = bsdf(dist, Model::Single);
        for &(ax, ay) in &alphas {
            let mf = Microfacet::new(dist, ax, ay);
            for mat in [Material { alpha_u: ax, alpha_v: ay, ..Material::mirror(ax) }, copper(ax, ay)] {
                for i in 0..3000u64 {
                    let wi = upper(&mut rng, 1.5);
                    let wo = upper(&mut rng, 1.5);
                    let h = (wi + wo).normalize();
                    let d = mf.d(h);
                    if !(d > 0.0) {
                        continue;
                    }
                    let g_sep = mf.g1_dist(wi) * mf.g1_dist(wo);
                    let g2 = 1.0 / (1.0 + mf.lambda(wi) + mf.lambda(wo));
                    // Relative difference; below 1e-300 (subnormals) values lose relative precision.
                    let rel = |a: f64, b: f64| ((a - b).abs() - 1e-300).max(0.0) / a.abs().max(b.abs()).max(1e-300);
                    let e_unc = unc.eval_orders(&mat, wi, wo, i, (1, 1));
                    let e_cor = cor.eval_orders(&mat, wi, wo, i, (1, 1));
                    let e_single = single.eval(&mat, wi, wo, i);
                    for c in 0..3 {
                        let f = fresnel::conductor(wi.dot(h), mat.eta.0[c], mat.k.0[c]) * mat.specular_reflectance.0[c];
                        let walter_sep = f * d * g_sep / (4.0 * wi.z);
                        let walter_g2 = f * d * g2 / (4.0 * wi.z);
                        worst_unc = worst_unc.max(rel(e_unc.0[c], walter_sep));
                        worst_cor = worst_cor.max(rel(e_cor.0[c], walter_g2));
                        let s = rel(e_single.0[c], e_unc.0[c]);
                        match dist {
                            Distribution::Ggx => worst_single_ggx = worst_single_ggx.max(s),
                            Distribution::Beckmann => worst_single_beck = worst_single_beck.max(s),
                        }
                    }
                    if dist == Distribution::Beckmann {
                        for w in [wi, wo] {
                            worst_g1_beck = worst_g1_beck.max(rel(mitsuba::smith_g1(&mf, w, h), mf.g1_dist(w)));
                        }
                    }
                }
            }
        }
    }
    println!("uncorrelated order 1 vs F·D·G1(ω_i)·G1(ω_o)/(4 cos θ_i): max rel dev {worst_unc:.3e}");
    println!("correlated order 1 vs F·D·G2/(4 cos θ_i), G2 = 1/(1+Λ_i+Λ_o): max rel dev {worst_cor:.3e}");
    println!("single vs uncorrelated order 1, GGX: max rel dev {worst_single_ggx:.3e}");
    println!("single vs uncorrelated order 1, Beckmann (Mitsuba's rational G1): max rel dev {worst_single_beck:.3e}");
    println!("Mitsuba's rational Beckmann G1 vs exact G1: max rel dev {worst_g1_beck:.3e}");
    ck.assert(&format!("uncorrelated order 1 = Walter G1·G1 ({worst_unc:.2e} ≤ 1e-12)"), worst_unc <= 1e-12);
    ck.assert(&format!("correlated order 1 = Walter G2 ({worst_cor:.2e} ≤ 1e-12)"), worst_cor <= 1e-12);
    ck.assert(&format!("single = uncorrelated order 1 for GGX ({worst_single_ggx:.2e} ≤ 1e-12)"), worst_single_ggx <= 1e-12);
    // Walter 2007: the rational G1 is within 0.35 % of the exact one; the product of two.
    let bound = 1.0035f64.powi(2) - 1.0;
    ck.assert(&format!("single ≈ uncorrelated order 1 for Beckmann ({worst_single_beck:.2e} ≤ {bound:.4})"), worst_single_beck <= bound);
    ck.assert(&format!("rational Beckmann G1 within 0.35 % ({worst_g1_beck:.2e})"), worst_g1_beck <= 0.0035);
    ck.finish();
}

// ---------------------------------------------------------------------------
// Reciprocity: f(ω_i, ω_o) = f(ω_o, ω_i), i.e. eval(ω_i,ω_o)/cos θ_o = eval(ω_o,ω_i)/cos θ_i.

#[test]
fn reciprocity() {
    let mut ck = Checker::new("reciprocity (uncorrelated asserted, correlated measured)");
    let n = 150_000u64;
    let pairs = [(0.3, 0.0, 1.0, 2.0), (1.2, 0.5, 0.4, 3.0), (1.4, 0.0, 1.4, PI), (0.8, 1.0, 1.3, 1.2)];
    let alphas = [(0.5, 0.5), (1.0, 1.0), (0.3, 0.9)];
    let mut table = Vec::new();
    let mut heavy_count = 0;
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        for model in [Model::Uncorrelated, Model::Correlated] {
            let b = bsdf(dist, model);
            for &(ax, ay) in &alphas {
                let mat = Material { alpha_u: ax, alpha_v: ay, ..Material::mirror(ax) };
                for &(ti, pi, to, po) in &pairs {
                    let wi = dir(ti, pi);
                    let wo = dir(to, po);
                    let mut fwd = Stat::default();
                    let mut bwd = Stat::default();
                    let mut diff = Stat::default();
                    // Deterministic single-scattering part (reciprocal by construction): the walk of
                    // eval_orders(1, ·) draws the same numbers, so eval − order 1 is its multiple-scattering part.
                    let s1 = b.eval_orders(&mat, wi, wo, 0, (1, 1)).0[0] / wo.z;
                    let s2 = b.eval_orders(&mat, wo, wi, 0, (1, 1)).0[0] / wi.z;
                    let (mut max_f, mut sum_f, mut max_b, mut sum_b) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
                    for key in 0..n {
                        let a = b.eval(&mat, wi, wo, key).0[0] / wo.z;
                        let c = b.eval(&mat, wo, wi, key).0[0] / wi.z;
                        fwd.push(a);
                        bwd.push(c);
                        diff.push(a - c);
                        max_f = max_f.max(a - s1);
                        sum_f += a - s1;
                        max_b = max_b.max(c - s2);
                        sum_b += c - s2;
                    }
                    // Heavy-tail diagnostic: when one path carries more than 1 % of the
                    // multiple-scattering sum, the estimator has not reached its CLT regime
                    // and its sample σ is unreliable.
                    let tail = (max_f / sum_f).max(max_b / sum_b);
                    // Relevance: where multiple scattering is < 1 % of f the check is dominated by
                    // the (exactly reciprocal, deterministic) single-scattering part, and the PT
                    // estimate of the tiny remainder is the rare-path case described in the report
                    // (Beckmann, θ_i = 0.8 → θ_o = 1.3 forward: an independent quadrature of order 2
                    // is reciprocal to 1 %, while the PT estimate from the ω_i side misses its rare paths).
                    let ms_fraction = ((fwd.mean() - s1) / fwd.mean()).max((bwd.mean() - s2) / bwd.mean());
                    let heavy = !(tail <= 0.01) || !(ms_fraction >= 0.01);
                    let tag = format!("{dist:?} {model:?} α=({ax},{ay}) θ_i={ti} φ_i={pi:.2} θ_o={to} φ_o={po:.2}");
                    let (fm, fs) = fwd.est();
                    let (bm, bs) = bwd.est();
                    let ratio = fm / bm;
                    let ratio_se = ratio * ((fs / fm).powi(2) + (bs / bm).powi(2)).sqrt();
                    let (mf_, mb_) = (fm - s1, bm - s2);
                    let mratio = mf_ / mb_;
                    let mratio_se = mratio.abs() * ((fs / mf_).powi(2) + (bs / mb_).powi(2)).sqrt();
                    println!(
                        "{tag}: f(i,o) = {fm:.5e} ± {fs:.1e}, f(o,i) = {bm:.5e} ± {bs:.1e}, ratio − 1 = {:+.4} ± {:.4}; multiple-scattering part ratio − 1 = {:+.4} ± {:.4}",
                        ratio - 1.0,
                        ratio_se,
                        mratio - 1.0,
                        mratio_se
                    );
                    ck.assert(&format!("{tag}: single-scattering part reciprocal"), (s1 - s2).abs() <= 1e-12 * s1.abs().max(s2.abs()));
                    if heavy {
                        println!(
                            "{tag}: largest single path = {:.1} % of the multiple-scattering sum, multiple scattering = {:.2} % of f: heavy-tailed or irrelevant, not asserted",
                            100.0 * tail,
                            100.0 * ms_fraction
                        );
                        heavy_count += 1;
                    }
                    if model == Model::Uncorrelated && !heavy {
                        // Paired difference (same keys): its standard error is the σ of the difference of means.
                        ck.close(&format!("{tag}: f(i,o) − f(o,i) = 0"), diff.est(), exact(0.0), 0.0, 0.0);
                    } else {
                        table.push((tag, ratio - 1.0, ratio_se, mratio - 1.0, mratio_se));
                    }
                }
            }
        }
    }
    println!("{heavy_count} configurations not asserted (heavy-tailed or multiple scattering < 1 % of f)");
    println!("correlated model non-reciprocity, f(ω_i,ω_o)/f(ω_o,ω_i) − 1 (full; multiple-scattering part only):");
    for (t, r, rs, m, ms) in &table {
        println!("  {t}: {r:+.4} ± {rs:.4}; {m:+.4} ± {ms:.4}");
    }
    ck.finish();
}

// ---------------------------------------------------------------------------
// Heitz §4.4.4: moments of sampled directions vs the integral of eval.

fn sampled_moments(model: Model, seed: u64) {
    let mut ck = Checker::new(&format!("sampled-direction moments (Heitz §4.4.4), {model:?}"));
    let n_int = 500_000;
    let n_smp = 500_000;
    let names = ["1", "x", "y", "z", "z²", "x²"];
    let mut rng = Sampler::new(seed);
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        let b = bsdf(dist, model);
        for &alpha in &[0.3, 1.0] {
            for &theta in &[0.3, 1.2] {
                let mat = Material::mirror(alpha);
                let wi = dir(theta, 0.7);
                let mut prop = HemisphereOutProposal::new(alpha, alpha, wi);
                prop.k = alpha.clamp(0.02, 0.8);
                let g = |w: DVec3| [1.0, w.x, w.y, w.z, w.z * w.z, w.x * w.x];
                let mut s_int = [Stat::default(); 6];
                for i in 0..n_int {
                    let wo = prop.sample(&mut rng);
                    let v = if wo.z > 0.0 { b.eval(&mat, wi, wo, i as u64).0[0] / prop.pdf(wo) } else { 0.0 };
                    let gv = g(wo);
                    for k in 0..6 {
                        s_int[k].push(gv[k] * v);
                    }
                }
                let mut s_smp = [Stat::default(); 6];
                for _ in 0..n_smp {
                    let s1 = rng.next();
                    let u = rng.next2();
                    let (w, wo) = match b.sample(&mat, wi, s1, u) {
                        Some(s) => (s.weight.0[0], s.wo),
                        None => (0.0, DVec3::Z),
                    };
                    let gv = g(wo);
                    for k in 0..6 {
                        s_smp[k].push(gv[k] * w);
                    }
                }
                for k in 0..6 {
                    ck.close(
                        &format!("{dist:?} {model:?} α={alpha} θ_i={theta}: E[w·{}] sampled vs ∫eval·{}", names[k], names[k]),
                        s_smp[k].est(),
                        s_int[k].est(),
                        0.0,
                        0.0,
                    );
                }
            }
        }
    }
    ck.finish();
}

#[test]
fn sampled_moments_uncorrelated() {
    sampled_moments(Model::Uncorrelated, 41);
}

#[test]
fn sampled_moments_correlated() {
    sampled_moments(Model::Correlated, 42);
}

// ---------------------------------------------------------------------------
// Per-bounce energy (printed for the notes).

#[test]
fn per_bounce_energy() {
    let n = 150_000;
    let mut rng = Sampler::new(51);
    let wi = DVec3::Z;
    println!("albedo by scattering order, GGX, θ_i = 0, perfect mirror (mean ± σ):");
    println!("{:<13} {:>5} {:>18} {:>18} {:>18} {:>18} {:>18}", "model", "α", "order 1", "order 2", "order 3", "orders 4+", "total");
    for model in [Model::Uncorrelated, Model::Correlated] {
        let b = bsdf(Distribution::Ggx, model);
        for &alpha in &[0.3, 1.0, 1.5] {
            let mat = Material::mirror(alpha);
            let prop = VndfOutProposal::new(Microfacet::new(Distribution::Ggx, alpha, alpha), wi, alpha.clamp(0.02, 0.8));
            let mut s = [Stat::default(); 5];
            for i in 0..n {
                let wo = prop.sample(&mut rng);
                let q = prop.pdf(wo);
                let mut vals = [0.0; 5];
                if wo.z > 0.0 {
                    for (k, o) in [(1, 1), (2, 2), (3, 3), (4, u32::MAX)].iter().enumerate() {
                        vals[k] = b.eval_orders(&mat, wi, wo, i as u64, *o).0[0] / q;
                    }
                    vals[4] = vals[..4].iter().sum();
                }
                for k in 0..5 {
                    s[k].push(vals[k]);
                }
            }
            let f = |st: &Stat| format!("{:.5} ± {:.5}", st.mean(), st.se());
            println!(
                "{:<13} {:>5} {:>18} {:>18} {:>18} {:>18} {:>18}",
                format!("{model:?}"),
                alpha,
                f(&s[0]),
                f(&s[1]),
                f(&s[2]),
                f(&s[3]),
                f(&s[4])
            );
        }
    }
    // Energy beyond the default bounce cap at α = 1.5.
    println!("energy above the default cap ({} bounces), GGX α = 1.5, θ_i = 0:", msx::config::DEFAULT_MAX_BOUNCES);
    for model in [Model::Uncorrelated, Model::Correlated] {
        let b = Bsdf::new(Config { distribution: Distribution::Ggx, model, max_bounces: 1024, ..Config::default() }).unwrap();
        let b_def = bsdf(Distribution::Ggx, model);
        let alpha = 1.5;
        let mat = Material::mirror(alpha);
        let prop = VndfOutProposal::new(Microfacet::new(Distribution::Ggx, alpha, alpha), wi, 0.8);
        let mut s = Stat::default();
        for i in 0..n {
            let wo = prop.sample(&mut rng);
            s.push(if wo.z > 0.0 {
                b.eval_orders(&mat, wi, wo, i as u64, (msx::config::DEFAULT_MAX_BOUNCES + 1, 1024)).0[0] / prop.pdf(wo)
            } else {
                0.0
            });
        }
        // Random-walk sampler: fraction of walks that hit the cap (weight 1 each for a mirror).
        let mut lost = Stat::default();
        for _ in 0..4 * n {
            let s1 = rng.next();
            let u = rng.next2();
            lost.push(if b_def.sample(&mat, wi, s1, u).is_some() { 0.0 } else { 1.0 });
        }
        println!(
            "  {model:?}: eval orders 65..1024 = {:.3e} ± {:.1e} ({n} paths); sample() walks failing at the default cap: {} of {} (95 % upper bound on the lost energy {:.1e})",
            s.mean(),
            s.se(),
            (lost.mean() * lost.n as f64).round(),
            lost.n,
            if lost.mean() == 0.0 { 3.0 / lost.n as f64 } else { lost.mean() + 2.0 * lost.se() }
        );
    }
}

// ---------------------------------------------------------------------------
// pdf / sample consistency.

#[test]
fn pdf_sample_consistency() {
    let mut ck = Checker::new("pdf/sample consistency of the multiple-scattering models");
    let mut rng = Sampler::new(61);
    let n_int = 200_000;
    for model in [Model::Uncorrelated, Model::Correlated] {
        for dist in [Distribution::Ggx, Distribution::Beckmann] {
            let b = bsdf(dist, model);
            for &alpha in &[0.1, 0.5, 1.5] {
                for &theta in &[0.0, 1.0, 1.45] {
                    let mat = Material::mirror(alpha);
                    let wi = dir(theta, 0.4);
                    let tag = format!("{model:?} {dist:?} α={alpha} θ_i={theta}");
                    // sample().pdf is exactly pdf(wi, wo).
                    let mut mismatches = 0;
                    for _ in 0..2000 {
                        let s1 = rng.next();
                        let u = rng.next2();
                        if let Some(s) = b.sample(&mat, wi, s1, u) {
                            if s.pdf.to_bits() != b.pdf(&mat, wi, s.wo).to_bits() {
                                mismatches += 1;
                            }
                        }
                    }
                    ck.assert(&format!("{tag}: sample().pdf == pdf() ({mismatches} mismatches)"), mismatches == 0);
                    // ∫_H² pdf dω_o, with an independent proposal.
                    let mut prop = HemisphereOutProposal::new(alpha, alpha, wi);
                    prop.k = 0.5;
                    let mut s_int = Stat::default();
                    for _ in 0..n_int {
                        let wo = prop.sample(&mut rng);
                        s_int.push(if wo.z > 0.0 { b.pdf(&mat, wi, wo) / prop.pdf(wo) } else { 0.0 });
                    }
                    // Expected: E_1 (the order-1 exit density integrates to the order-1
                    // albedo, estimated here by Monte Carlo over visible normals) plus the
                    // cosine lobe's mass max(1 − E_1,table, 1e-3). With an exact table that is
                    // 1; the table is bilinear in (μ², √α): 1 % interpolation allowance.
                    let mf = Microfacet::new(dist, alpha, alpha);
                    let l0 = 1.0 + mf.lambda(wi);
                    let mut e1 = Stat::default();
                    for _ in 0..n_int {
                        let (u1, u2) = rng.next2();
                        let v = mf
                            .sample_visible(wi, u1, u2)
                            .map(|m| msx::microfacet::reflect(wi, m))
                            .filter(|wo| wo.z > 0.0)
                            .map(|wo| {
                                let lo = mf.lambda(wo);
                                if model == Model::Uncorrelated {
                                    1.0 / (1.0 + lo)
                                } else {
                                    l0 / (l0 + lo)
                                }
                            })
                            .unwrap_or(0.0);
                        e1.push(v);
                    }
                    let table = msx::tables::albedo::AlbedoTable::get(dist);
                    let e1_table = if model == Model::Uncorrelated { table.e1_uncorrelated(alpha, wi.z) } else { table.e1_correlated(alpha, wi.z) };
                    let expected = (e1.mean() + (1.0 - e1_table).max(1e-3), e1.se());
                    println!(
                        "{tag}: ∫pdf dω_o over the hemisphere = {:.5} ± {:.5} (order-1 albedo {:.5} MC, {e1_table:.5} table)",
                        s_int.mean(),
                        s_int.se(),
                        e1.mean()
                    );
                    ck.close(&format!("{tag}: ∫pdf = E_1 + (1 − E_1,table)"), s_int.est(), expected, 0.0, 0.0);
                    ck.close(&format!("{tag}: ∫pdf ≈ 1"), s_int.est(), (1.0, 0.0), 0.01, 0.0);
                }
            }
        }
    }
    ck.finish();
}
