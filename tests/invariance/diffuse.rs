//! The invariance-principle model (Cui et al. 2023) on the diffuse
//! microsurface (`models::invariance::general`): the incremental complete
//! recursion against `invariance::segment_term`, furnace, equality in
//! expectation with Heitz's random walk (albedo, energy per order, f at fixed
//! pairs), reciprocity, sampled moments = eval integration, and variance /
//! time per call against Heitz.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

use crate::common::*;
use glam::DVec3;
use msx::microfacet::Microsurface;
use msx::models::invariance;
use msx::models::invariance::general as ig;
use msx::rng::Sampler;
use msx::walk::{height, WalkOptions};
use msx::{Distribution, Microfacet, Spectrum};
use std::f64::consts::PI;
use std::time::Instant;

const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];
const MAXB: u32 = 1024;

fn opts(max_bounces: u32, orders: (u32, u32)) -> WalkOptions {
    WalkOptions { max_bounces, orders }
}

fn all_orders() -> WalkOptions {
    opts(MAXB, (1, MAXB))
}

fn diffuse(a: f64) -> Microsurface {
    Microsurface::Diffuse { albedo: Spectrum([a, a, a, 1.0]) }
}

fn random_dir(rng: &mut Sampler, up: bool) -> DVec3 {
    let theta = if rng.next() < 1.0 / 3.0 { 0.35 * rng.next() } else { rng.next().acos() };
    let d = dir(theta.clamp(1e-3, PI / 2.0 - 1e-3), 2.0 * PI * rng.next());
    if up {
        d
    } else {
        DVec3::new(d.x, d.y, -d.z)
    }
}

/// The incremental table equals (Π|Λ|)·S_k of the complete O(k³) recursion on
/// every up/down pattern (k ≤ 8), and a downward direction hits for sure
/// (continuation ratio 1).
#[test]
fn exit_table_matches_complete_recursion() {
    let mut ck = Checker::new("ExitTable = (Π|Λ|)·segment_term (complete recursion), all patterns");
    let mut rng = Sampler::new(11);
    let mut worst = 0.0f64;
    let mut worst_cont = 0.0f64;
    let mut cases = 0;
    for dist in DISTS {
        for &(ax, ay) in &[(0.1, 0.1), (0.5, 0.5), (1.0, 1.0), (2.0, 2.0), (0.3, 0.9)] {
            let mf = Microfacet::new(dist, ax, ay);
            for k in 1..=8usize {
                for pattern in 0..(1u32 << (k - 1)) {
                    for _ in 0..4 {
                        let mut dirs = vec![random_dir(&mut rng, false)];
                        for i in 1..k {
                            dirs.push(random_dir(&mut rng, (pattern >> (i - 1)) & 1 == 1));
                        }
                        dirs.push(random_dir(&mut rng, true));
                        let pl: f64 = dirs[..k].iter().map(|&d| mf.abs_lambda(d)).product();
                        let reference = pl * invariance::segment_term(&mf, &dirs);
                        let got = ig::p_exit_incremental(&mf, &dirs);
                        let r = (got - reference).abs() / reference.abs().max(1e-300);
                        if reference > 1e-300 {
                            worst = worst.max(r);
                        }
                        ck.assert(
                            &format!("{dist:?} α=({ax},{ay}) k={k} pattern={pattern:b}: {got} vs {reference}"),
                            got.is_finite() && (reference == 0.0 && got == 0.0 || r < 1e-10),
                        );
                        ck.assert("p_exit ≤ 1", got <= 1.0 + 1e-12);
                        // Continuation of downward directions is 1.
                        let mut t = ig::ExitTable::new(mf.abs_lambda(dirs[0]));
                        for &d in &dirs[1..k] {
                            let h_before = t.hit_probability();
                            let c = t.push(mf.abs_lambda(d), d.z < 0.0);
                            // (H = 0 after an upward direction with Λ = 0 in double
                            // precision: nothing hits any more, continuation 0.)
                            if d.z < 0.0 && h_before > 0.0 && (c - 1.0).abs() > 1e-10 {
                                println!("downward continuation {c} (H = {}) {dist:?} α=({ax},{ay}) {dirs:?}", t.hit_probability());
                                worst_cont = worst_cont.max((c - 1.0).abs());
                            }
                            ck.assert("continuation in [0,1]", (0.0..=1.0 + 1e-12).contains(&c));
                        }
                        cases += 1;
                    }
                }
            }
        }
    }
    println!("{cases} sequences: max rel err {worst:.2e}; max |continuation − 1| at downward directions {worst_cont:.2e}");
    ck.assert("downward continuation = 1", worst_cont < 1e-10);
    ck.finish();
}

/// ∫ eval(ω_i, ω_o) g(ω_o) dω_o with cosine-weighted ω_o, channel 0.
fn eval_integral(f: &dyn Fn(DVec3, DVec3, &mut Sampler) -> Spectrum, wi: DVec3, n: usize, seed: u64, g: &dyn Fn(DVec3) -> f64) -> (f64, f64) {
    let mut rng = Sampler::new(seed);
    let mut walk = Sampler::new(seed ^ 0x5eed);
    let mut st = Stat::default();
    for _ in 0..n {
        let (u1, u2) = rng.next2();
        let wo = cosine_hemisphere(u1, u2);
        if !(wo.z > 0.0) {
            st.push(0.0);
            continue;
        }
        let v = f(wi, wo, &mut walk);
        st.push(v.0[0] * g(wo) * PI / wo.z);
    }
    st.est()
}

fn inv_eval(mf: Microfacet, s: Microsurface, o: WalkOptions) -> impl Fn(DVec3, DVec3, &mut Sampler) -> Spectrum {
    move |wi, wo, rng| ig::eval(&mf, &s, wi, wo, &o, rng)
}

fn heitz_eval(mf: Microfacet, s: Microsurface, o: WalkOptions) -> impl Fn(DVec3, DVec3, &mut Sampler) -> Spectrum {
    move |wi, wo, rng| height::eval(&mf, &s, wi, wo, &o, rng)
}

fn sample_mean(mf: Microfacet, s: Microsurface, wi: DVec3, o: WalkOptions, n: usize, seed: u64, g: &dyn Fn(DVec3) -> f64) -> (f64, f64) {
    let mut rng = Sampler::new(seed);
    let mut st = Stat::default();
    for _ in 0..n {
        let first = (rng.next(), rng.next(), rng.next());
        match ig::sample(&mf, &s, wi, first, &o, &mut rng) {
            Some((wo, w, _)) => st.push(w.0[0] * g(wo)),
            None => st.push(0.0),
        }
    }
    st.est()
}

fn point(f: &dyn Fn(DVec3, DVec3, &mut Sampler) -> Spectrum, wi: DVec3, wo: DVec3, n: usize, seed: u64) -> (f64, f64) {
    let mut rng = Sampler::new(seed);
    let mut st = Stat::default();
    for _ in 0..n {
        st.push(f(wi, wo, &mut rng).0[0]);
    }
    st.est()
}

#[test]
fn conductor_and_dielectric_are_not_handled() {
    let mut ck = Checker::new("conductor / dielectric → zero / None");
    let mf = Microfacet::new(Distribution::Ggx, 0.5, 0.5);
    let mut rng = Sampler::new(1);
    let (wi, wo) = (dir(0.5, 0.0), dir(0.7, 2.0));
    let cond = Microsurface::Conductor(msx::microfacet::ConductorFresnel::new(Spectrum::splat(0.0), Spectrum::splat(1.0), 3));
    let diel = Microsurface::Dielectric { eta: 1.5, radiance: false };
    for s in [cond, diel] {
        ck.assert("eval zero", ig::eval(&mf, &s, wi, wo, &all_orders(), &mut rng).max_value() == 0.0);
        ck.assert("sample None", ig::sample(&mf, &s, wi, (0.5, 0.5, 0.5), &all_orders(), &mut rng).is_none());
    }
    ck.finish();
}

#[test]
fn furnace() {
    let mut ck = Checker::new("diffuse furnace (albedo 1): eval integration and mean sample weight = 1 within 3σ + 0.3 %");
    let one = |_: DVec3| 1.0;
    let s = diffuse(1.0);
    let mut seed = 100;
    for dist in DISTS {
        for alpha in [0.5, 1.0, 2.0] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for theta in [0.0, 1.0] {
                let wi = dir(theta, 0.3);
                seed += 1;
                let e = eval_integral(&inv_eval(mf, s, all_orders()), wi, 150_000, seed, &one);
                ck.close(&format!("{dist:?} α={alpha} θi={theta} eval ∫"), e, exact(1.0), 0.003, 0.0);
                let m = sample_mean(mf, s, wi, all_orders(), 150_000, seed + 1000, &one);
                ck.close(&format!("{dist:?} α={alpha} θi={theta} sample mean weight"), m, exact(1.0), 0.003, 0.0);
            }
        }
    }
    ck.finish();
}

/// Invariance == Heitz in expectation: albedo, energy of orders 1, 2, 3, 4+ and
/// f·cos at three fixed pairs (albedo 0.8).
#[test]
fn heitz_agreement() {
    let mut ck = Checker::new("diffuse invariance == Heitz random walk (albedo 0.8)");
    let one = |_: DVec3| 1.0;
    let s = diffuse(0.8);
    let mut seed = 500;
    let configs =
        [(Distribution::Ggx, 0.5, 1.0), (Distribution::Ggx, 1.0, 0.4), (Distribution::Beckmann, 1.0, 1.0), (Distribution::Beckmann, 2.0, 0.2)];
    for &(dist, alpha, theta) in &configs {
        let mf = Microfacet::new(dist, alpha, alpha);
        let wi = dir(theta, 0.0);
        for (name, o, n) in [
            ("albedo", all_orders(), 120_000),
            ("order 1", opts(MAXB, (1, 1)), 80_000),
            ("order 2", opts(MAXB, (2, 2)), 120_000),
            ("order 3", opts(MAXB, (3, 3)), 120_000),
            ("orders 4+", opts(MAXB, (4, MAXB)), 120_000),
        ] {
            seed += 2;
            let a = eval_integral(&inv_eval(mf, s, o), wi, n, seed, &one);
            let b = eval_integral(&heitz_eval(mf, s, o), wi, n, seed + 1, &one);
            ck.close(&format!("{dist:?} α={alpha} θi={theta} {name}: invariance vs heitz"), a, b, 0.0, 0.0);
        }
    }
    let pairs = [
        (Distribution::Ggx, 0.5, dir(0.3, 0.0), dir(0.8, 2.5)),
        (Distribution::Ggx, 1.0, dir(1.2, 0.0), dir(1.0, 0.2)),
        (Distribution::Beckmann, 1.0, dir(0.6, 0.0), dir(1.3, 3.0)),
    ];
    for &(dist, alpha, wi, wo) in &pairs {
        let mf = Microfacet::new(dist, alpha, alpha);
        seed += 2;
        let a = point(&inv_eval(mf, s, all_orders()), wi, wo, 400_000, seed);
        let b = point(&heitz_eval(mf, s, all_orders()), wi, wo, 400_000, seed + 1);
        ck.close(&format!("{dist:?} α={alpha} wi={wi:.2} wo={wo:.2} f·cos: invariance vs heitz"), a, b, 0.0, 0.0);
    }
    ck.finish();
}

/// f(ω_i, ω_o) = f(ω_o, ω_i): eval(ω_i, ω_o)/cos θ_o vs eval(ω_o, ω_i)/cos θ_i.
#[test]
fn reciprocity() {
    let mut ck = Checker::new("diffuse invariance reciprocity");
    let s = diffuse(0.9);
    let mut seed = 900;
    for dist in DISTS {
        for &(alpha, (ti, to, dphi)) in &[(0.5, (0.3, 1.1, 2.0)), (1.0, (0.9, 0.2, 0.5)), (2.0, (1.3, 0.6, 3.0))] {
            let mf = Microfacet::new(dist, alpha, alpha);
            let (wi, wo) = (dir(ti, 0.0), dir(to, dphi));
            for (name, o) in [("all", all_orders()), ("order 2", opts(MAXB, (2, 2))), ("orders 3+", opts(MAXB, (3, MAXB)))] {
                seed += 2;
                let a = point(&inv_eval(mf, s, o), wi, wo, 200_000, seed);
                let b = point(&inv_eval(mf, s, o), wo, wi, 200_000, seed + 1);
                ck.close(
                    &format!("{dist:?} α={alpha} θi={ti} θo={to} {name}: f(i,o) vs f(o,i)"),
                    (a.0 / wo.z, a.1 / wo.z),
                    (b.0 / wi.z, b.1 / wi.z),
                    0.0,
                    0.0,
                );
            }
        }
    }
    ck.finish();
}

/// E[weight·g(ω_o)] of `sample` = ∫ g·eval for several g and order ranges.
#[test]
fn sampled_moments_match_eval() {
    let mut ck = Checker::new("diffuse invariance: sampled moments = eval integration");
    let s = diffuse(0.8);
    let gs: [(&str, &dyn Fn(DVec3) -> f64); 3] = [("1", &|_| 1.0), ("z", &|w: DVec3| w.z), ("x", &|w: DVec3| w.x)];
    let mut seed = 1300;
    for &(dist, alpha, theta) in &[(Distribution::Ggx, 0.5, 1.0), (Distribution::Beckmann, 1.0, 0.5), (Distribution::Ggx, 2.0, 0.0)] {
        let mf = Microfacet::new(dist, alpha, alpha);
        let wi = dir(theta, 0.0);
        for (oname, o) in [("all", all_orders()), ("orders 2–3", opts(MAXB, (2, 3))), ("max_bounces 2", opts(2, (1, MAXB)))] {
            for (gname, g) in gs.iter() {
                seed += 2;
                let a = sample_mean(mf, s, wi, o, 120_000, seed, *g);
                let b = eval_integral(&inv_eval(mf, s, o), wi, 120_000, seed + 1, *g);
                ck.close(&format!("{dist:?} α={alpha} θi={theta} {oname} g={gname}: sample vs eval"), a, b, 0.0, 0.0);
            }
        }
    }
    ck.finish();
}

/// Variance and ns per eval call at off-specular pairs, invariance vs Heitz
/// (printed; efficiency = 1/(variance·time)).
#[test]
fn variance_and_time_per_call() {
    let mut ck = Checker::new("diffuse: variance and ns per call vs heitz (printed)");
    let s = diffuse(0.8);
    let cases = [
        (Distribution::Ggx, 0.5, (0.8, 0.0), (0.6, 2.5)),
        (Distribution::Ggx, 1.0, (0.3, 0.0), (1.2, 2.0)),
        (Distribution::Beckmann, 1.0, (0.8, 0.0), (0.6, 2.5)),
    ];
    for &(dist, alpha, (ti, pi), (to, po)) in &cases {
        let mf = Microfacet::new(dist, alpha, alpha);
        let (wi, wo) = (dir(ti, pi), dir(to, po));
        let o = opts(64, (1, 64));
        let fs: [&dyn Fn(&mut Sampler) -> Spectrum; 2] = [&|r| ig::eval(&mf, &s, wi, wo, &o, r), &|r| height::eval(&mf, &s, wi, wo, &o, r)];
        let mut rngs = [Sampler::new(1), Sampler::new(2)];
        let mut stats = [Stat::default(); 2];
        let mut blocks: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
        let (n, block) = (60_000, 2000);
        for _ in 0..n / block {
            for e in 0..2 {
                let t0 = Instant::now();
                let mut vals = [0.0f64; 2000];
                for v in vals.iter_mut() {
                    *v = fs[e](&mut rngs[e]).0[0];
                }
                blocks[e].push(t0.elapsed().as_nanos() as f64 / block as f64);
                std::hint::black_box(&vals);
                for v in vals {
                    stats[e].push(v);
                }
            }
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(|a, b| a.partial_cmp(b).unwrap());
            v[v.len() / 2]
        };
        let (t_i, t_h) = (median(&mut blocks[0]), median(&mut blocks[1]));
        let [si, sh] = stats;
        let eff = |s: &Stat, t: f64| 1.0 / (s.var().max(1e-300) * t);
        println!(
            "{dist:?} α={alpha} θi={ti} θo={to} Δφ={:.1}: invariance mean {:.5} var {:.3e} {t_i:.0} ns | heitz mean {:.5} var {:.3e} {t_h:.0} ns | variance ratio heitz/inv {:.2}, efficiency inv/heitz {:.2}",
            po - pi,
            si.mean(),
            si.var(),
            sh.mean(),
            sh.var(),
            sh.var() / si.var(),
            eff(&si, t_i) / eff(&sh, t_h)
        );
        ck.close(&format!("{dist:?} α={alpha}: invariance vs heitz mean"), si.est(), sh.est(), 0.0, 0.0);
    }
    ck.finish();
}
