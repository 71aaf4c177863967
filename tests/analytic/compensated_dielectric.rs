//! Energy compensation of rough dielectrics (Turquin 2019 / Kulla-Conty 2017):
//! the single-scattering lobe of `single_dielectric` scaled by 1/E(μ_i, α, η_r).
//!
//! Checked: the albedo table equals an independent Monte Carlo estimate of the
//! integral of `single_dielectric::eval` (Importance mode); the compensated
//! furnace albedo E_r + E_t is 1 from outside and from inside; the compensated
//! lobe is ≥ the single lobe; sample weights equal eval/pdf; no NaN or negative
//! values over extreme parameters.
//!
//! Tolerances: 3σ of the Monte Carlo standard error (family-wise in
//! `Checker::finish`) plus an allowance fixed before measuring: the table is
//! trilinear on a 32 (μ) × 32 (√α) × 32 (√(1 − 1/η²)) grid of a 28×28-point
//! warped product quadrature over visible normals; its interpolation +
//! quadrature error is allowed ALLOW_REL = 1.5 % of the value (the conductor
//! table of `compensated.rs` measured up to ~1 % between nodes on a
//! comparable grid). The deterministic part of the table error (table vs the
//! same quadrature with 64² normals at the query point) is printed.

use crate::common::{Checker, Stat, UNIFORM_SPHERE_PDF};
use glam::DVec3;
use msx::microfacet::fresnel::dielectric_full;
use msx::microfacet::mitsuba::Sampling;
use msx::microfacet::{reflect, refract};
use msx::models::analytic::compensated_dielectric as cd;
use msx::models::analytic::dielectric_albedo::{self as table, DielectricAlbedoTable};
use msx::models::single::dielectric as single_dielectric;
use msx::rng::Sampler;
use msx::{Distribution, Microfacet};
use std::time::Instant;

const ALLOW_REL: f64 = 0.015;
const DISTS: [Distribution; 2] = [Distribution::Ggx, Distribution::Beckmann];

fn dir(theta: f64, phi: f64) -> DVec3 {
    crate::common::dir(theta, phi)
}

/// Sphere proposal written for this test: with weight 0.1 the uniform sphere,
/// otherwise m from the exact visible-normal distribution of ω_i mirrored up,
/// then reflection (½) or refraction (½, nothing under total internal
/// reflection: a defective proposal, whose density below is still exact).
struct Proposal {
    mf: Microfacet,
    eta: f64,
    wi: DVec3,
}

impl Proposal {
    const U: f64 = 0.1;

    fn wi_up(&self) -> DVec3 {
        if self.wi.z < 0.0 {
            -self.wi
        } else {
            self.wi
        }
    }

    fn sample(&self, rng: &mut Sampler) -> Option<DVec3> {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < Self::U {
            return Some(crate::common::uniform_sphere(u1, u2));
        }
        let m = self.mf.sample_visible(self.wi_up(), u1, u2)?;
        if c < Self::U + 0.5 * (1.0 - Self::U) {
            Some(reflect(self.wi, m))
        } else {
            let (f, cos_t, _, eta_ti) = dielectric_full(self.wi.dot(m), self.eta);
            if f >= 1.0 {
                return None;
            }
            Some(refract(self.wi, m, cos_t, eta_ti))
        }
    }

    fn pdf(&self, wo: DVec3) -> f64 {
        let wi = self.wi;
        let half = 0.5 * (1.0 - Self::U);
        let mut p = Self::U * UNIFORM_SPHERE_PDF;
        let up = |h: DVec3| if h.z < 0.0 { -h } else { h };
        // Either branch can land on either side of the macrosurface: both are
        // tried for every ω_o and kept where they reproduce it.
        let h = wi + wo;
        if h.length() > 1e-12 {
            let m = up(h.normalize());
            if reflect(wi, m).dot(wo) > 1.0 - 1e-9 {
                p += half * self.mf.d_visible(self.wi_up(), m) / (4.0 * wo.dot(m).abs());
            }
        }
        // The sampled m faces ω_i's side, so the relative IOR is that of ω_i's side.
        let eta_r = if wi.z > 0.0 { self.eta } else { 1.0 / self.eta };
        let h = wi + eta_r * wo;
        if h.length() > 1e-12 {
            let m = up(h.normalize());
            let (f, cos_t, _, eta_ti) = dielectric_full(wi.dot(m), self.eta);
            if f < 1.0 && refract(wi, m, cos_t, eta_ti).dot(wo) > 1.0 - 1e-9 {
                let denom = wi.dot(m) + eta_r * wo.dot(m);
                let jac = eta_r * eta_r * wo.dot(m).abs() / (denom * denom);
                p += half * self.mf.d_visible(self.wi_up(), m) * jac;
            }
        }
        p
    }
}

/// (E_r, E_t, E_r + E_t) estimates of ∫ f(ω_i, ω_o)|cos θ_o| dω_o.
fn albedo(f: impl Fn(DVec3) -> f64, prop: &Proposal, n: usize, seed: u64) -> [(f64, f64); 3] {
    let mut rng = Sampler::new(seed);
    let (mut r, mut t, mut s) = (Stat::default(), Stat::default(), Stat::default());
    for _ in 0..n {
        let x = match prop.sample(&mut rng) {
            Some(wo) => {
                let p = prop.pdf(wo);
                let x = if p > 0.0 { f(wo) / p } else { 0.0 };
                (x, wo.z * prop.wi.z > 0.0)
            }
            None => (0.0, true),
        };
        r.push(if x.1 { x.0 } else { 0.0 });
        t.push(if x.1 { 0.0 } else { x.0 });
        s.push(x.0);
    }
    [r.est(), t.est(), s.est()]
}

fn incident(theta: f64, inside: bool) -> DVec3 {
    let w = dir(theta, 0.7);
    if inside {
        DVec3::new(w.x, w.y, -w.z)
    } else {
        w
    }
}

const ETAS: [f64; 3] = [1.1, 1.5, 2.4];
const ALPHAS: [f64; 3] = [0.1, 0.5, 1.0];
const THETAS: [f64; 3] = [0.0, 1.0, 1.45];

/// One configuration of the albedo checks, with its proposal and label.
struct Case {
    dist: Distribution,
    eta: f64,
    inside: bool,
    alpha: f64,
    mf: Microfacet,
    wi: DVec3,
    prop: Proposal,
    label: String,
}

/// Every configuration of the albedo checks: DISTS × ETAS × (outside, inside)
/// × ALPHAS × THETAS, in that order.
fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    for dist in DISTS {
        for &eta in &ETAS {
            for inside in [false, true] {
                for &alpha in &ALPHAS {
                    for &theta in &THETAS {
                        let mf = Microfacet::new(dist, alpha, alpha);
                        let wi = incident(theta, inside);
                        let label = format!("{dist:?} η={eta} {} α={alpha} θ={theta}", if inside { "inside" } else { "outside" });
                        v.push(Case { dist, eta, inside, alpha, mf, wi, prop: Proposal { mf, eta, wi }, label });
                    }
                }
            }
        }
    }
    v
}

/// The table's parallel build is deterministic — a second build equals the cached one bit for bit, whatever
/// the threads' order — and every node is an albedo (finite, in [0, 1]). The build time is printed.
#[test]
fn table_build_is_deterministic_and_bounded() {
    for dist in DISTS {
        let t0 = Instant::now();
        let fresh = DielectricAlbedoTable::compute(dist);
        let dt = t0.elapsed().as_secs_f64();
        println!(
            "{dist:?}: table of {}×{}×{}×2 entries ({}² normals each (μ, α)) computed in {dt:.3} s (threads: {:?}); E(1, 0.5, 1.5) = {:.5}",
            table::MU.n,
            table::ALPHA.n,
            table::N_ETA,
            table::GRID,
            std::thread::available_parallelism().map(|n| n.get()).ok(),
            fresh.e(0.5, 1.0, 1.5)
        );
        let cached = DielectricAlbedoTable::get(dist);
        for (side, (a, b)) in fresh.grids().iter().zip(cached.grids()).enumerate() {
            assert_eq!(a.values.len(), b.values.len(), "{dist:?} side {side}: sizes differ");
            for (i, (x, y)) in a.values.iter().zip(&b.values).enumerate() {
                assert_eq!(x.to_bits(), y.to_bits(), "{dist:?} side {side} node {i}: {x} vs {y} in two builds");
                assert!(x.is_finite() && (0.0..=1.0).contains(x), "{dist:?} side {side} node {i}: {x} is not an albedo");
            }
        }
    }
}

/// The table against an independent Monte Carlo integral of
/// `single_dielectric::eval` (Importance mode), off the table nodes. The
/// deterministic interpolation error (table vs the same quadrature at the
/// point, 64² normals) is printed beside.
#[test]
fn table_matches_monte_carlo() {
    let mut ck = Checker::new("table vs Monte Carlo albedo of single_dielectric");
    for (seed, Case { dist, eta, inside, alpha, mf, wi, prop, label }) in (1001..).zip(cases()) {
        let est = albedo(|wo| single_dielectric::eval(&mf, eta, wi, wo, false).0, &prop, 100_000, seed);
        let eta_r = if inside { 1.0 / eta } else { eta };
        let tab = DielectricAlbedoTable::get(dist).e(alpha, wi.z.abs(), eta_r);
        let direct = table::single_albedo(dist, alpha, wi.z.abs(), eta_r, 64);
        println!("  {label}: table {tab:.5}, direct quadrature {direct:.5} (interp. err {:+.2e})", tab - direct);
        ck.close(&format!("{label}: E table"), (tab, 0.0), est[2], ALLOW_REL, 0.0);
    }
    ck.finish();
}

/// White furnace (Importance mode, no absorption): E_r + E_t = 1.
#[test]
fn furnace_outside_and_inside() {
    let mut ck = Checker::new("compensated dielectric furnace E_r + E_t = 1");
    for (seed, Case { dist, eta, inside, alpha, mf, wi, prop, label }) in (5001..).zip(cases()) {
        let [r, t, s] = albedo(|wo| cd::eval(&mf, eta, wi, wo, false), &prop, 100_000, seed);
        // The single-scattering albedo beside it, for the reader: the table's value (which
        // `table_matches_monte_carlo` checks against a Monte Carlo integral), not a second integral.
        let eta_r = if inside { 1.0 / eta } else { eta };
        let e1 = DielectricAlbedoTable::get(dist).e(alpha, wi.z.abs(), eta_r);
        println!("  {label}: E_r = {:.5} ± {:.1e}, E_t = {:.5} ± {:.1e} (single: E = {e1:.5})", r.0, r.1, t.0, t.1);
        ck.close(&format!("{label}: E_r + E_t"), s, (1.0, 0.0), ALLOW_REL, 0.0);
    }
    ck.finish();
}

#[test]
fn compensated_at_least_single_and_weight_is_eval_over_pdf() {
    let mut ck = Checker::new("compensated ≥ single; weight = eval/pdf; pdf = single pdf");
    let mut rng = Sampler::new(77);
    let (mut n_ge, mut n_w, mut n_zero) = (0usize, 0usize, 0usize);
    let mut worst_w = 0.0f64;
    for dist in DISTS {
        for &eta in &[1.1, 1.5, 2.4, 1.0 / 1.5, 1.33] {
            for &alpha in &[0.05, 0.1, 0.3, 0.5, 1.0, 2.0] {
                let mf = Microfacet::new(dist, alpha, alpha * 0.7);
                for _ in 0..300 {
                    let (a, b) = rng.next2();
                    let wi = crate::common::uniform_sphere(a, b);
                    let (c, d) = rng.next2();
                    let wo = crate::common::uniform_sphere(c, d);
                    for radiance in [false, true] {
                        let v = cd::eval(&mf, eta, wi, wo, radiance);
                        let v1 = single_dielectric::eval(&mf, eta, wi, wo, radiance).0;
                        ck.assert(&format!("{dist:?} η={eta} α={alpha} wi={wi} wo={wo}: comp {v} ≥ single {v1}"), v >= v1 && v.is_finite());
                        n_ge += 1;
                    }
                    ck.assert("pdf = single pdf", cd::pdf(&mf, eta, wi, wo) == single_dielectric::pdf(&mf, eta, wi, wo));
                    let (s1, u1, u2) = (rng.next(), rng.next(), rng.next());
                    for radiance in [false, true] {
                        if let Some((wo, pdf, w)) = cd::sample(&mf, eta, Sampling::Visible, wi, (s1, u1, u2), radiance) {
                            if w == 0.0 {
                                // Mitsuba's sample that ends on the wrong side of its facet
                                // (weight 0 by convention, eval there belongs to another m).
                                n_zero += 1;
                                continue;
                            }
                            let e = cd::eval(&mf, eta, wi, wo, radiance);
                            let p = cd::pdf(&mf, eta, wi, wo);
                            let rel_p = (p - pdf).abs() / pdf.max(1e-300);
                            let rel_w = if w > 0.0 { (e / p - w).abs() / w } else { e.abs() };
                            worst_w = worst_w.max(rel_w).max(rel_p);
                            ck.assert(
                                &format!("{dist:?} η={eta} α={alpha} wi={wi}: weight {w} vs eval/pdf {} (pdf {pdf} vs {p})", e / p),
                                rel_w < 1e-6 && rel_p < 1e-6,
                            );
                            n_w += 1;
                        }
                    }
                }
            }
        }
    }
    println!("{n_ge} pairs compared, {n_w} samples checked ({n_zero} zero-weight wrong-side samples skipped), worst relative weight/pdf mismatch {worst_w:.2e}");
    ck.finish();
}

#[test]
fn robustness() {
    let mut ck = Checker::new("compensated dielectric robustness");
    let mut rng = Sampler::new(99);
    let mut count = 0usize;
    let mut max_scale = 0.0f64;
    for dist in DISTS {
        for &eta in &[1.0, 1.0 + 1e-9, 1.001, 1.01, 0.99, 0.5, 1.0 / 1.5, 0.2, 3.0, 5.0, 10.0] {
            for &alpha in &[1e-4, 1e-3, 0.01, 0.1, 0.5, 1.0, 2.0, 4.0] {
                let mf = Microfacet::new(dist, alpha, alpha);
                for k in 0..60 {
                    let wi = match k % 4 {
                        0 => dir(std::f64::consts::FRAC_PI_2 - 1e-7, 0.3),
                        1 => dir(std::f64::consts::FRAC_PI_2 + 1e-7, 0.3),
                        _ => {
                            let (a, b) = rng.next2();
                            crate::common::uniform_sphere(a, b)
                        }
                    };
                    let (c, d) = rng.next2();
                    let wo = if k % 3 == 0 { dir(std::f64::consts::FRAC_PI_2 - 1e-9, 2.0) } else { crate::common::uniform_sphere(c, d) };
                    max_scale = max_scale.max(cd::scale(&mf, eta, wi));
                    for radiance in [false, true] {
                        let v = cd::eval(&mf, eta, wi, wo, radiance);
                        let p = cd::pdf(&mf, eta, wi, wo);
                        ck.assert(&format!("{dist:?} η={eta} α={alpha} eval {v} pdf {p}"), v.is_finite() && v >= 0.0 && p.is_finite() && p >= 0.0);
                        let (s1, u1, u2) = (rng.next(), rng.next(), rng.next());
                        if let Some((wo, pdf, w)) = cd::sample(&mf, eta, Sampling::Visible, wi, (s1, u1, u2), radiance) {
                            ck.assert(
                                &format!("{dist:?} η={eta} α={alpha} sample {wo} {pdf} {w}"),
                                wo.is_finite() && pdf.is_finite() && pdf > 0.0 && w.is_finite() && w >= 0.0,
                            );
                        }
                        count += 1;
                    }
                }
            }
        }
    }
    for bad in [f64::NAN, 0.0, -1.5, f64::INFINITY] {
        let mf = Microfacet::new(Distribution::Ggx, 0.3, 0.3);
        ck.assert(&format!("scale at η={bad}"), cd::scale(&mf, bad, dir(0.5, 0.0)) == 1.0);
    }
    println!("{count} evaluations; largest compensation factor {max_scale:.3}");
    ck.finish();
}
