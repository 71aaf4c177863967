//! The invariance model on the rough dielectric (`models::invariance::dielectric`):
//! the exact depth law of the first run against Cui's segment term and against
//! a brute-force height simulation, order 1 = Walter with the height-correlated
//! G2 (Beta form for transmission) exactly and with zero variance, the
//! furnace (E_r + E_t = 1), equality in expectation with Heitz's random walk
//! (albedo, E_r, orders 1, 2, 3, 4+, f at fixed pairs on both sides),
//! reciprocity with the η² factors, and sampled moments = eval integration.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

use crate::common::*;
use glam::DVec3;
use msx::microfacet::fresnel;
use msx::microfacet::Microsurface;
use msx::models::invariance;
use msx::models::invariance::dielectric::{self as idl, PieceChain};
use msx::rng::Sampler;
use msx::walk::{height, WalkOptions};
use msx::{Distribution, Microfacet};
use std::f64::consts::PI;

const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];
const MAXB: u32 = 1024;

fn opts(max_bounces: u32, orders: (u32, u32)) -> WalkOptions {
    WalkOptions { max_bounces, orders }
}

fn all_orders() -> WalkOptions {
    opts(MAXB, (1, MAXB))
}

/// A direction at polar angle θ from the normal of side `outside` (z < 0 inside).
fn side_dir(theta: f64, phi: f64, outside: bool) -> DVec3 {
    let w = dir(theta, phi);
    if outside {
        w
    } else {
        DVec3::new(w.x, w.y, -w.z)
    }
}

fn random_dir(rng: &mut Sampler, up: bool) -> DVec3 {
    let theta = if rng.next() < 0.3 { 0.3 * rng.next() } else { rng.next().acos() };
    let d = dir(theta.clamp(1e-3, PI / 2.0 - 1e-3), 2.0 * PI * rng.next());
    if up {
        d
    } else {
        DVec3::new(d.x, d.y, -d.z)
    }
}

/// A monotone sequence: `downs` ≥ 1 downward directions, then `ups` upward ones.
fn monotone(rng: &mut Sampler, downs: usize, ups: usize) -> Vec<DVec3> {
    let mut v = Vec::with_capacity(downs + ups);
    for i in 0..downs + ups {
        v.push(random_dir(rng, i >= downs));
    }
    v
}

fn chain_of(mf: &Microfacet, dirs: &[DVec3]) -> (PieceChain, Vec<f64>) {
    let mut ch = PieceChain::new(mf.abs_lambda(dirs[0]));
    let mut conts = Vec::new();
    for &d in &dirs[1..] {
        if d.z < 0.0 {
            assert!(ch.push_down(mf.abs_lambda(d)));
            conts.push(1.0);
        } else {
            conts.push(ch.push_up(mf.lambda(d)));
        }
    }
    (ch, conts)
}

/// H·E[e^{−Λ_x τ}] of the chain = (Π|Λ|)·S_k of Cui's complete recursion
/// (`invariance::segment_term`) on every monotone pattern up to k = 8, and the
/// continuation probabilities are the ratios of those hit probabilities.
#[test]
fn piece_chain_equals_segment_term() {
    let mut ck = Checker::new("PieceChain: H·exit = (Π|Λ|)·S_k, continuation = H_{m+1}/H_m (monotone runs)");
    let mut rng = Sampler::new(3);
    let mut worst = 0.0f64;
    let mut cases = 0;
    for dist in DISTS {
        for &(ax, ay) in &[(0.1, 0.1), (0.5, 0.5), (1.0, 1.0), (2.5, 2.5), (0.2, 0.9)] {
            let mf = Microfacet::new(dist, ax, ay);
            for downs in 1..=5usize {
                for ups in 0..=(8 - downs) {
                    for _ in 0..6 {
                        let dirs = monotone(&mut rng, downs, ups);
                        let x = random_dir(&mut rng, true);
                        let (ch, conts) = chain_of(&mf, &dirs);
                        let pl: f64 = dirs.iter().map(|&d| mf.abs_lambda(d)).product();
                        let mut seq = dirs.clone();
                        seq.push(x);
                        let reference = pl * invariance::segment_term(&mf, &seq);
                        let got = ch.hit_probability() * ch.exit_given_hits(mf.lambda(x));
                        let r = (got - reference).abs() / reference.max(1e-300);
                        if reference > 1e-280 {
                            worst = worst.max(r);
                        }
                        ck.assert(
                            &format!("{dist:?} α=({ax},{ay}) {downs}↓{ups}↑: {got:e} vs {reference:e}"),
                            got.is_finite() && (r < 1e-10 || reference < 1e-280),
                        );
                        // H_m from the segment term with a vertical last direction (Λ = 0).
                        let mut h_prev = 1.0;
                        for m in 1..dirs.len() {
                            let mut s = dirs[..=m].to_vec();
                            s.push(DVec3::Z);
                            let plm: f64 = dirs[..=m].iter().map(|&d| mf.abs_lambda(d)).product();
                            let h = plm * invariance::segment_term(&mf, &s);
                            if h_prev > 1e-200 {
                                let rc = (conts[m - 1] - h / h_prev).abs();
                                ck.assert(&format!("{dist:?} continuation {m} of {downs}↓{ups}↑: {} vs {}", conts[m - 1], h / h_prev), rc < 1e-10);
                            }
                            h_prev = h;
                        }
                        cases += 1;
                    }
                }
            }
        }
    }
    println!("{cases} sequences, max rel err {worst:.2e}");
    ck.finish();
}

/// Brute force: optical depth τ of the last vertex by simulating the heights
/// (downward jump +Exp(L), upward −Exp(Λ), rejected when τ ≤ 0 — i.e.
/// conditioned on every direction hitting). None when rejected.
fn simulate_depth(mf: &Microfacet, dirs: &[DVec3], rng: &mut Sampler) -> Option<f64> {
    let mut tau = 0.0;
    for &d in dirs {
        let e = -(1.0 - rng.next()).ln();
        if d.z < 0.0 {
            tau += e / mf.abs_lambda(d);
        } else {
            tau -= e / mf.lambda(d);
            if tau <= 0.0 {
                return None;
            }
        }
    }
    Some(tau)
}

/// The depth drawn by the chain has the law of the simulated heights given the
/// hits: E[τ], E[e^{−0.7τ}] and E[(1 − e^{−τ})^{Λ'}] (the refraction exit that
/// `transmit_exit` estimates, top piece exact) agree with the brute force.
#[test]
fn depth_law_matches_height_simulation() {
    let mut ck = Checker::new("PieceChain depth law = simulated heights given the hits");
    let mut rng = Sampler::new(17);
    let n = 60_000;
    for (k, &(dist, alpha, downs, ups)) in [
        (Distribution::Ggx, 0.5, 1, 0),
        (Distribution::Ggx, 1.0, 2, 1),
        (Distribution::Beckmann, 0.8, 1, 2),
        (Distribution::Ggx, 2.0, 3, 2),
        (Distribution::Beckmann, 1.5, 2, 3),
    ]
    .iter()
    .enumerate()
    {
        let mf = Microfacet::new(dist, alpha, alpha);
        // A sequence whose hit probability keeps the rejection sampler cheap.
        let (dirs, ch) = loop {
            let dirs = monotone(&mut rng, downs, ups);
            let (ch, _) = chain_of(&mf, &dirs);
            if ch.hit_probability() > 0.05 {
                break (dirs, ch);
            }
        };
        println!("{dist:?} α={alpha} {downs}↓{ups}↑: hit probability {:.3}", ch.hit_probability());
        let lt = mf.lambda(random_dir(&mut rng, true));
        let mut sim_rng = Sampler::new(1000 + k as u64);
        let mut chain_rng = Sampler::new(2000 + k as u64);
        let (mut s_tau, mut s_exp, mut s_tr) = (Stat::default(), Stat::default(), Stat::default());
        let (mut c_tau, mut c_exp, mut c_tr) = (Stat::default(), Stat::default(), Stat::default());
        let mut accepted = 0usize;
        while accepted < n {
            if let Some(t) = simulate_depth(&mf, &dirs, &mut sim_rng) {
                accepted += 1;
                s_tau.push(t);
                s_exp.push((-0.7 * t).exp());
                s_tr.push((-(-t).exp_m1()).powf(lt));
            }
        }
        for _ in 0..n {
            let t = ch.sample_depth(&mut chain_rng);
            c_tau.push(t);
            c_exp.push((-0.7 * t).exp());
            c_tr.push(ch.transmit_exit(lt, &mut chain_rng));
        }
        let tag = format!("{dist:?} α={alpha} {downs}↓{ups}↑");
        ck.close(&format!("{tag} E[τ]"), c_tau.est(), s_tau.est(), 0.0, 0.0);
        ck.close(&format!("{tag} E[e^-0.7τ] sampled"), c_exp.est(), s_exp.est(), 0.0, 0.0);
        ck.close(&format!("{tag} E[e^-0.7τ] exact"), exact(ch.exit_given_hits(0.7)), s_exp.est(), 0.0, 0.0);
        ck.close(&format!("{tag} E[(1-e^-τ)^Λ'] transmit_exit (Λ'={lt:.3})"), c_tr.est(), s_tr.est(), 0.0, 0.0);
    }
    ck.finish();
}

/// Walter 2007 reflection/transmission with the height-correlated G2, written
/// here from the formulas (Ross 1/(1+Λ_i+Λ_o); transmission B(1+Λ_i, 1+Λ_o')),
/// in the local frame of ω_i's side; Importance mode.
fn walter_g2(mf: &Microfacet, eta: f64, wi: DVec3, wo: DVec3) -> f64 {
    let outside = wi.z > 0.0;
    let (wi_l, wo_l) = if outside { (wi, wo) } else { (-wi, -wo) };
    let e = if outside { eta } else { 1.0 / eta };
    if wo_l.z > 0.0 {
        walter_reflection(mf, wi_l, wo_l, |c| fresnel::dielectric(c, e))
    } else {
        // G2 = G1(ω_i)·P(exit | hit) = (1/L)·L·B(L, 1+Λ_o') = B(1+Λ_i, 1+Λ_o') (Pinel).
        let (l, lo) = (1.0 + mf.lambda(wi_l), mf.lambda(-wo_l));
        let g2 = (libm::lgamma(l) + libm::lgamma(1.0 + lo) - libm::lgamma(l + 1.0 + lo)).exp();
        walter_transmission(mf, wi_l, wo_l, e, g2)
    }
}

#[test]
fn order1_is_walter_with_beta_g2_exactly() {
    let mut ck = Checker::new("order 1 = Walter with height-correlated G2, deterministic");
    let mut rng = Sampler::new(5);
    let mut worst = 0.0f64;
    let o1 = opts(MAXB, (1, 1));
    for dist in DISTS {
        for &alpha in &[0.05, 0.3, 1.0, 2.0] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for &eta in &[1.1, 1.5, 2.4] {
                for _ in 0..60 {
                    let outside = rng.next() < 0.5;
                    let wi = side_dir(rng.next().acos().min(1.5), 0.0, outside);
                    let wo = side_dir(rng.next().acos().min(1.5), 2.0 * PI * rng.next(), rng.next() < 0.5);
                    let reference = walter_g2(&mf, eta, wi, wo);
                    let a = idl::eval(&mf, eta, false, wi, wo, &o1, &mut Sampler::new(1));
                    let b = idl::eval(&mf, eta, false, wi, wo, &o1, &mut Sampler::new(2));
                    let r = (a - reference).abs() / reference.abs().max(1e-300);
                    if reference > 1e-300 {
                        worst = worst.max(r);
                    }
                    ck.assert(
                        &format!("{dist:?} α={alpha} η={eta} wi={wi:.3} wo={wo:.3}: {a:e} vs {reference:e}"),
                        a == b && (r < 1e-11 || reference < 1e-300 && a < 1e-290),
                    );
                }
            }
        }
    }
    println!("max rel err {worst:.2e}");
    ck.finish();
}

/// ∫ eval(ω_i, ·) g dω with the dielectric proposal of tests/common.
#[allow(clippy::too_many_arguments)]
fn eval_integral(
    f: &dyn Fn(DVec3, DVec3, &mut Sampler) -> f64,
    mf: Microfacet,
    eta: f64,
    wi: DVec3,
    n: usize,
    seed: u64,
    g: &dyn Fn(DVec3) -> f64,
) -> (f64, f64) {
    let prop = DielectricProposal::new(mf, wi, eta);
    proposal_integral(n, seed, 0x5eed, |r| prop.sample(r), |w| prop.pdf(w), |wo, walk| f(wi, wo, walk) * g(wo))
}

fn inv(mf: Microfacet, eta: f64, radiance: bool, o: WalkOptions) -> impl Fn(DVec3, DVec3, &mut Sampler) -> f64 {
    move |wi, wo, rng| idl::eval(&mf, eta, radiance, wi, wo, &o, rng)
}

fn heitz_eval(mf: Microfacet, eta: f64, radiance: bool, o: WalkOptions) -> impl Fn(DVec3, DVec3, &mut Sampler) -> f64 {
    let s = Microsurface::Dielectric { eta, radiance };
    move |wi, wo, rng| height::eval(&mf, &s, wi, wo, &o, rng).0[0]
}

/// Mean of weight·g(ω_o) over `invariance_dielectric::sample`.
fn sample_mean(mf: Microfacet, eta: f64, wi: DVec3, o: WalkOptions, n: usize, seed: u64, g: &dyn Fn(DVec3) -> f64) -> (f64, f64) {
    let run = |seed: u64| {
        let mut rng = Sampler::new(seed);
        let mut st = Stat::default();
        for _ in 0..n {
            let first = (rng.next(), rng.next(), rng.next());
            match idl::sample(&mf, eta, false, wi, first, &o, &mut rng) {
                Some((wo, w, _)) => {
                    assert!(wo.is_finite() && (wo.length() - 1.0).abs() < 1e-9 && w == 1.0, "sample {wo:?} weight {w}");
                    st.push(w * g(wo));
                }
                None => st.push(0.0),
            }
        }
        st
    };
    let seed = seed + seed_offset();
    replicate_est(&run(seed), &run(seed ^ REPLICATE_SALT))
}

fn point(f: &dyn Fn(DVec3, DVec3, &mut Sampler) -> f64, wi: DVec3, wo: DVec3, n: usize, seed: u64) -> (f64, f64) {
    let run = |seed: u64| {
        let mut rng = Sampler::new(seed);
        let mut st = Stat::default();
        for _ in 0..n {
            st.push(f(wi, wo, &mut rng));
        }
        st
    };
    let seed = seed + seed_offset();
    replicate_est(&run(seed), &run(seed ^ REPLICATE_SALT))
}

/// E_r + E_t = 1 (Importance mode: the phase functions conserve energy) by eval
/// integration and by the mean sample weight, outside and inside (η < 1 seen
/// from ω_i, total internal reflection), GGX and Beckmann, α 0.1 … 2, θ_i up to 1.45.
#[test]
fn furnace() {
    let mut ck = Checker::new("dielectric invariance furnace: E_r + E_t = 1 within 3σ + 0.3 %");
    let mut seed = 100;
    let n = 25_000;
    for &eta in &[1.1, 1.5, 2.4] {
        for outside in [true, false] {
            for dist in DISTS {
                for &alpha in &[0.1, 0.5, 1.0, 2.0] {
                    for &theta in &[0.3, 1.45] {
                        seed += 4;
                        let mf = Microfacet::new(dist, alpha, alpha);
                        let wi = side_dir(theta, 0.7, outside);
                        let tag = format!("η={eta} {} {dist:?} α={alpha} θi={theta}", if outside { "outside" } else { "inside" });
                        let e = eval_integral(&inv(mf, eta, false, all_orders()), mf, eta, wi, n, seed, &|_| 1.0);
                        ck.close(&format!("{tag} E_r+E_t (eval)"), e, exact(1.0), 0.003, 0.0);
                        let s = sample_mean(mf, eta, wi, all_orders(), n, seed + 1, &|_| 1.0);
                        ck.close(&format!("{tag} E_r+E_t (sample)"), s, exact(1.0), 0.003, 0.0);
                    }
                }
            }
        }
    }
    ck.finish();
}

/// Invariance == Heitz in expectation: albedo, reflected energy, energy of
/// orders 1, 2, 3, 4+, and f·|cos θ_o| at fixed pairs on both sides.
#[test]
fn heitz_agreement() {
    let mut ck = Checker::new("dielectric invariance == Heitz random walk");
    let mut seed = 500;
    let same_side = |wi: DVec3| move |w: DVec3| ((w.z > 0.0) == (wi.z > 0.0)) as u8 as f64;
    let configs = [
        (Distribution::Ggx, 0.5, 1.5, side_dir(0.8, 0.0, true)),
        (Distribution::Ggx, 1.0, 1.5, side_dir(0.3, 0.0, false)),
        (Distribution::Beckmann, 1.0, 2.4, side_dir(1.2, 0.0, true)),
        (Distribution::Beckmann, 2.0, 1.3, side_dir(0.6, 0.0, false)),
    ];
    for &(dist, alpha, eta, wi) in &configs {
        let mf = Microfacet::new(dist, alpha, alpha);
        let tag = format!("{dist:?} α={alpha} η={eta} wi.z={:.2}", wi.z);
        let same = same_side(wi);
        for (name, o, g, n) in [
            ("albedo", all_orders(), None, 60_000),
            ("E_r", all_orders(), Some(&same as &dyn Fn(DVec3) -> f64), 60_000),
            ("order 1", opts(MAXB, (1, 1)), None, 30_000),
            ("order 2", opts(MAXB, (2, 2)), None, 60_000),
            ("order 3", opts(MAXB, (3, 3)), None, 60_000),
            ("orders 4+", opts(MAXB, (4, MAXB)), None, 60_000),
        ] {
            seed += 2;
            let one = |_: DVec3| 1.0;
            let g: &dyn Fn(DVec3) -> f64 = g.unwrap_or(&one);
            let a = eval_integral(&inv(mf, eta, false, o), mf, eta, wi, n, seed, g);
            let b = eval_integral(&heitz_eval(mf, eta, false, o), mf, eta, wi, n, seed + 1, g);
            ck.close(&format!("{tag} {name}: invariance vs heitz"), a, b, 0.0, 0.0);
        }
    }
    let pairs = [
        (Distribution::Ggx, 0.5, side_dir(0.3, 0.0, true), side_dir(1.0, 2.5, true)),
        (Distribution::Ggx, 1.0, side_dir(0.7, 0.0, true), side_dir(0.4, 2.0, false)),
        (Distribution::Beckmann, 1.0, side_dir(0.5, 0.0, false), side_dir(1.1, 0.5, false)),
        (Distribution::Ggx, 1.5, side_dir(1.2, 0.0, false), side_dir(0.5, 3.0, true)),
    ];
    for &(dist, alpha, wi, wo) in &pairs {
        let mf = Microfacet::new(dist, alpha, alpha);
        seed += 2;
        let a = point(&inv(mf, 1.5, true, all_orders()), wi, wo, 200_000, seed);
        let b = point(&heitz_eval(mf, 1.5, true, all_orders()), wi, wo, 200_000, seed + 1);
        ck.close(&format!("{dist:?} α={alpha} wi={wi:.2} wo={wo:.2} f·cos (radiance): invariance vs heitz"), a, b, 0.0, 0.0);
    }
    ck.finish();
}

/// Importance mode: f(i,o)/η_o² = f(o,i)/η_i²; Radiance mode: η_o² f(i,o) = η_i² f(o,i).
#[test]
fn reciprocity() {
    let mut ck = Checker::new("dielectric invariance reciprocity");
    let eta = 1.5;
    let mut seed = 900;
    for dist in DISTS {
        for &(ax, ay) in &[(0.5, 0.5), (1.0, 0.4)] {
            let mf = Microfacet::new(dist, ax, ay);
            for (name, wi, wo) in [
                ("out→out", side_dir(0.4, 0.1, true), side_dir(1.1, 2.5, true)),
                ("in→in", side_dir(0.5, 0.3, false), side_dir(1.0, 2.0, false)),
                ("out→in", side_dir(0.9, 0.1, true), side_dir(0.4, 2.5, false)),
            ] {
                for radiance in [false, true] {
                    seed += 2;
                    let a = point(&inv(mf, eta, radiance, all_orders()), wi, wo, 100_000, seed);
                    let b = point(&inv(mf, eta, radiance, all_orders()), wo, wi, 100_000, seed + 1);
                    let (x, y) = dielectric_reciprocal_pair(a, b, wi, wo, eta, radiance);
                    ck.close(&format!("{dist:?} α=({ax},{ay}) {name} {}", if radiance { "radiance" } else { "importance" }), x, y, 0.0, 0.0);
                }
            }
        }
    }
    ck.finish();
}

/// E[weight·g(ω_o)] of `sample` = ∫ g·eval for several g and order ranges.
#[test]
fn sampled_moments_match_eval() {
    let mut ck = Checker::new("dielectric invariance: sampled moments = eval integration");
    let gs: [(&str, &dyn Fn(DVec3) -> f64); 3] = [("1", &|_| 1.0), ("z", &|w: DVec3| w.z), ("x", &|w: DVec3| w.x)];
    let mut seed = 1300;
    for &(dist, alpha, eta, wi) in &[
        (Distribution::Ggx, 0.5, 1.5, side_dir(1.0, 0.0, true)),
        (Distribution::Beckmann, 1.0, 1.5, side_dir(0.5, 0.0, false)),
        (Distribution::Ggx, 2.0, 2.4, side_dir(0.2, 0.0, true)),
    ] {
        let mf = Microfacet::new(dist, alpha, alpha);
        for (oname, o) in [("all", all_orders()), ("orders 2–3", opts(MAXB, (2, 3))), ("max_bounces 2", opts(2, (1, MAXB)))] {
            for (gname, g) in gs.iter() {
                seed += 2;
                let e = eval_integral(&inv(mf, eta, false, o), mf, eta, wi, 40_000, seed, *g);
                let s = sample_mean(mf, eta, wi, o, 40_000, seed + 1, *g);
                ck.close(&format!("{dist:?} α={alpha} η={eta} wi.z={:.2} {oname} g={gname}", wi.z), s, e, 0.0, 0.0);
            }
        }
    }
    ck.finish();
}
