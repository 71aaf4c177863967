//! `single` on rough dielectrics: Mitsuba's roughdielectric, Walter 2007 with
//! the separable G, against closed forms written here from the paper
//! (deterministic), and its sample/eval/pdf consistency. (`single` on
//! conductors is order 1 of the position-free models: tests/posfree/conductor.rs;
//! both are compared with Mitsuba's own BSDFs in python_tests/.)

// Lints relaxed for this test file: angles near π/2 on purpose.
#![allow(clippy::approx_constant)]

mod common;

use common::dielectric::*;
use common::*;
use msx::microfacet::mitsuba::Sampling;
use msx::models::single::dielectric as sd;
use msx::rng::Sampler;
use msx::{Distribution, Microfacet};

const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];

// ---------------------------------------------------------------------------
// 1. single_dielectric against Walter 2007 (deterministic).

#[test]
fn single_dielectric_closed_form() {
    let mut ck = Checker::new("single_dielectric = Walter 2007 with Mitsuba's separable G (deterministic)");
    let mut rng = Sampler::new(11);
    let (mut worst_eval, mut worst_pdf, mut worst_rad, mut worst_ill, mut n_t, mut n_r) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0, 0);
    for dist in DISTS {
        for &alpha in &[0.05, 0.3, 1.0, 1.7] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for &eta in &[1.1, 1.5, 2.4, 0.7] {
                for _ in 0..2000 {
                    let wi = sphere_dir(&mut rng, 0.02);
                    let wo = sphere_dir(&mut rng, 0.02);
                    let h = walter_h(eta, wi, wo);
                    let g = ref_g1_mitsuba(dist, alpha, alpha, wi, h) * ref_g1_mitsuba(dist, alpha, alpha, wo, h);
                    let expected = walter(dist, alpha, alpha, eta, wi, wo, g, true);
                    let (v, is_r) = sd::eval(&mf, eta, wi, wo, false);
                    let (vr, _) = sd::eval(&mf, eta, wi, wo, true);
                    ck.assert("is_reflection flag", is_r == (wi.z * wo.z > 0.0));
                    let (ni, no) = sides(eta, wi, wo);
                    let good = well_conditioned(eta, wi, wo);
                    if good {
                        worst_eval = worst_eval.max(rel(v, expected));
                        worst_rad = worst_rad.max(rel(vr, expected * (ni / no).powi(2)));
                    } else {
                        worst_ill = worst_ill.max(rel(v, expected)).max(rel(vr, expected * (ni / no).powi(2)));
                    }
                    // pdf: D(h)·G1(ω_i)·|ω_i·h|/|cos θ_i| · (F or 1 − F) · |∂h/∂ω_o|.
                    let (ih, oh) = (wi.dot(h), wo.dot(h));
                    let mut p = 0.0;
                    if ih * wi.z > 0.0 && oh * wo.z > 0.0 {
                        let mut d = ref_d(dist, alpha, alpha, h);
                        if d * h.z <= 1e-20 {
                            d = 0.0;
                        }
                        let f = if ih > 0.0 { ref_fresnel(ih, eta) } else { ref_fresnel(-ih, 1.0 / eta) };
                        let pm = d * ref_g1_mitsuba(dist, alpha, alpha, wi, h) * ih.abs() / wi.z.abs();
                        p = if is_r {
                            n_r += 1;
                            pm * f / (4.0 * oh.abs())
                        } else {
                            n_t += 1;
                            let den = ni * ih + no * oh;
                            pm * (1.0 - f) * no * no * oh.abs() / (den * den)
                        };
                    }
                    if good {
                        worst_pdf = worst_pdf.max(rel(sd::pdf(&mf, eta, wi, wo), p));
                    } else {
                        worst_ill = worst_ill.max(rel(sd::pdf(&mf, eta, wi, wo), p));
                    }
                }
            }
        }
    }
    println!("{n_r} reflection and {n_t} transmission pairs with non-zero pdf");
    println!("eval (Importance) vs Walter: max rel dev {worst_eval:.3e}; Radiance = Importance·(η_i/η_o)²: {worst_rad:.3e}; pdf: {worst_pdf:.3e}");
    println!("transmission pairs within 1 % of total internal reflection (1 − F loses digits): max rel dev {worst_ill:.3e}");
    // Two algebraically equal formulas in double precision: D at α = 0.05 amplifies the
    // rounding of h (exponent tan²θ/α² up to ~10³), hence 1e-11 rather than 1e-12.
    ck.assert(&format!("eval = Walter ({worst_eval:.2e} ≤ 1e-11)"), worst_eval <= 1e-11);
    ck.assert(&format!("Radiance mode 1/η² ({worst_rad:.2e} ≤ 1e-11)"), worst_rad <= 1e-11);
    ck.assert(&format!("pdf closed form ({worst_pdf:.2e} ≤ 1e-11)"), worst_pdf <= 1e-11);
    ck.assert(&format!("near-critical pairs ({worst_ill:.2e} ≤ 1e-7)"), worst_ill <= 1e-7);
    ck.finish();
}

// ---------------------------------------------------------------------------
// 2. single_dielectric self-consistency: weight = eval/pdf, pdf integrates to
//    the mass of its valid samples.

#[test]
fn single_dielectric_sampling() {
    let mut ck = Checker::new("single_dielectric sample/eval/pdf consistency");
    let mut rng = Sampler::new(12);
    let mut worst_w = 0.0f64;
    let mut worst_p = 0.0f64;
    let n = 40_000;
    for dist in DISTS {
        for &alpha in &[0.1, 0.5, 1.0] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for &eta in &[1.5, 2.4] {
                for &theta in &[0.0, 1.0, 1.45] {
                    for inside in [false, true] {
                        let mut wi = dir(theta, 0.3);
                        if inside {
                            wi.z = -wi.z;
                        }
                        for radiance in [false, true] {
                            let mut valid = Stat::default();
                            for _ in 0..n {
                                let s1 = rng.next();
                                let (u1, u2) = rng.next2();
                                let Some((wo, pdf, weight, is_r)) = sd::sample(&mf, eta, Sampling::Visible, wi, (s1, u1, u2), radiance) else {
                                    valid.push(0.0);
                                    continue;
                                };
                                valid.push(if weight > 0.0 { 1.0 } else { 0.0 });
                                if weight > 0.0 {
                                    ck.assert("flag", is_r == (wi.z * wo.z > 0.0));
                                    let (v, _) = sd::eval(&mf, eta, wi, wo, radiance);
                                    let p = sd::pdf(&mf, eta, wi, wo);
                                    worst_w = worst_w.max(rel(weight, v / pdf));
                                    worst_p = worst_p.max(rel(pdf, p));
                                }
                            }
                            if radiance {
                                continue;
                            }
                            // ∫ pdf over the sphere with an independent proposal.
                            let prop = DielProposal::new(wi, eta, alpha);
                            let mut integral = Stat::default();
                            for _ in 0..n {
                                let v = match prop.sample(&mut rng) {
                                    Some(o) => {
                                        let q = prop.pdf(o);
                                        if q > 0.0 {
                                            sd::pdf(&mf, eta, wi, o) / q
                                        } else {
                                            0.0
                                        }
                                    }
                                    None => 0.0,
                                };
                                integral.push(v);
                            }
                            let tag = format!("{dist:?} α={alpha} η={eta} θ_i={theta} {}", if inside { "inside" } else { "outside" });
                            ck.close(&format!("{tag}: ∫pdf = P(valid sample)"), integral.est(), valid.est(), 0.0, 0.0);
                        }
                    }
                }
            }
        }
    }
    println!("weight vs eval/pdf: max rel dev {worst_w:.3e}; sample pdf vs pdf(): {worst_p:.3e}");
    ck.assert(&format!("weight = eval/pdf ({worst_w:.2e} ≤ 1e-9)"), worst_w <= 1e-9);
    ck.assert(&format!("sample pdf = pdf() ({worst_p:.2e} ≤ 1e-9)"), worst_p <= 1e-9);
    ck.finish();
}
