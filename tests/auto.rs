//! `model="auto"` (src/models/auto/, README.md, model table): it is exactly `correlated`,
//! with one bounce where its rule finds order 1 alone within the tolerance;
//! the energy it omits stays within the tolerance, measured independently
//! (full random walks, off-grid points, real materials: copper, albedo 0.5,
//! glass from both sides); smooth surfaces get the deterministic order-1
//! model; the rule is a bound at random points it accepts; parameter errors.
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! Monte Carlo standard error, z the family-wise 3σ level of
//! `common::family_sigmas`. Run with `--nocapture` for the measured values.

mod common;

use common::*;
use glam::DVec3;
use msx::models::auto;
use msx::rng::Sampler;
use msx::{Bsdf, Config, Distribution, Estimator, Material, Model, Spectrum, Surface};
use std::f64::consts::PI;

const CU_ETA: [f64; 3] = [0.200438, 0.924033, 1.10221];
const CU_K: [f64; 3] = [3.91295, 2.45285, 2.14219];

fn bsdf(surface: Surface, distribution: Distribution, model: Model, max_bounces: u32, tolerance: f64) -> Bsdf {
    Bsdf::new(Config { surface, distribution, model, max_bounces, tolerance, estimator: Estimator::Pt, channels: 3, seed: 7, ..Config::default() })
        .unwrap()
}

/// Material of a surface: copper (conductor), glass of relative IOR `ior`
/// (dielectric), albedo 0.5 (diffuse); Importance mode (energy conserving).
fn material(surface: Surface, alpha_u: f64, alpha_v: f64, ior: f64) -> Material {
    let mut m = Material::mirror(alpha_u);
    m.alpha_v = alpha_v;
    m.radiance = false;
    match surface {
        Surface::Conductor => {
            m.eta = Spectrum([CU_ETA[0], CU_ETA[1], CU_ETA[2], 0.0]);
            m.k = Spectrum([CU_K[0], CU_K[1], CU_K[2], 0.0]);
        }
        Surface::Dielectric => m.ior = ior,
        Surface::Diffuse => m.reflectance = Spectrum::splat(0.5),
    }
    m
}

fn cap(surface: Surface, dist: Distribution, m: &Material, wi: DVec3, tol: f64, max_bounces: u32) -> u32 {
    let eta = if wi.z > 0.0 { m.ior } else { 1.0 / m.ior };
    auto::OrderOneRule::new(surface, dist, tol).cap(m.alpha_u.max(m.alpha_v), wi.z.abs(), eta, max_bounces)
}

const SURFACES: [Surface; 3] = [Surface::Conductor, Surface::Dielectric, Surface::Diffuse];
const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];

/// auto(ω_i, ω_o) is bit-identical to correlated with max_bounces = the cap
/// (1 or the full 64; same seed and key), for eval, pdf and sample — except
/// the order-1 calls of a conductor and of a dielectric, whose pdf is the
/// density of the walk's first vertex and whose sample takes the walk's first
/// direction with the weight eval/pdf (src/models/auto/mod.rs `order_one_*`,
/// posfree/dielectric.rs `order_one_*`; `dielectric_order_one_call`).
#[test]
fn auto_is_truncated_correlated() {
    let mut ck = Checker::new("auto == correlated with the table's bounce cap, 1 or all (bit-identical)");
    let mut rng = Sampler::new(1);
    let mut caps = std::collections::BTreeMap::new();
    let mut glass_reduced = [0; 2]; // reduced dielectric calls from above, from below
    for surface in SURFACES {
        for dist in DISTS {
            for _ in 0..150 {
                let alpha = 10f64.powf(rng.gen_range(-2.5, 0.7));
                let m = material(surface, alpha, alpha * rng.gen_range(0.5, 1.0), 1.5);
                let below = surface == Surface::Dielectric && rng.next() < 0.5;
                let wi = {
                    let d = dir(rng.next().acos().min(1.55), 0.0);
                    if below {
                        DVec3::new(d.x, d.y, -d.z)
                    } else {
                        d
                    }
                };
                let wo = {
                    let d = dir(rng.next().acos().min(1.55), 2.0 * PI * rng.next());
                    if surface == Surface::Dielectric && rng.next() < 0.5 {
                        DVec3::new(d.x, d.y, -d.z)
                    } else {
                        d
                    }
                };
                let k = cap(surface, dist, &m, wi, 0.01, 64);
                *caps.entry(k).or_insert(0) += 1;
                if surface == Surface::Dielectric && k == 1 {
                    glass_reduced[usize::from(below)] += 1;
                }
                let a = bsdf(surface, dist, Model::Auto, 64, 0.01);
                let c = bsdf(surface, dist, Model::Correlated, k, 0.01);
                let key = rng.next().to_bits();
                let same_eval = a.eval(&m, wi, wo, key).0 == c.eval(&m, wi, wo, key).0;
                let (s1, s2) = (rng.next(), (rng.next(), rng.next()));
                let (x, y) = (a.sample(&m, wi, s1, s2), c.sample(&m, wi, s1, s2));
                let (same_pdf, same_sample) = if surface == Surface::Dielectric && k == 1 {
                    dielectric_order_one_call(&a, &c, &m, dist, wi, wo, key, (s1, s2))
                } else if surface == Surface::Conductor && k == 1 {
                    // A conductor's order-1 call: the same eval (the walk's first next event is the closed
                    // form, in the same arithmetic), the visible-normal reflection density as pdf, and a
                    // sample along the walk's first reflection (the same numbers) weighted by eval/pdf.
                    let mf = msx::microfacet::Microfacet::new(dist, m.alpha_u, m.alpha_v);
                    let unit = |v: DVec3| v / v.length(); // as the Bsdf takes its directions
                    let p1 = |wo: DVec3| if wo.z > 0.0 { mf.reflect_pdf(unit(wi), unit(wo)) } else { 0.0 };
                    let sample_ok = match (x, y) {
                        (Some(x), y) => {
                            let f = a.eval(&m, wi, x.wo, key);
                            // eval takes x.wo renormalised: a rounding of it, which a lobe of α ≈ 0.004 turns
                            // into a relative 1e-11 of its value.
                            let close = (0..3).all(|c| (x.weight.0[c] * x.pdf - f.0[c]).abs() <= 1e-9 * f.0[c]);
                            let same_pdf = (x.pdf - p1(x.wo)).abs() <= 1e-9 * x.pdf;
                            let ok = same_pdf && close && y.is_none_or(|y| y.wo == x.wo);
                            if !ok {
                                println!(
                                    "sample: pdf {} vs {}, weight·pdf {:?} vs eval {:?}, walk {:?}",
                                    x.pdf,
                                    p1(x.wo),
                                    x.weight.0.map(|w| w * x.pdf),
                                    f.0,
                                    y.map(|y| y.wo)
                                );
                            }
                            ok
                        }
                        (None, None) => true,
                        (None, Some(_)) => false,
                    };
                    (a.pdf(&m, wi, wo) == p1(wo), sample_ok)
                } else {
                    let same_sample = match (x, y) {
                        (Some(x), Some(y)) => x.wo == y.wo && x.pdf == y.pdf && x.weight.0 == y.weight.0,
                        (None, None) => true,
                        _ => false,
                    };
                    (a.pdf(&m, wi, wo) == c.pdf(&m, wi, wo), same_sample)
                };
                ck.assert(
                    &format!("{surface:?} {dist:?} α={alpha:.4} wi={wi:.3} cap {k} eval {same_eval} pdf {same_pdf} sample {same_sample}"),
                    same_eval && same_pdf && same_sample,
                );
            }
        }
    }
    println!("caps chosen (tolerance 1 %): {caps:?}");
    ck.assert("both order 1 alone and the full model in use", caps.contains_key(&1) && caps.contains_key(&64));
    ck.assert(&format!("reduced dielectric calls from above and below: {glass_reduced:?}"), glass_reduced.iter().all(|&n| n >= 10));
    ck.finish();
}

/// The checks of one reduced dielectric call (`auto_is_truncated_correlated`; `a` auto, `c` correlated capped at
/// one vertex): (pdf, sample) as expected. `pdf` is the density of the walk's first vertex — Walter 2007 with
/// G = G1(ω_i) = 1/(1 + Λ_i), written independently in tests/common/dielectric.rs — to 1e-9 relative (where the
/// transmission's Fresnel factor is well conditioned); `sample` is the capped walk's direction wherever the walk
/// leaves there (it may also go on, where the closed form returns its direction all the same), with the pdf
/// `pdf` reports and the weight eval/pdf.
#[allow(clippy::too_many_arguments)]
fn dielectric_order_one_call(
    a: &Bsdf,
    c: &Bsdf,
    m: &Material,
    dist: Distribution,
    wi: DVec3,
    wo: DVec3,
    key: u64,
    u: (f64, (f64, f64)),
) -> (bool, bool) {
    use common::dielectric::{lam_up, rel, walter, walter_h, well_conditioned};
    let unit = |v: DVec3| v / v.length(); // as the Bsdf takes its directions
    let density = |wo: DVec3| {
        let (wi, wo) = (unit(wi), unit(wo));
        // Walter's G carries χ⁺(v·h / v·n) of both directions: a facet seen from behind has no density.
        let h = walter_h(m.ior, wi, wo);
        if wi.dot(h) * wi.z <= 0.0 || wo.dot(h) * wo.z <= 0.0 {
            return 0.0;
        }
        walter(dist, m.alpha_u, m.alpha_v, m.ior, wi, wo, 1.0 / (1.0 + lam_up(dist, m.alpha_u, m.alpha_v, wi)), false)
    };
    let close = |got: f64, want: f64| rel(got, want) <= 1e-9 || want.abs() < 1e-300 && got.abs() < 1e-300;
    let pdf_ok = |wo: DVec3, got: f64| !well_conditioned(m.ior, unit(wi), unit(wo)) || close(got, density(wo));
    let same_pdf = pdf_ok(wo, a.pdf(m, wi, wo));
    let (x, y) = (a.sample(m, wi, u.0, u.1), c.sample(m, wi, u.0, u.1));
    let same_sample = match (x, y) {
        (Some(x), y) => {
            let f = a.eval(m, wi, x.wo, key).0[0];
            let ok = y.is_none_or(|y| y.wo == x.wo)
                && (x.pdf - a.pdf(m, wi, x.wo)).abs() <= 1e-12 * x.pdf
                && pdf_ok(x.wo, x.pdf)
                && (x.weight.0[0] * x.pdf - f).abs() <= 1e-9 * f;
            if !ok {
                println!(
                    "sample: pdf {} (pdf() {}, Walter {}), weight·pdf {} vs eval {f}, walk {:?}",
                    x.pdf,
                    a.pdf(m, wi, x.wo),
                    density(x.wo),
                    x.weight.0[0] * x.pdf,
                    y.map(|y| y.wo)
                );
            }
            ok
        }
        (None, None) => true,
        (None, Some(_)) => false,
    };
    (same_pdf, same_sample)
}

/// Reduced dielectric calls (`auto`'s order 1 in closed form, both sides of the surface), per configuration:
/// the cap is 1 there (asserted), and
/// - the sampler draws from the density `pdf` reports: Pearson's χ² (tests/common/chi2.rs), Šidák over the
///   configurations at a family-wise 1e-3;
/// - its expectation is the capped walk's (`correlated` with max_bounces 1: a random exit in place of its
///   probability) for test functions g of ω_o — E[g·weight] of both samplers, independent streams, within
///   their standard errors (`Checker`, family-wise 3σ), Radiance mode in one case.
#[test]
fn dielectric_order_one_sampler() {
    use common::chi2::{chi2_of, chi2_p_value};
    // (distribution, α, tolerance, ω_i, Radiance mode)
    let configs = [
        (Distribution::Ggx, 0.3, 0.05, dir(0.7, 0.4), false),
        (Distribution::Beckmann, 0.3, 0.05, -dir(0.5, 1.1), false),
        (Distribution::Ggx, 0.2, 0.2, -dir(1.0, 2.0), true),
        (Distribution::Beckmann, 0.5, 0.05, dir(1.0, 0.0), false),
        (Distribution::Beckmann, 0.1, 0.01, dir(1.1, 0.3), true),
    ];
    let level = 1.0 - (1.0 - 1e-3f64).powf(1.0 / configs.len() as f64);
    let mut ck = Checker::new("auto's reduced dielectric calls: sampler against its pdf (χ²) and the capped walk's expectation");
    let n = 400_000;
    for (i, &(dist, alpha, tol, wi, radiance)) in configs.iter().enumerate() {
        let mut m = material(Surface::Dielectric, alpha, alpha, 1.5);
        m.radiance = radiance;
        let label = format!("{dist:?} α {alpha} tol {tol} ω_i {wi:.3}{}", if radiance { " radiance" } else { "" });
        ck.assert(&format!("{label}: reduced to order 1"), cap(Surface::Dielectric, dist, &m, wi, tol, 64) == 1);
        let a = bsdf(Surface::Dielectric, dist, Model::Auto, 64, tol);
        let (stat, dof, worst) = chi2_of(&a, &a, &m, wi, 4100 + i as u64, 2_000_000);
        let p = chi2_p_value(stat, dof);
        println!("{label}: χ² = {stat:.1}, {dof} dof, p = {p:.4} (bound {level:.2e}); largest |O − E|/√E = {worst:.2}");
        ck.assert(&format!("{label}: χ² p = {p:.3e} > {level:.2e}"), p > level);
        let c = bsdf(Surface::Dielectric, dist, Model::Correlated, 1, tol);
        // g: 1, x, z, the transmitted part.
        let g = |w: DVec3| [1.0, w.x, w.z, if w.z * wi.z < 0.0 { 1.0 } else { 0.0 }];
        let mean = |b: &Bsdf, seed: u64| {
            let mut st = [Stat::default(); 4];
            let mut rng = Sampler::new(seed + seed_offset());
            for _ in 0..n {
                let (s1, s2) = (rng.next(), rng.next2());
                let s = b.sample(&m, wi, s1, s2);
                for (k, st) in st.iter_mut().enumerate() {
                    st.push(s.map_or(0.0, |s| g(s.wo)[k] * s.weight.0[0]));
                }
            }
            st
        };
        let (closed, walk) = (mean(&a, 4200 + 2 * i as u64), mean(&c, 4201 + 2 * i as u64));
        for (k, what) in ["1", "x", "z", "across"].iter().enumerate() {
            println!(
                "{label} E[{what}·weight]: closed {:.5} ± {:.1e}, walk {:.5} ± {:.1e}",
                closed[k].mean(),
                closed[k].se(),
                walk[k].mean(),
                walk[k].se()
            );
            ck.close(&format!("{label} E[{what}·weight]"), closed[k].est(), walk[k].est(), 0.0, 0.0);
        }
        ck.assert(&format!("{label}: the closed form has less variance"), closed[0].var() < walk[0].var());
    }
    ck.finish();
}

/// The energy auto omits, (E_full − E_auto)/E_full, measured with fresh walks of
/// the full correlated sampler (its orders and weights: copper's Fresnel,
/// albedo 0.5, glass), at points between the table nodes, is at most the
/// tolerance (one-sided, z·σ).
#[test]
fn omitted_energy_within_tolerance() {
    let mut ck = Checker::new("omitted energy of auto ≤ tolerance (independent walks, real materials)");
    let n = 60_000;
    let mut seed = 100u64;
    let mut worst = (0.0f64, String::new());
    for surface in SURFACES {
        for dist in DISTS {
            for &alpha in &[0.013, 0.07, 0.23, 0.61, 1.7] {
                for &(mu, below) in &[(0.93f64, false), (0.41, false), (0.12, false), (0.63, true)] {
                    if below && surface != Surface::Dielectric {
                        continue;
                    }
                    for &tol in &[0.01, 0.05] {
                        let m = material(surface, alpha, alpha, 1.5);
                        let wi = {
                            let d = dir(mu.acos(), 0.3);
                            if below {
                                DVec3::new(d.x, d.y, -d.z)
                            } else {
                                d
                            }
                        };
                        let k = cap(surface, dist, &m, wi, tol, 64);
                        let full = bsdf(surface, dist, Model::Correlated, 64, 0.01);
                        // Ratio estimator of Σ w·[order > k] / Σ w over the full walks.
                        seed += 1;
                        let mut rng = Sampler::new(seed);
                        let (mut sw, mut so, mut sww, mut soo, mut swo) = (0.0, 0.0, 0.0, 0.0, 0.0);
                        for _ in 0..n {
                            let (s1, s2) = (rng.next(), (rng.next(), rng.next()));
                            let (w, omitted) = match full.sample(&m, wi, s1, s2) {
                                Some(s) => {
                                    let w = s.weight.0[0];
                                    // The order of the sample: auto (cap k) returns the same
                                    // sample iff the walk left within k bounces.
                                    let a = bsdf(surface, dist, Model::Correlated, k, 0.01).sample(&m, wi, s1, s2);
                                    (w, if a.is_some() { 0.0 } else { w })
                                }
                                None => (0.0, 0.0),
                            };
                            sw += w;
                            so += omitted;
                            sww += w * w;
                            soo += omitted * omitted;
                            swo += w * omitted;
                        }
                        let nf = n as f64;
                        let (mw, mo) = (sw / nf, so / nf);
                        let r = mo / mw;
                        // Delta-method variance of the ratio of means.
                        let (vw, vo, cwo) = (sww / nf - mw * mw, soo / nf - mo * mo, swo / nf - mw * mo);
                        let var_r = (vo - 2.0 * r * cwo + r * r * vw) / (mw * mw * nf);
                        let se = var_r.max(0.0).sqrt();
                        let tag = format!("{surface:?} {dist:?} α={alpha} μ={mu}{} tol={tol}: cap {k}", if below { " (inside)" } else { "" });
                        if r - tol > worst.0 {
                            worst = (r - tol, tag.clone());
                        }
                        ck.at_most(&tag, (r, se), tol);
                    }
                }
            }
        }
    }
    println!("largest omitted − tolerance: {:.2e} ({})", worst.0, worst.1);
    ck.finish();
}

/// Smooth surfaces: the cap is 1, and auto is the deterministic order-1 model
/// (Walter 2007 with the height-correlated G2) — zero variance.
#[test]
fn smooth_surfaces_get_order_one() {
    let mut ck = Checker::new("smooth surfaces: auto = deterministic order 1");
    for surface in [Surface::Conductor, Surface::Dielectric] {
        for dist in DISTS {
            let m = material(surface, 0.01, 0.01, 1.5);
            let a = bsdf(surface, dist, Model::Auto, 64, 0.01);
            let c = bsdf(surface, dist, Model::Correlated, 64, 0.01);
            let mut rng = Sampler::new(3);
            for _ in 0..200 {
                let wi = dir(rng.next().acos().min(1.3), 0.0);
                let d = dir(rng.next().acos().min(1.3), 2.0 * PI * rng.next());
                let wo = if surface == Surface::Dielectric && rng.next() < 0.5 { DVec3::new(d.x, d.y, -d.z) } else { d };
                let k = cap(surface, dist, &m, wi, 0.01, 64);
                let v1 = a.eval(&m, wi, wo, 1).0;
                let v2 = a.eval(&m, wi, wo, 2).0;
                let order1 = c.eval_orders(&m, wi, wo, 3, (1, 1)).0;
                ck.assert(
                    &format!("{surface:?} {dist:?} wi={wi:.3} wo={wo:.3}: cap {k}, {v1:?} vs order 1 {order1:?}"),
                    k == 1 && v1 == v2 && v1 == order1,
                );
            }
        }
    }
    ck.finish();
}

#[test]
fn tolerance_is_validated() {
    let mut ck = Checker::new("auto_tolerance validation");
    for tol in [0.0, -0.1, 1.0, 2.0, f64::NAN, f64::INFINITY] {
        let e = Bsdf::new(Config { model: Model::Auto, tolerance: tol, ..Config::default() }).err();
        ck.assert(&format!("tolerance {tol} rejected naming auto_tolerance: {e:?}"), e.is_some_and(|e| e.parameter == "auto_tolerance"));
    }
    ck.assert("0.2 accepted", Bsdf::new(Config { model: Model::Auto, tolerance: 0.2, ..Config::default() }).is_ok());
    // Through the C ABI: a tolerance with another model is an error naming it.
    let mut p = msx::ffi::MsxParams {
        surface: msx::ffi::MSX_SURFACE_CONDUCTOR,
        distribution: msx::ffi::MSX_DISTRIBUTION_GGX,
        model: msx::ffi::MSX_MODEL_CORRELATED,
        estimator: msx::ffi::MSX_ESTIMATOR_PT,
        max_bounces: 0,
        channels: 3,
        seed: 0,
        auto_tolerance: 0.05,
        mis_density: 0,
        sample_all_normals: 0,
    };
    let mut out: *mut msx::ffi::MsxBsdf = std::ptr::null_mut();
    let mut err = [0 as std::os::raw::c_char; 256];
    let rc = msx::ffi::msx_bsdf_new(&p, &mut out, err.as_mut_ptr(), err.len());
    let msg = unsafe { std::ffi::CStr::from_ptr(err.as_ptr()) }.to_string_lossy().into_owned();
    ck.assert(
        &format!("auto_tolerance with model correlated: rc {rc}, '{msg}'"),
        rc == msx::ffi::MSX_ERR_INVALID_PARAMETER && msg.contains("auto_tolerance"),
    );
    p.model = msx::ffi::MSX_MODEL_AUTO;
    let rc = msx::ffi::msx_bsdf_new(&p, &mut out, err.as_mut_ptr(), err.len());
    ck.assert("auto with auto_tolerance 0.05 accepted", rc == msx::ffi::MSX_OK && !out.is_null());
    msx::ffi::msx_bsdf_free(out);
    ck.finish();
}

/// The rule is a bound: at random (α, μ_i) it accepts — α drawn near its
/// threshold, where a violation would show, IORs between the rule's nodes —
/// an independent estimate of the multiply scattered fraction T₁ (F = 1) with
/// more samples than the rule's own (128 × 128 jittered visible normals, other
/// random numbers) is at most the tolerance (one-sided, z·σ of its own standard
/// error). And the rule is no more conservative than measured on the case
/// issue 31 names (Beckmann α = 0.1, the copper of Mitsuba's material preview).
#[test]
fn rule_is_a_bound_at_random_points() {
    use auto::table::{ms_fraction, MU};
    let mut ck = Checker::new("auto's rule: independent T₁ ≤ tolerance where it accepts");
    let mut rng = Sampler::new(31);
    let mut stream = 1000u64;
    let mut worst = (f64::NEG_INFINITY, String::new());
    for tol in [0.01, 0.05] {
        for surface in SURFACES {
            for dist in DISTS {
                // 1/1.33: water seen from inside, near total internal reflection.
                let etas: &[f64] = if surface == Surface::Dielectric { &[1.5, 1.0 / 1.5, 1.0 / 1.33] } else { &[1.0] };
                for &eta in etas {
                    let rule = auto::OrderOneRule::new(surface, dist, tol);
                    let thresholds = rule.thresholds(eta);
                    let (mut points, mut tries) = (0, 0);
                    while points < 12 && tries < 100_000 {
                        tries += 1;
                        let mu = rng.gen_range(MU.node(0), 1.0);
                        let Some(cell) = auto::table::mu_cell(mu) else { continue };
                        let t = thresholds[cell];
                        if !(t > 0.0) {
                            continue;
                        }
                        // α log-uniform over [t/4, t]: mostly near the threshold.
                        let alpha = t * 4f64.powf(-rng.next());
                        ck.assert(
                            &format!("{surface:?} {dist:?} η {eta:.3} α {alpha:.4} μ {mu:.4}: accepted"),
                            rule.order_one_suffices(alpha, mu, eta),
                        );
                        stream += 1;
                        let (t1, se) = ms_fraction(surface, dist, eta, alpha, mu, 128, stream);
                        let tag = format!("{surface:?} {dist:?} tol {tol} η {eta:.3} α {alpha:.4} (threshold {t:.4}) μ {mu:.4}");
                        if t1 - tol > worst.0 {
                            worst = (t1 - tol, tag.clone());
                        }
                        ck.at_most(&tag, (t1, se), tol);
                        points += 1;
                    }
                    ck.assert(&format!("{surface:?} {dist:?} tol {tol} η {eta:.3}: 12 accepted points found"), points == 12);
                }
            }
        }
    }
    println!("largest T₁ − tolerance: {:.2e} ({})", worst.0, worst.1);
    // Beckmann α = 0.1, copper, tolerance 1 %: the share of μ_i ∈ [0, 1] where order 1 alone is
    // accepted, measured 0.646 (μ_i ≥ 0.354; the rule before, four-corner cells of a 24 × 16 grid:
    // 0.483, μ_i ≥ 0.517). T₁ itself reaches 1 % at μ_i ≈ 0.32 (no rule can accept more than ≈ 0.68).
    let rule = auto::OrderOneRule::new(Surface::Conductor, Distribution::Beckmann, 0.01);
    let n = 100_000;
    let accepted = (0..n).filter(|&k| rule.order_one_suffices(0.1, (k as f64 + 0.5) / n as f64, 1.0)).count() as f64 / n as f64;
    println!("Beckmann α 0.1 conductor, tolerance 1 %: order 1 accepted for {:.1} % of μ_i ∈ [0, 1]", 100.0 * accepted);
    ck.assert(&format!("Beckmann α 0.1: accepted share of μ_i {accepted:.3} ≥ 0.64 (measured 0.646)"), accepted >= 0.64);
    ck.finish();
}

/// Measurement behind the rule's design (module docs; run with `--ignored --nocapture`),
/// printed, not asserted. Per row: α log grid 0.005…4 (48), μ log grid 0.02…1 (48). A decrease in α = T(α_k) below the running
/// max over α_j < α_k by > 3σ (combined SE); an increase in μ = T(μ_k) above the running min over μ_j < μ_k
/// by > 3σ. Only cells with T ≤ 0.3 counted.
#[test]
#[ignore]
#[allow(clippy::needless_range_loop)] // indices are grid coordinates here
fn measure_t1_monotonicity() {
    let n = 48;
    let alpha = |a: usize| (0.005f64.ln() + (4f64.ln() - 0.005f64.ln()) * a as f64 / (n - 1) as f64).exp();
    let mu = |i: usize| (0.02f64.ln() * (1.0 - i as f64 / (n - 1) as f64)).exp();
    let mut rows: Vec<(Surface, Distribution, f64)> = vec![];
    for d in [Distribution::Beckmann, Distribution::Ggx] {
        rows.push((Surface::Conductor, d, 1.0));
        rows.push((Surface::Diffuse, d, 1.0));
        for k in -6..=6 {
            rows.push((Surface::Dielectric, d, (3f64.ln() * k as f64 / 6.0).exp()));
            // 1/3 … 3
        }
        for eta in [1.5, 1.0 / 1.5, 1.33, 1.0 / 1.33] {
            rows.push((Surface::Dielectric, d, eta));
        }
    }
    for (s, d, eta) in rows {
        let side = if s == Surface::Diffuse { 64 } else { 32 };
        let v: Vec<Vec<(f64, f64)>> =
            (0..n).map(|a| (0..n).map(|i| auto::table::ms_fraction(s, d, eta, alpha(a), mu(i), side, 0)).collect()).collect();
        // α direction, per μ.
        let (mut na, mut mu_hi_a, mut worst_a) = (0, 0.0f64, (0.0f64, String::new()));
        for i in 0..n {
            let mut best = v[0][i];
            for a in 1..n {
                let (t, se) = v[a][i];
                if t <= 0.3 {
                    let z = (best.0 - t) / best.1.hypot(se).max(1e-12);
                    if best.0 - t > 1e-9 && z > 3.0 {
                        na += 1;
                        mu_hi_a = mu_hi_a.max(mu(i));
                        if best.0 - t > worst_a.0 {
                            worst_a = (best.0 - t, format!("μ {:.3}: α {:.3} {:.4} < max below {:.4}", mu(i), alpha(a), t, best.0));
                        }
                    }
                }
                if t > best.0 {
                    best = (t, se);
                }
            }
        }
        // μ direction, per α.
        let (mut nm, mut mu_hi_m, mut worst_m) = (0, 0.0f64, (0.0f64, String::new()));
        for a in 0..n {
            let mut low = v[a][0];
            for i in 1..n {
                let (t, se) = v[a][i];
                if low.0 <= 0.3 {
                    let z = (t - low.0) / low.1.hypot(se).max(1e-12);
                    if t - low.0 > 1e-9 && z > 3.0 {
                        nm += 1;
                        mu_hi_m = mu_hi_m.max(mu(i));
                        if t - low.0 > worst_m.0 {
                            worst_m = (t - low.0, format!("α {:.3}: μ {:.3} {:.4} > min at smaller μ {:.4}", alpha(a), mu(i), t, low.0));
                        }
                    }
                }
                if t < low.0 {
                    low = (t, se);
                }
            }
        }
        println!("{s:?} {d:?} η {eta:.3}: α-decreases {na} (up to μ {mu_hi_a:.3}; largest {:.3} {}) | μ-increases {nm} (up to μ {mu_hi_m:.3}; largest {:.3} {})", worst_a.0, worst_a.1, worst_m.0, worst_m.1);
    }
}

/// Measurement (run with `--ignored --nocapture`; ≈ 20 s): every cell of the rule at its threshold
/// and at 0.7 × it, at both ends and three interior μ, for three tolerances: an independent T₁
/// (64 × 64 visible normals, other random numbers) against the tolerance, printed with the counts above
/// it by more than 2σ and 3σ.
#[test]
#[ignore]
#[allow(clippy::needless_range_loop)] // indices are grid coordinates here
fn measure_every_cell_at_its_threshold() {
    let mut stream = 50_000u64;
    for tol in [0.01, 0.05, 0.2] {
        for (s, d, eta) in [
            (Surface::Conductor, Distribution::Beckmann, 1.0),
            (Surface::Conductor, Distribution::Ggx, 1.0),
            (Surface::Diffuse, Distribution::Beckmann, 1.0),
            (Surface::Diffuse, Distribution::Ggx, 1.0),
            (Surface::Dielectric, Distribution::Beckmann, 1.5),
            (Surface::Dielectric, Distribution::Beckmann, 1.0 / 1.5),
            (Surface::Dielectric, Distribution::Ggx, 1.5),
            (Surface::Dielectric, Distribution::Ggx, 1.0 / 1.5),
            (Surface::Dielectric, Distribution::Beckmann, 1.0 / 1.33),
        ] {
            let th = auto::OrderOneRule::new(s, d, tol).thresholds(eta);
            let (mut n, mut over2, mut over3, mut worst) = (0, 0, 0, (f64::NEG_INFINITY, String::new()));
            for c in 0..64 {
                if th[c] <= 0.0 {
                    continue;
                }
                let (x0, x1) = (auto::table::MU.node(c).powi(2), auto::table::MU.node(c + 1).powi(2));
                for k in 0..5 {
                    let mu = (x0 + (x1 - x0) * k as f64 / 4.0).sqrt();
                    for alpha in [th[c], th[c] * 0.7] {
                        stream += 1;
                        let (t, se) = auto::table::ms_fraction(s, d, eta, alpha, mu, 64, stream);
                        let z = (t - tol) / se.max(1e-12);
                        n += 1;
                        if z > 2.0 {
                            over2 += 1;
                        }
                        if z > 3.0 {
                            over3 += 1;
                        }
                        if t - tol > worst.0 {
                            worst = (t - tol, format!("cell {c} μ {mu:.3} α {alpha:.4}: {t:.4} ± {se:.4}"));
                        }
                    }
                }
            }
            println!(
                "tol {tol} {s:?} {d:?} η {eta:.3}: {n} points, {over2} above tol by > 2σ, {over3} by > 3σ; largest T₁ − tol {:.4} ({})",
                worst.0, worst.1
            );
        }
    }
}
