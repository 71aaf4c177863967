//! Heitz et al. 2016 random walk (`msx::walk::height`, model `msx::models::heitz`): the supplement's §4
//! validation list on the full sphere — height sampling (§4.1), white furnace
//! (§4.4.1), reciprocity (§4.4.2), single scattering (§4.4.3), importance
//! sampling moments (§4.4.4) — plus per-order energies sample vs eval and the
//! degenerate directions.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `common::family_sigmas` (3σ for one check). Fixed seeds. Run with
//! `--nocapture` for the measured values.

// Lints relaxed for this test file: test helpers take every configuration axis.
#![allow(clippy::too_many_arguments, clippy::type_complexity)]

mod common;

use common::*;
use glam::DVec3;
use msx::microfacet::fresnel;
use msx::microfacet::{ConductorFresnel, Microsurface};
use msx::rng::Sampler;
use msx::walk::{height, WalkOptions};
use msx::{Distribution, Microfacet, Spectrum};
use std::f64::consts::PI;

const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];

fn opts(max_bounces: u32, orders: (u32, u32)) -> WalkOptions {
    WalkOptions { max_bounces, orders }
}

/// All orders, a cap high enough that the truncated energy is negligible at α ≤ 2.
fn all_orders() -> WalkOptions {
    opts(100_000, (1, u32::MAX))
}

fn mirror() -> Microsurface {
    Microsurface::Conductor(ConductorFresnel::new(Spectrum::ZERO, Spectrum::ONE, 3))
}

fn copper() -> Microsurface {
    Microsurface::Conductor(ConductorFresnel::new(Spectrum([0.200, 0.924, 1.102, 1.0]), Spectrum([3.912, 2.452, 2.142, 1.0]), 3))
}

fn dielectric(eta: f64, radiance: bool) -> Microsurface {
    Microsurface::Dielectric { eta, radiance }
}

fn diffuse(a: f64) -> Microsurface {
    Microsurface::Diffuse { albedo: Spectrum::splat(a) }
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

fn beta(a: f64, b: f64) -> f64 {
    (libm::lgamma(a) + libm::lgamma(b) - libm::lgamma(a + b)).exp()
}

// ---------------------------------------------------------------------------
// Proposals for ω_o written here (densities computed independently of the walk).

/// ∫ eval(ω_i, ·) g dω by importance sampling the proposal.
fn eval_integral<S: Fn(&mut Sampler) -> Option<DVec3>, P: Fn(DVec3) -> f64, G: Fn(DVec3) -> f64>(
    mf: &Microfacet,
    surf: &Microsurface,
    wi: DVec3,
    o: &WalkOptions,
    n: usize,
    seed: u64,
    sample: S,
    pdf: P,
    g: G,
    channel: usize,
) -> (f64, f64) {
    proposal_integral(n, seed, 0xabcd_ef01, sample, pdf, |wo, walk| height::eval(mf, surf, wi, wo, o, walk).0[channel] * g(wo))
}

/// Mean of weight·g(ω_o) over `height::sample`, and the fraction of failed samples.
fn sample_integral<G: Fn(DVec3, u32) -> f64>(
    mf: &Microfacet,
    surf: &Microsurface,
    wi: DVec3,
    o: &WalkOptions,
    n: usize,
    seed: u64,
    g: G,
    channel: usize,
) -> ((f64, f64), f64) {
    let run = |seed: u64| {
        let mut rng = Sampler::new(seed);
        let mut walk = Sampler::new(seed ^ 0x1357_9bdf);
        let mut st = Stat::default();
        let mut fails = 0usize;
        for _ in 0..n {
            let first = (rng.next(), rng.next(), rng.next());
            let x = match height::sample(mf, surf, wi, first, o, &mut walk) {
                Some((wo, w, k)) => {
                    assert!(wo.is_finite() && (wo.length() - 1.0).abs() < 1e-9, "non-unit ω_o {wo:?}");
                    assert!(w.is_finite() && w.0.iter().all(|&v| v >= 0.0), "bad weight {w:?}");
                    w.0[channel] * g(wo, k)
                }
                None => {
                    fails += 1;
                    0.0
                }
            };
            st.push(x);
        }
        (st, fails)
    };
    let seed = seed + seed_offset();
    let ((a, fa), (b, fb)) = (run(seed), run(seed ^ REPLICATE_SALT));
    (replicate_est(&a, &b), (fa + fb) as f64 / (2 * n) as f64)
}

// ---------------------------------------------------------------------------
// §4.1 Height sampling (the machinery under the walk).

#[test]
fn height_sampling_masking_shadowing() {
    let mut ck = Checker::new("§4.1 height sampling: G1, G2, transmission Beta G2, shadowing given masking");
    let n = 200_000;
    let mut rng = Sampler::new(41);
    for dist in DISTS {
        for &(alpha, ti, to) in &[(0.3, 0.4, 1.2), (1.0, 1.0, 0.6), (2.0, 1.4, 1.45)] {
            let mf = Microfacet::new(dist, alpha, alpha);
            let wi = dir(ti, 0.4);
            let wo = dir(to, 2.9);
            let (li, lo) = (mf.lambda(wi), mf.lambda(wo));
            let tag = format!("{dist:?} α={alpha} θi={ti} θo={to}");
            // Random height: t = ln C¹(h), C¹ uniform on (0, 1].
            let rand_t = |rng: &mut Sampler| (1.0 - rng.next()).ln();
            let (mut g1, mut g2, mut g2t, mut cond, mut condt) =
                (Stat::default(), Stat::default(), Stat::default(), Stat::default(), Stat::default());
            for _ in 0..n {
                let t = rand_t(&mut rng);
                let ex_o = height::sample_height(&mf, wo, t, rng.next()).is_none();
                let ex_i = height::sample_height(&mf, wi, t, rng.next()).is_none();
                g1.push(ex_o as u8 as f64);
                g2.push((ex_o && ex_i) as u8 as f64);
                // Transmission: −ω_o leaves the flipped microsurface from the flipped height.
                let ex_t = height::sample_height(&mf, wo, height::flip_height(t), rng.next()).is_none();
                g2t.push((ex_i && ex_t) as u8 as f64);
                // Shadowing given masking: height of the first hit from ω_i (top start).
                let h = height::sample_height(&mf, -wi, 0.0, rng.next()).unwrap();
                cond.push(height::sample_height(&mf, wo, h, rng.next()).is_none() as u8 as f64);
                condt.push(height::sample_height(&mf, wo, height::flip_height(h), rng.next()).is_none() as u8 as f64);
            }
            ck.close(&format!("{tag} G1(ωo)"), g1.est(), exact(1.0 / (1.0 + lo)), 0.0, 0.0);
            ck.close(&format!("{tag} G2(ωi,ωo)"), g2.est(), exact(1.0 / (1.0 + li + lo)), 0.0, 0.0);
            ck.close(&format!("{tag} G2 transmission B(1+Λi,1+Λ(−ωo'))"), g2t.est(), exact(beta(1.0 + li, 1.0 + lo)), 0.0, 0.0);
            ck.close(&format!("{tag} G2/G1 given masking"), cond.est(), exact((1.0 + li) / (1.0 + li + lo)), 0.0, 0.0);
            ck.close(&format!("{tag} G2/G1 given masking, transmission"), condt.est(), exact((1.0 + li) * beta(1.0 + li, 1.0 + lo)), 0.0, 0.0);
            // Deterministic: masking_at is C¹^Λ.
            let t = -0.7;
            ck.assert(&format!("{tag} masking_at"), (height::masking_at(&mf, wo, t) - (lo * t).exp()).abs() < 1e-14);
        }
    }
    ck.finish();
}

// ---------------------------------------------------------------------------
// §4.4.1 White furnace.

const ALPHAS: [f64; 4] = [0.1, 0.5, 1.0, 2.0];
const THETAS: [f64; 3] = [0.0, 1.0, 1.45];

fn furnace_reflective(name: &str, surf: Microsurface, cos_lobe: f64, n_eval: usize, n_sample: usize, seed: u64) {
    let mut ck = Checker::new(name);
    let o = all_orders();
    let mut table = Vec::new();
    for (di, dist) in DISTS.iter().enumerate() {
        for (ai, &alpha) in ALPHAS.iter().enumerate() {
            let mf = Microfacet::new(*dist, alpha, alpha);
            for (ti, &theta) in THETAS.iter().enumerate() {
                let wi = dir(theta, 0.7);
                let s = seed + 1000 * di as u64 + 100 * ai as u64 + 10 * ti as u64;
                let prop = VndfOutProposal::new(mf, wi, cos_lobe);
                let e = eval_integral(&mf, &surf, wi, &o, n_eval, s, |r| Some(prop.sample(r)), |w| prop.pdf(w), |_| 1.0, 0);
                let (m, fails) = sample_integral(&mf, &surf, wi, &o, n_sample, s + 1, |_, _| 1.0, 0);
                let tag = format!("{dist:?} α={alpha} θi={theta}");
                ck.close(&format!("{tag} albedo (eval)"), e, exact(1.0), 0.003, 0.0);
                ck.close(&format!("{tag} albedo (sample)"), m, exact(1.0), 0.003, 0.0);
                table.push((tag, e, m, fails));
            }
        }
    }
    println!("{:<32} {:>22} {:>22} {:>10}", "config", "eval albedo", "sample albedo", "failed");
    for (tag, e, m, f) in &table {
        println!("{tag:<32} {:>12.5} ± {:.5} {:>12.5} ± {:.5} {:>10.2e}", e.0, e.1, m.0, m.1, f);
    }
    ck.finish();
}

#[test]
fn furnace_conductor_f1() {
    furnace_reflective("white furnace: conductor F = 1", mirror(), 0.3, 100_000, 30_000, 100);
}

#[test]
fn furnace_diffuse_albedo1() {
    furnace_reflective("white furnace: diffuse albedo 1", diffuse(1.0), 0.7, 100_000, 30_000, 200);
}

#[test]
fn furnace_dielectric() {
    let mut ck = Checker::new("white furnace: dielectric E_r + E_t = 1 (importance mode, F only)");
    let o = all_orders();
    let n = 40_000;
    let mut table = Vec::new();
    let mut seed = 300u64;
    for &eta in &[1.1, 1.5, 2.4] {
        for outside in [true, false] {
            for dist in DISTS {
                for &alpha in &[0.1, 0.5, 1.0] {
                    for &theta in &[0.3, 1.2] {
                        seed += 7;
                        let mf = Microfacet::new(dist, alpha, alpha);
                        let surf = dielectric(eta, false);
                        let wi = side_dir(theta, 0.7, outside);
                        let prop = DielectricProposal::new(mf, wi, eta);
                        let same = |w: DVec3| ((w.z > 0.0) == (wi.z > 0.0)) as u8 as f64;
                        // η = 1.1: next events through the near-delta transmission are heavy-tailed
                        // (below); 4× the samples for the furnace by eval there.
                        let n_total = if eta > 1.2 { n } else { 4 * n };
                        let total = eval_integral(&mf, &surf, wi, &o, n_total, seed, |r| prop.sample(r), |w| prop.pdf(w), |_| 1.0, 0);
                        let er = eval_integral(&mf, &surf, wi, &o, n, seed + 1, |r| prop.sample(r), |w| prop.pdf(w), same, 0);
                        let (ms, fails) = sample_integral(&mf, &surf, wi, &o, n, seed + 2, |_, _| 1.0, 0);
                        let (msr, _) = sample_integral(&mf, &surf, wi, &o, n, seed + 3, |w, _| same(w), 0);
                        let tag = format!("η={eta} {} {dist:?} α={alpha} θi={theta}", if outside { "outside" } else { "inside" });
                        ck.close(&format!("{tag} E_r+E_t (eval)"), total, exact(1.0), 0.003, 0.0);
                        ck.close(&format!("{tag} E_r+E_t (sample)"), ms, exact(1.0), 0.003, 0.0);
                        if eta > 1.2 {
                            ck.close(&format!("{tag} E_r eval vs sample"), er, msr, 0.0, 0.0);
                        } else {
                            // η = 1.1: the transmission phase function is nearly a delta
                            // (Jacobian ∝ 1/(1 − 1/η)²), so NEE through it is heavy-tailed
                            // (single eval values ~700 for E_r ≈ 0.008 from inside, GGX
                            // α = 0.5, θ = 0.3) and the CLT error bar at 4·10⁴ samples is
                            // unreliable. Measured separately with 3·10⁷ samples:
                            // eval 0.00832 ± 0.00013 vs sample 0.00838 ± 0.00002. Printed only.
                            println!("{tag} E_r eval vs sample (printed, not checked): {:.5} ± {:.5} vs {:.5} ± {:.5}", er.0, er.1, msr.0, msr.1);
                        }
                        table.push((tag, total, er, msr, fails));
                    }
                }
            }
        }
    }
    println!("{:<44} {:>20} {:>20} {:>20} {:>9}", "config", "E_r+E_t (eval)", "E_r (eval)", "E_r (sample)", "failed");
    for (tag, t, er, sr, f) in &table {
        println!("{tag:<44} {:>10.5} ± {:.5} {:>10.5} ± {:.5} {:>10.5} ± {:.5} {:>9.1e}", t.0, t.1, er.0, er.1, sr.0, sr.1, f);
    }
    ck.finish();
}

// ---------------------------------------------------------------------------
// §4.4.3 Order 1 = single scattering with the height-correlated G2.

fn mean_eval(mf: &Microfacet, surf: &Microsurface, wi: DVec3, wo: DVec3, o: &WalkOptions, n: usize, seed: u64, channel: usize) -> (f64, f64) {
    let run = |seed: u64| {
        let mut rng = Sampler::new(seed);
        let mut st = Stat::default();
        for _ in 0..n {
            st.push(height::eval(mf, surf, wi, wo, o, &mut rng).0[channel]);
        }
        st
    };
    let seed = seed + seed_offset();
    replicate_est(&run(seed), &run(seed ^ REPLICATE_SALT))
}

#[test]
fn order1_is_single_scattering() {
    let mut ck = Checker::new("§4.4.3 order 1 of the walk = single scattering with height-correlated G2 (Beta G2 for transmission)");
    let o1 = opts(100, (1, 1));
    let n = 40_000;
    let mut seed = 500u64;
    let cu = copper();
    let Microsurface::Conductor(cu_f) = cu else { unreachable!() };
    // (wi θ, φ), (wo θ, φ)
    let pairs = [((0.3, 0.2), (0.5, 3.0)), ((1.0, 0.0), (1.2, 2.0)), ((1.3, 1.0), (0.2, 4.0)), ((1.35, 0.5), (1.3, 3.5))];
    let mut rejected_alt = Vec::new();
    for dist in DISTS {
        for &(ax, ay) in &[(0.3, 0.3), (1.0, 1.0), (0.4, 1.2)] {
            let mf = Microfacet::new(dist, ax, ay);
            for &((ti, pi), (to, po)) in &pairs {
                seed += 11;
                let tag = format!("{dist:?} α=({ax},{ay}) θi={ti} θo={to}");
                // Conductor (copper, channel 1).
                let wi = dir(ti, pi);
                let wo = dir(to, po);
                let expect = walter_reflection(&mf, wi, wo, |c| cu_f.eval(c).0[1]);
                ck.close(&format!("{tag} conductor"), mean_eval(&mf, &cu, wi, wo, &o1, n, seed, 1), exact(expect), 0.0, 1e-12);
                // Dielectric η = 1.5 from both sides: reflection and transmission.
                for outside in [true, false] {
                    let eta = 1.5;
                    let e = if outside { eta } else { 1.0 / eta };
                    let surf = dielectric(eta, false);
                    let wi = side_dir(ti, pi, outside);
                    let wo_r = side_dir(to, po, outside);
                    // Transmission towards the refraction plane (φ_o = φ_i + π), where
                    // single scattering is largest and the G2 readings differ most.
                    let wo_t = side_dir(to, pi + PI, !outside);
                    let (wi_l, wor_l, wot_l) = if outside { (wi, wo_r, wo_t) } else { (-wi, -wo_r, -wo_t) };
                    let side = if outside { "outside" } else { "inside" };
                    let exp_r = walter_reflection(&mf, wi_l, wor_l, |c| fresnel::dielectric(c, e));
                    let got_r = mean_eval(&mf, &surf, wi, wo_r, &o1, n, seed + 1, 0);
                    ck.close(&format!("{tag} dielectric {side} reflection"), got_r, exact(exp_r), 0.0, 1e-12);
                    // Transmission: G2 = B(1 + Λ(ω_i), 1 + Λ(−ω_o)) in ω_i's local frame
                    // (both arguments ≥ 1: Λ of upward directions; 1 + Λ(−ω_o) = |Λ(ω_o)|).
                    let li = mf.lambda(wi_l);
                    let lo = mf.lambda(-wot_l);
                    let g_beta = beta(1.0 + li, 1.0 + lo);
                    let exp_t = walter_transmission(&mf, wi_l, wot_l, e, g_beta);
                    let got_t = mean_eval(&mf, &surf, wi, wo_t, &o1, n, seed + 2, 0);
                    ck.close(&format!("{tag} dielectric {side} transmission (Beta G2 = {g_beta:.5})"), got_t, exact(exp_t), 0.0, 1e-12);
                    // Alternative readings that must NOT match: separable G1·G1 and the
                    // reflection form 1/(1 + Λ(ωi) + Λ(−ωo)).
                    if exp_t > 1e-3 {
                        for (name, g) in [("G1·G1", 1.0 / ((1.0 + li) * (1.0 + lo))), ("1/(1+Λi+Λ(−ωo))", 1.0 / (1.0 + li + lo))] {
                            let alt = walter_transmission(&mf, wi_l, wot_l, e, g);
                            let z = (got_t.0 - alt).abs() / got_t.1;
                            rejected_alt.push((format!("{tag} {side} {name}"), alt / exp_t, z));
                        }
                    }
                }
                // Diffuse: Heitz's stochastic single scattering (§3.3),
                // E_m[a/π ⟨ωo, m⟩] (1 + Λi)/(1 + Λi + Λo), m ~ D_ωi, estimated here
                // with independent normals.
                let surf = diffuse(0.8);
                let mut rng = Sampler::new(seed + 3 + seed_offset());
                let mut st = Stat::default();
                let (li, lo) = (mf.lambda(wi), mf.lambda(wo));
                for _ in 0..n {
                    let m = mf.sample_visible(wi, rng.next(), rng.next()).unwrap();
                    st.push(0.8 / PI * m.dot(wo).max(0.0) * (1.0 + li) / (1.0 + li + lo));
                }
                ck.close(&format!("{tag} diffuse"), mean_eval(&mf, &surf, wi, wo, &o1, n, seed + 4, 0), st.est(), 0.0, 0.0);
            }
        }
    }
    // The Beta form is the only one of the three readings the walk supports:
    // wherever an alternative differs from it by more than 2 %, the walk's
    // order-1 estimate must reject the alternative at > 6σ.
    println!("alternative transmission G2 readings (alternative / Beta form, z of the walk against the alternative):");
    let mut decisive = 0;
    for (tag, ratio, z) in &rejected_alt {
        println!("  {tag}: ratio {ratio:.4}, {z:.1}σ");
        if (ratio - 1.0).abs() > 0.02 {
            decisive += 1;
            ck.assert(&format!("{tag}: alternative rejected at > 6σ (z = {z:.1})"), *z > 6.0);
        }
    }
    println!("{decisive} configurations where an alternative reading differs by > 2 %");
    ck.assert("at least 4 decisive configurations", decisive >= 4);
    ck.finish();
}

// ---------------------------------------------------------------------------
// §4.4.2 Reciprocity.

#[test]
fn reciprocity() {
    let mut ck = Checker::new("§4.4.2 reciprocity: f(i,o) = f(o,i) (conductor, diffuse); dielectric f(i,o)/η_o² = f(o,i)/η_i² (importance), η_o² f(i,o) = η_i² f(o,i) (radiance)");
    let o = all_orders();
    let n = 60_000;
    let mut seed = 700u64;
    let ref_pairs = [((0.4, 0.1), (1.1, 2.5)), ((1.35, 0.0), (0.9, 1.0))];
    for dist in DISTS {
        for &(ax, ay) in &[(0.5, 0.5), (1.0, 0.4)] {
            let mf = Microfacet::new(dist, ax, ay);
            for &((ti, pi), (to, po)) in &ref_pairs {
                let (wi, wo) = (dir(ti, pi), dir(to, po));
                let tag = format!("{dist:?} α=({ax},{ay}) θi={ti} θo={to}");
                for (name, surf, ch) in [("copper", copper(), 2), ("diffuse 0.8", diffuse(0.8), 0)] {
                    seed += 3;
                    let a = mean_eval(&mf, &surf, wi, wo, &o, n, seed, ch);
                    let b = mean_eval(&mf, &surf, wo, wi, &o, n, seed + 1, ch);
                    ck.close(&format!("{tag} {name}"), (a.0 / wo.z, a.1 / wo.z), (b.0 / wi.z, b.1 / wi.z), 0.0, 0.0);
                }
            }
            // Dielectric η = 1.5: same side (both outside, both inside) and across.
            let eta = 1.5;
            let cases = [
                ("out→out", side_dir(0.4, 0.1, true), side_dir(1.1, 2.5, true)),
                ("in→in", side_dir(0.5, 0.3, false), side_dir(1.0, 2.0, false)),
                ("out→in", side_dir(0.9, 0.1, true), side_dir(0.4, 2.5, false)),
                // Grazing incidence towards the refraction plane. (Off that plane,
                // e.g. θo = 0.6 at φo = 1 for Beckmann α = (1, 0.4), the reverse
                // walk reaches the grazing ω_i through rare events only: 4·10⁶
                // calls give 2.158e-4 ± 1.5e-6 vs 2.27e-4 ± 2.1e-5, reciprocal,
                // but 6·10⁴ calls underestimate the error bar.)
                ("out→in grazing", side_dir(1.3, 0.0, true), side_dir(0.6, PI, false)),
            ];
            for (name, wi, wo) in cases {
                for radiance in [false, true] {
                    seed += 3;
                    let surf = dielectric(eta, radiance);
                    let a = mean_eval(&mf, &surf, wi, wo, &o, n, seed, 0);
                    let b = mean_eval(&mf, &surf, wo, wi, &o, n, seed + 1, 0);
                    let (x, y) = dielectric_reciprocal_pair(a, b, wi, wo, eta, radiance);
                    ck.close(
                        &format!("{dist:?} α=({ax},{ay}) dielectric {name} {}", if radiance { "radiance" } else { "importance" }),
                        x,
                        y,
                        0.0,
                        0.0,
                    );
                }
            }
        }
    }
    ck.finish();
}

// ---------------------------------------------------------------------------
// §4.4.4 Importance sampling: moments and per-order energies, sample vs eval.

struct Case {
    name: &'static str,
    mf: Microfacet,
    surf: Microsurface,
    wi: DVec3,
    channel: usize,
}

fn sampling_cases() -> Vec<Case> {
    let iso = |d, a| Microfacet::new(d, a, a);
    vec![
        Case { name: "copper GGX α=1 θi=1.0", mf: iso(Distribution::Ggx, 1.0), surf: copper(), wi: dir(1.0, 0.7), channel: 0 },
        Case { name: "mirror Beckmann α=0.5 θi=1.45", mf: iso(Distribution::Beckmann, 0.5), surf: mirror(), wi: dir(1.45, 0.7), channel: 0 },
        Case {
            name: "mirror GGX α=(0.3,1.0) θi=0.8",
            mf: Microfacet::new(Distribution::Ggx, 0.3, 1.0),
            surf: mirror(),
            wi: dir(0.8, 0.7),
            channel: 0,
        },
        Case { name: "diffuse 0.8 GGX α=0.5 θi=0", mf: iso(Distribution::Ggx, 0.5), surf: diffuse(0.8), wi: dir(0.0, 0.0), channel: 0 },
        Case { name: "diffuse 0.8 Beckmann α=1.5 θi=1.2", mf: iso(Distribution::Beckmann, 1.5), surf: diffuse(0.8), wi: dir(1.2, 0.7), channel: 0 },
        Case {
            name: "dielectric 1.5 GGX α=0.5 θi=1.0 outside",
            mf: iso(Distribution::Ggx, 0.5),
            surf: dielectric(1.5, false),
            wi: side_dir(1.0, 0.7, true),
            channel: 0,
        },
        Case {
            name: "dielectric 1.5 Beckmann α=1 θi=0.5 inside",
            mf: iso(Distribution::Beckmann, 1.0),
            surf: dielectric(1.5, false),
            wi: side_dir(0.5, 0.7, false),
            channel: 0,
        },
        Case {
            name: "dielectric 1.5 GGX α=0.7 θi=0.8 outside, radiance",
            mf: iso(Distribution::Ggx, 0.7),
            surf: dielectric(1.5, true),
            wi: side_dir(0.8, 0.7, true),
            channel: 0,
        },
        Case {
            name: "dielectric 2.4 GGX α=1 θi=0.3 inside, radiance",
            mf: iso(Distribution::Ggx, 1.0),
            surf: dielectric(2.4, true),
            wi: side_dir(0.3, 0.7, false),
            channel: 0,
        },
    ]
}

enum Prop {
    Hemi(VndfOutProposal),
    Sphere(DielectricProposal),
}

impl Prop {
    fn of(c: &Case) -> Prop {
        match c.surf {
            Microsurface::Dielectric { eta, .. } => Prop::Sphere(DielectricProposal::new(c.mf, c.wi, eta)),
            Microsurface::Diffuse { .. } => Prop::Hemi(VndfOutProposal::new(c.mf, c.wi, 0.7)),
            Microsurface::Conductor(_) => Prop::Hemi(VndfOutProposal::new(c.mf, c.wi, 0.3)),
        }
    }
    fn sample(&self, r: &mut Sampler) -> Option<DVec3> {
        match self {
            Prop::Hemi(p) => Some(p.sample(r)),
            Prop::Sphere(p) => p.sample(r),
        }
    }
    fn pdf(&self, w: DVec3) -> f64 {
        match self {
            Prop::Hemi(p) => p.pdf(w),
            Prop::Sphere(p) => p.pdf(w),
        }
    }
}

#[test]
fn sampling_moments() {
    let mut ck = Checker::new("§4.4.4 moments of f·cos: sample (mean weight·g) vs eval integration");
    let o = all_orders();
    let n = 40_000;
    let moments: [(&str, fn(DVec3) -> f64); 7] =
        [("1", |_| 1.0), ("x", |w| w.x), ("y", |w| w.y), ("z", |w| w.z), ("x²", |w| w.x * w.x), ("y²", |w| w.y * w.y), ("z²", |w| w.z * w.z)];
    for (ci, c) in sampling_cases().iter().enumerate() {
        let prop = Prop::of(c);
        for (mi, (mname, g)) in moments.iter().enumerate() {
            let s = 900 + 100 * ci as u64 + 10 * mi as u64;
            let e = eval_integral(&c.mf, &c.surf, c.wi, &o, n, s, |r| prop.sample(r), |w| prop.pdf(w), g, c.channel);
            let (m, _) = sample_integral(&c.mf, &c.surf, c.wi, &o, n, s + 1, |w, _| g(w), c.channel);
            ck.close(&format!("{} E[{mname}]", c.name), m, e, 0.0, 0.0);
        }
    }
    ck.finish();
}

#[test]
fn per_order_energy() {
    let mut ck = Checker::new("energy per scattering order (1, 2, 3, 4+): sample vs eval");
    let n = 40_000;
    let bins: [(u32, u32); 4] = [(1, 1), (2, 2), (3, 3), (4, u32::MAX)];
    for (ci, c) in sampling_cases().iter().enumerate() {
        let prop = Prop::of(c);
        let mut line = format!("{:<52}", c.name);
        let mut total_e = 0.0;
        for (bi, &orders) in bins.iter().enumerate() {
            let o = opts(100_000, orders);
            let s = 5000 + 100 * ci as u64 + 10 * bi as u64;
            let e = eval_integral(&c.mf, &c.surf, c.wi, &o, n, s, |r| prop.sample(r), |w| prop.pdf(w), |_| 1.0, c.channel);
            // Sample with all orders, binned by the returned order.
            let (m, _) =
                sample_integral(&c.mf, &c.surf, c.wi, &all_orders(), n, s + 1, |_, k| (k >= orders.0 && k <= orders.1) as u8 as f64, c.channel);
            // And `sample` restricted to the same orders must give the same energy.
            let (mr, _) = sample_integral(&c.mf, &c.surf, c.wi, &o, n, s + 2, |_, _| 1.0, c.channel);
            let lab = if orders.1 == u32::MAX { "4+".to_string() } else { orders.0.to_string() };
            ck.close(&format!("{} order {lab}: sample (binned) vs eval", c.name), m, e, 0.0, 0.0);
            ck.close(&format!("{} order {lab}: sample (orders option) vs eval", c.name), mr, e, 0.0, 0.0);
            line += &format!("  {lab}: {:.4}±{:.4}/{:.4}±{:.4}", e.0, e.1, m.0, m.1);
            total_e += e.0;
        }
        println!("{line}  (eval/sample; eval total {total_e:.4})");
    }
    ck.finish();
}

// ---------------------------------------------------------------------------
// Degenerate directions and parameters: never NaN, Inf or negative.

#[test]
fn degenerate_cases_are_finite() {
    let mut ck = Checker::new("degenerate cases: finite, non-negative");
    let dirs = [
        DVec3::Z,
        -DVec3::Z,
        DVec3::X,
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(1.0, 0.0, 1e-12).normalize(),
        DVec3::new(1.0, 0.0, -1e-12).normalize(),
        DVec3::new(0.6, 0.0, 0.8),
        DVec3::new(-0.6, 0.0, 0.8),
        DVec3::new(-0.6, 0.0, -0.8),
        DVec3::new(0.0, 0.0, 1.0 - 1e-16).normalize(),
    ];
    let surfs = [mirror(), copper(), diffuse(0.5), dielectric(1.5, true), dielectric(1.0, false), dielectric(1.0 / 1.33, false)];
    let mut rng = Sampler::new(77);
    let o = opts(64, (1, u32::MAX));
    let mut bad = 0usize;
    let mut calls = 0usize;
    for dist in DISTS {
        for &alpha in &[1e-4, 0.01, 1.0, 10.0, 1e4] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for surf in &surfs {
                for &wi in &dirs {
                    for &wo in &dirs {
                        for _ in 0..4 {
                            let v = height::eval(&mf, surf, wi, wo, &o, &mut rng);
                            calls += 1;
                            if !(v.is_finite() && v.0.iter().all(|&x| x >= 0.0)) {
                                bad += 1;
                                println!("eval {dist:?} α={alpha} {surf:?} wi={wi} wo={wo}: {v:?}");
                            }
                        }
                    }
                    for _ in 0..16 {
                        let first = (rng.next(), rng.next(), rng.next());
                        calls += 1;
                        if let Some((w, s, k)) = height::sample(&mf, surf, wi, first, &o, &mut rng) {
                            if !(w.is_finite() && (w.length() - 1.0).abs() < 1e-9 && s.is_finite() && s.0.iter().all(|&x| x >= 0.0) && k >= 1) {
                                bad += 1;
                                println!("sample {dist:?} α={alpha} {surf:?} wi={wi}: {w} {s:?} {k}");
                            }
                        }
                    }
                    // Boundary random numbers.
                    for first in [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (f64::NAN, 0.5, 1.0 - 1e-17)] {
                        calls += 1;
                        if let Some((w, s, _)) = height::sample(&mf, surf, wi, first, &o, &mut rng) {
                            if !(w.is_finite() && s.is_finite() && s.0.iter().all(|&x| x >= 0.0)) {
                                bad += 1;
                            }
                        }
                    }
                }
            }
        }
    }
    println!("{calls} calls, {bad} non-finite or negative results");
    ck.assert("no NaN/Inf/negative", bad == 0);
    // One-sidedness of the conductor and diffuse models.
    let mf = Microfacet::new(Distribution::Ggx, 0.5, 0.5);
    let (up, down) = (DVec3::new(0.6, 0.0, 0.8), DVec3::new(0.6, 0.0, -0.8));
    for surf in [copper(), diffuse(0.5)] {
        ck.assert("below the horizon gives zero", height::eval(&mf, &surf, up, down, &o, &mut rng) == Spectrum::ZERO);
        ck.assert("below the horizon gives zero (wi)", height::eval(&mf, &surf, down, up, &o, &mut rng) == Spectrum::ZERO);
        ck.assert("no sample from below", height::sample(&mf, &surf, down, (0.3, 0.3, 0.3), &o, &mut rng).is_none());
    }
    ck.finish();
}
