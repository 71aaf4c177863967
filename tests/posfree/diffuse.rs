//! Position-free rough diffuse microsurface (`models::posfree::diffuse`): white
//! furnace from eval integration and from the mean sample weight, reciprocity of
//! the uncorrelated model, sampled moments = eval integration (Heitz 2016
//! supplement §4.4.4), order 1 = single-scattering diffuse microfacet BRDF with
//! the matching G (reference by numerical integration over m, written here
//! from Heitz §3.3 with `crate::common::ref_d` / `crate::common::ref_lambda`).
//!
//! Statistical checks: |estimate − expected| ≤ z·σ (+ stated allowance), σ the
//! combined Monte Carlo standard error, z the family-wise 3σ level of
//! `crate::common::family_sigmas`. Run with `--nocapture` for the measured values.

// Lints relaxed for this test file: per-channel statistics indexed by channel.
#![allow(clippy::needless_range_loop)]

use crate::common::*;
use crate::shared::*;
use glam::DVec3;
use msx::models::posfree::diffuse::{eval_pt, sample_walk};
use msx::models::posfree::{Options, Segments};
use msx::rng::Sampler;
use msx::walk::WalkOptions;
use msx::{Distribution, Microfacet, Spectrum};
use std::f64::consts::PI;

const MAX_BOUNCES: u32 = 1024;

fn opts(segments: Segments, orders: (u32, u32)) -> Options {
    Options { segments, walk: WalkOptions { max_bounces: MAX_BOUNCES, orders } }
}

const SEGS: [Segments; 2] = [Segments::Uncorrelated, Segments::Correlated];
const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];

/// Mean sample weight per channel (a failed walk counts 0) and the moments
/// E[w·g(ω_o)] for g in `moments`.
fn sample_stats(mf: &Microfacet, albedo: Spectrum, wi: DVec3, o: &Options, n: usize, seed: u64, moments: &[fn(DVec3) -> f64]) -> Vec<[Stat; 3]> {
    let mut rng = Sampler::new(seed);
    let mut st = vec![[Stat::default(); 3]; moments.len()];
    for _ in 0..n {
        let first = (rng.next(), rng.next(), rng.next());
        let r = sample_walk(mf, albedo, wi, first, o, &mut rng);
        for (k, g) in moments.iter().enumerate() {
            for c in 0..3 {
                let v = match r {
                    Some((wo, w, _)) => w.0[c] * g(wo),
                    None => 0.0,
                };
                st[k][c].push(v);
            }
        }
    }
    st
}

/// ∫ g(ω_o)·eval(ω_i, ω_o) dω_o, ω_o from an even mixture of the cosine and
/// the uniform hemisphere (the uniform part bounds eval/pdf at grazing ω_o,
/// where the correlated model's later orders do not vanish like cos θ_o and a
/// pure cosine proposal gives heavy tails), per channel.
fn eval_stats(mf: &Microfacet, albedo: Spectrum, wi: DVec3, o: &Options, n: usize, seed: u64, moments: &[fn(DVec3) -> f64]) -> Vec<[Stat; 3]> {
    let mut rng = Sampler::new(seed);
    let mut st = vec![[Stat::default(); 3]; moments.len()];
    for _ in 0..n {
        let (u1, u2) = rng.next2();
        let wo = if rng.next() < 0.5 { cosine_hemisphere(u1, u2) } else { uniform_hemisphere_around(DVec3::Z, u1, u2) };
        let pdf = 0.5 * (wo.z / PI + UNIFORM_HEMISPHERE_PDF);
        let v = if pdf > 0.0 { eval_pt(mf, albedo, wi, wo, o, &mut rng) * (1.0 / pdf) } else { Spectrum::ZERO };
        for (k, g) in moments.iter().enumerate() {
            for c in 0..3 {
                st[k][c].push(v.0[c] * g(wo));
            }
        }
    }
    st
}

#[test]
fn diffuse_furnace() {
    let mut ck = Checker::new("diffuse microsurface, albedo 1: ∫ eval dω_o = 1 and mean sample weight = 1");
    let (n_eval, n_sample) = (300_000, 40_000);
    let one: [fn(DVec3) -> f64; 1] = [|_| 1.0];
    let mut seed = 1u64;
    for seg in SEGS {
        for dist in DISTS {
            for alpha in [0.1, 0.5, 1.0, 2.0] {
                let mf = Microfacet::new(dist, alpha, alpha);
                for theta in [0.0, 1.0, 1.45] {
                    let wi = dir(theta, 0.3);
                    let o = opts(seg, (1, MAX_BOUNCES));
                    seed += 2;
                    let e = eval_stats(&mf, Spectrum::ONE, wi, &o, n_eval, seed, &one);
                    let s = sample_stats(&mf, Spectrum::ONE, wi, &o, n_sample, seed + 1, &one);
                    let label = format!("{} {} α={alpha} θ_i={theta}", seg_name(seg), dist_name(dist));
                    ck.close(&format!("{label} eval-integrated"), e[0][0].est(), exact(1.0), 0.003, 0.0);
                    ck.close(&format!("{label} mean sample weight"), s[0][0].est(), exact(1.0), 0.003, 0.0);
                }
            }
        }
    }
    ck.finish();
}

#[test]
fn diffuse_reciprocity_uncorrelated() {
    let mut ck = Checker::new("diffuse, uncorrelated: f(ω_i, ω_o) = f(ω_o, ω_i)");
    let n = 60_000;
    let albedo = Spectrum([0.9, 0.6, 0.3, 1.0]);
    let pairs = [(dir(0.2, 0.0), dir(1.2, 2.5)), (dir(0.7, 0.0), dir(0.7, PI)), (dir(1.4, 0.0), dir(0.4, 1.0)), (dir(1.0, 0.5), dir(1.45, -2.0))];
    let mut seed = 300u64;
    let mut cor_asym = 0.0f64;
    for dist in DISTS {
        for alpha in [0.3, 1.0, 2.0] {
            let mf = Microfacet::new(dist, alpha, alpha);
            for (pi, &(wi, wo)) in pairs.iter().enumerate() {
                for seg in SEGS {
                    let o = opts(seg, (1, MAX_BOUNCES));
                    let mut fwd = [Stat::default(); 3];
                    let mut bwd = [Stat::default(); 3];
                    seed += 2;
                    let mut r1 = Sampler::new(seed);
                    let mut r2 = Sampler::new(seed + 1);
                    for _ in 0..n {
                        // f = eval/cos θ_o; compare eval(wi,wo)·cos θ_i with eval(wo,wi)·cos θ_o.
                        let a = eval_pt(&mf, albedo, wi, wo, &o, &mut r1) * wi.z;
                        let b = eval_pt(&mf, albedo, wo, wi, &o, &mut r2) * wo.z;
                        for c in 0..3 {
                            fwd[c].push(a.0[c]);
                            bwd[c].push(b.0[c]);
                        }
                    }
                    match seg {
                        Segments::Uncorrelated => {
                            for c in [0, 2] {
                                let label = format!("{} α={alpha} pair {pi} ch{c}", dist_name(dist));
                                ck.close(&label, fwd[c].est(), bwd[c].est(), 0.0, 0.0);
                            }
                        }
                        Segments::Correlated => {
                            let r = fwd[0].mean() / bwd[0].mean() - 1.0;
                            println!(
                                "(info) correlated {} α={alpha} pair {pi}: f(wi,wo)/f(wo,wi) − 1 = {r:+.4} (± {:.4})",
                                dist_name(dist),
                                (fwd[0].se() / fwd[0].mean()).hypot(bwd[0].se() / bwd[0].mean())
                            );
                            cor_asym = cor_asym.max(r.abs());
                        }
                    }
                }
            }
        }
    }
    println!("(info) largest |f(wi,wo)/f(wo,wi) − 1| of the correlated diffuse model: {cor_asym:.4}");
    ck.finish();
}

#[test]
fn diffuse_sampled_moments() {
    let mut ck = Checker::new("diffuse: sampled moments E[w·g(ω_o)] = ∫ g·eval dω_o (albedo 0.9/0.6/0.3)");
    let n = 60_000;
    let albedo = Spectrum([0.9, 0.6, 0.3, 1.0]);
    let moments: [fn(DVec3) -> f64; 5] = [|_| 1.0, |w| w.x, |w| w.y, |w| w.z, |w| w.z * w.z];
    let names = ["1", "x", "y", "z", "z²"];
    let mut seed = 700u64;
    for seg in SEGS {
        for dist in DISTS {
            for alpha in [0.5, 1.5] {
                let mf = Microfacet::new(dist, alpha, alpha);
                for theta in [0.5, 1.3] {
                    let wi = dir(theta, 0.8);
                    let o = opts(seg, (1, MAX_BOUNCES));
                    seed += 2;
                    let e = eval_stats(&mf, albedo, wi, &o, n, seed, &moments);
                    let s = sample_stats(&mf, albedo, wi, &o, n, seed + 1, &moments);
                    for k in 0..moments.len() {
                        for c in [0, 2] {
                            let label = format!("{} {} α={alpha} θ_i={theta} moment {} ch{c}", seg_name(seg), dist_name(dist), names[k]);
                            ck.close(&label, s[k][c].est(), e[k][c].est(), 0.0, 1e-12);
                        }
                    }
                }
            }
        }
    }
    ck.finish();
}

/// ∫ ⟨ω_o, m⟩⁺ ⟨ω_i, m⟩⁺ D(m) dm over the upper hemisphere by the midpoint rule
/// in (u, φ) with θ_m = atan(α·tan(πu/2)) (resolves the peak of D for small α).
fn diffuse_integral(dist: Distribution, alpha: f64, wi: DVec3, wo: DVec3) -> f64 {
    let (nu, nphi) = (1500usize, 400usize);
    let du = 1.0 / nu as f64;
    let dphi = 2.0 * PI / nphi as f64;
    let mut sum = 0.0;
    for iu in 0..nu {
        let u = (iu as f64 + 0.5) * du;
        let s = (0.5 * PI * u).tan();
        let theta = (alpha * s).atan();
        let sec2 = 1.0 + s * s;
        let dtheta_du = alpha * 0.5 * PI * sec2 / (1.0 + alpha * alpha * s * s);
        let (st, ct) = theta.sin_cos();
        let mut ring = 0.0;
        for ip in 0..nphi {
            let phi = (ip as f64 + 0.5) * dphi;
            let m = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
            let a = wi.dot(m);
            let b = wo.dot(m);
            if a > 0.0 && b > 0.0 {
                ring += a * b * ref_d(dist, alpha, alpha, m);
            }
        }
        sum += ring * st * dtheta_du;
    }
    sum * du * dphi
}

#[test]
fn diffuse_order1_is_single_scattering() {
    let mut ck = Checker::new("diffuse order 1 = (a/π)∫⟨o,m⟩⟨i,m⟩D dm · G / cos θ_i (G1·G1 unc, G2 cor)");
    let n = 60_000;
    let albedo = Spectrum([0.8, 0.8, 0.8, 1.0]);
    let pairs = [(dir(0.3, 0.0), dir(0.9, 2.0)), (dir(1.0, 0.0), dir(1.0, PI)), (dir(1.45, 0.0), dir(0.6, 0.5))];
    let mut seed = 900u64;
    // Sanity of the quadrature: ∫⟨z,m⟩D dm = 1 and ∫⟨ω,m⟩⁺D dm = A(ω) = cos θ (1 + Λ(ω)).
    for dist in DISTS {
        for alpha in [0.1, 2.0] {
            let w = dir(0.9, 0.0);
            let z_area = diffuse_integral_proj(dist, alpha, DVec3::Z);
            let w_area = diffuse_integral_proj(dist, alpha, w);
            let lam = ref_lambda(dist, alpha, alpha, w);
            ck.close(&format!("quadrature ∫cos θ_m D dm = 1 ({} α={alpha})", dist_name(dist)), exact(z_area), exact(1.0), 1e-5, 0.0);
            ck.close(&format!("quadrature A(ω) = cos θ(1+Λ) ({} α={alpha})", dist_name(dist)), exact(w_area), exact(w.z * (1.0 + lam)), 1e-4, 0.0);
        }
    }
    for seg in SEGS {
        for dist in DISTS {
            for alpha in [0.1, 0.5, 1.0, 2.0] {
                let mf = Microfacet::new(dist, alpha, alpha);
                for (pi, &(wi, wo)) in pairs.iter().enumerate() {
                    let li = ref_lambda(dist, alpha, alpha, wi);
                    let lo = ref_lambda(dist, alpha, alpha, wo);
                    let g = match seg {
                        Segments::Uncorrelated => 1.0 / ((1.0 + li) * (1.0 + lo)),
                        Segments::Correlated => 1.0 / (1.0 + li + lo),
                    };
                    let expected = albedo.0[0] / PI * diffuse_integral(dist, alpha, wi, wo) * g / wi.z;
                    let o = opts(seg, (1, 1));
                    seed += 1;
                    let mut rng = Sampler::new(seed);
                    let mut st = Stat::default();
                    for _ in 0..n {
                        st.push(eval_pt(&mf, albedo, wi, wo, &o, &mut rng).0[0]);
                    }
                    let label = format!("{} {} α={alpha} pair {pi}", seg_name(seg), dist_name(dist));
                    ck.close(&label, st.est(), exact(expected), 2e-4, 1e-12);
                }
            }
        }
    }
    ck.finish();
}

/// ∫ ⟨ω, m⟩⁺ D(m) dm with the quadrature of [`diffuse_integral`].
fn diffuse_integral_proj(dist: Distribution, alpha: f64, w: DVec3) -> f64 {
    let (nu, nphi) = (1500usize, 400usize);
    let du = 1.0 / nu as f64;
    let dphi = 2.0 * PI / nphi as f64;
    let mut sum = 0.0;
    for iu in 0..nu {
        let u = (iu as f64 + 0.5) * du;
        let s = (0.5 * PI * u).tan();
        let theta = (alpha * s).atan();
        let dtheta_du = alpha * 0.5 * PI * (1.0 + s * s) / (1.0 + alpha * alpha * s * s);
        let (st, ct) = theta.sin_cos();
        let mut ring = 0.0;
        for ip in 0..nphi {
            let phi = (ip as f64 + 0.5) * dphi;
            let m = DVec3::new(st * phi.cos(), st * phi.sin(), ct);
            let a = w.dot(m);
            if a > 0.0 {
                ring += a * ref_d(dist, alpha, alpha, m);
            }
        }
        sum += ring * st * dtheta_du;
    }
    sum * du * dphi
}
