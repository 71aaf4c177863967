//! Generated Beckmann surfaces and the ray tracer on them (src/microgeometry/).
//!
//! Error estimates: one finite surface deviates from the ensemble statistics by
//! an amount set by how many correlation areas it holds, which no formula
//! for binomial counts captures (neighbouring facets are strongly correlated).
//! Every test therefore measures its statistic on K independent surface
//! realisations and uses the spread between them: standard error = sample
//! standard deviation / √K, compared with the Student t quantile for K − 1
//! degrees of freedom at the family-wise level of a single two-sided 3σ test
//! (Bonferroni over the checks of the family). This covers the ray sampling
//! error as well, since each realisation also has its own rays.

mod common;

use common::family_sigmas;
use glam::DVec3;
use msx::microgeometry::{Facet, HeightField, Side, SimConfig, Simulation, SurfaceParams, Trace};
use msx::rng::Sampler;
use msx::{Distribution, Microfacet};
use std::f64::consts::PI;

// ------------------------------------------------------------------ helpers

/// Two-sided Student t quantile with `nu` degrees of freedom whose tail
/// probability equals the normal tail beyond `z` (so that `z` = family_sigmas(k)
/// becomes the matching t threshold). CDF by Simpson integration of the density.
fn t_quantile_like_normal(z: f64, nu: f64) -> f64 {
    let p_tail = 0.5 * libm::erfc(z / std::f64::consts::SQRT_2); // one side
    let c = (libm::lgamma((nu + 1.0) / 2.0) - libm::lgamma(nu / 2.0)).exp() / (nu * PI).sqrt();
    let dens = |x: f64| c * (1.0 + x * x / nu).powf(-(nu + 1.0) / 2.0);
    // Upper tail ∫_t^∞ = 1/2 − ∫_0^t.
    let tail = |t: f64| {
        let n = 4000;
        let h = t / n as f64;
        let mut s = dens(0.0) + dens(t);
        for i in 1..n {
            s += dens(i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
        }
        0.5 - s * h / 3.0
    };
    let (mut lo, mut hi) = (0.0f64, 200.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if tail(mid) > p_tail {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Mean and standard error over realisations.
fn mean_se(x: &[f64]) -> (f64, f64) {
    let k = x.len() as f64;
    let m = x.iter().sum::<f64>() / k;
    let v = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (k - 1.0);
    (m, (v / k).sqrt())
}

/// Collects (label, per-realisation values, expected) checks and fails with
/// all of them listed; threshold Student t (K − 1 dof) at the family-wise level.
struct Family {
    name: String,
    checks: Vec<(String, f64, f64, f64)>,
    k: usize,
}

impl Family {
    fn new(name: &str, k: usize) -> Self {
        Family { name: name.into(), checks: Vec::new(), k }
    }
    fn add(&mut self, label: String, values: &[f64], expected: f64) {
        assert_eq!(values.len(), self.k);
        let (m, se) = mean_se(values);
        self.checks.push((label, m, se, expected));
    }
    fn threshold(&self) -> f64 {
        t_quantile_like_normal(family_sigmas(self.checks.len()), self.k as f64 - 1.0)
    }
    /// Largest |t| of the family (for power checks).
    fn max_t(&self) -> f64 {
        self.checks.iter().filter(|c| c.2 > 0.0).map(|(_, m, se, e)| (m - e).abs() / se).fold(0.0, f64::max)
    }
    fn finish(self) {
        let thr = self.threshold();
        let mut fails = Vec::new();
        for (label, m, se, e) in &self.checks {
            // A statistic without spread (every probe gave the same value) must
            // equal the expectation to rounding.
            let t = if *se > 0.0 {
                (m - e) / se
            } else if (m - e).abs() <= 1e-6 * e.abs().max(1.0) {
                0.0
            } else {
                f64::INFINITY
            };
            println!("{label}: measured {m:.6} ± {se:.6}, expected {e:.6}, t = {t:+.2}");
            if !(t.abs() <= thr) {
                fails.push(label.clone());
            }
        }
        println!(
            "=== {}: {} checks, K = {} realisations, threshold |t| ≤ {thr:.2}; {} failed ===",
            self.name,
            self.checks.len(),
            self.k,
            fails.len()
        );
        assert!(fails.is_empty(), "{}: {:?}", self.name, fails);
    }
}

/// K independent surfaces (K/2 spectral syntheses).
fn surfaces(p: &SurfaceParams, k: usize, seed: u64) -> Vec<HeightField> {
    (0..k / 2).flat_map(|s| HeightField::generate_pair(p, seed * 1000 + s as u64).unwrap()).collect()
}

/// Standard normal CDF and its inverse (bisection), for equiprobable bins.
fn phi(x: f64) -> f64 {
    0.5 * libm::erfc(-x / std::f64::consts::SQRT_2)
}
fn phi_inv(p: f64) -> f64 {
    let (mut lo, mut hi) = (-40.0, 40.0);
    for _ in 0..200 {
        let m = 0.5 * (lo + hi);
        if phi(m) < p {
            lo = m;
        } else {
            hi = m;
        }
    }
    0.5 * (lo + hi)
}

// ---------------------------------------------------------------- surfaces

/// Fractions of facets in an 8×8 grid of bins equiprobable under Beckmann's
/// P22 (Gaussian slopes of variances α²/2), per surface, for slopes scaled by
/// `scale` (1 = the generated roughness).
fn slope_histograms(fields: &[HeightField], alpha: (f64, f64), scale: f64) -> Vec<Vec<f64>> {
    const B: usize = 8;
    let edges: Vec<f64> = (1..B).map(|i| phi_inv(i as f64 / B as f64)).collect();
    let bin = |x: f64| edges.iter().take_while(|&&e| x > e).count();
    let (sx, sy) = (alpha.0 / std::f64::consts::SQRT_2, alpha.1 / std::f64::consts::SQRT_2);
    fields
        .iter()
        .map(|f| {
            let mut h = vec![0.0; B * B];
            let mut n = 0.0;
            f.for_each_facet(|x, y| {
                h[bin(x / (sx * scale)) * B + bin(y / (sy * scale))] += 1.0;
                n += 1.0;
            });
            h.iter().map(|c| c / n).collect()
        })
        .collect()
}

#[test]
fn generated_slopes_follow_beckmann_p22() {
    // 2D histogram of facet slopes in 64 bins of probability 1/64 each, plus
    // the slope variances, against Beckmann; isotropic and anisotropic.
    let k = 24;
    for (alpha, corr) in [((0.5, 0.5), 6.0), ((1.0, 0.1), 6.0)] {
        let p = SurfaceParams { alpha_x: alpha.0, alpha_y: alpha.1, grid: 128, corr_cells: corr };
        let fields = surfaces(&p, k, 11);
        let mut fam = Family::new(&format!("slopes α={alpha:?}"), k);
        let hist = slope_histograms(&fields, alpha, 1.0);
        for b in 0..64 {
            let v: Vec<f64> = hist.iter().map(|h| h[b]).collect();
            fam.add(format!("α={alpha:?} bin ({}, {})", b / 8, b % 8), &v, 1.0 / 64.0);
        }
        // Second moments: E[s_x²] = α_x²/2, E[s_y²] = α_y²/2, E[s_x s_y] = 0.
        let mom: Vec<[f64; 3]> = fields
            .iter()
            .map(|f| {
                let (mut a, mut b, mut c, mut n) = (0.0, 0.0, 0.0, 0.0);
                f.for_each_facet(|x, y| {
                    a += x * x;
                    b += y * y;
                    c += x * y;
                    n += 1.0;
                });
                [a / n, b / n, c / n]
            })
            .collect();
        let v = |i: usize| mom.iter().map(|m| m[i]).collect::<Vec<f64>>();
        fam.add(format!("α={alpha:?} E[sx²]"), &v(0), alpha.0 * alpha.0 / 2.0);
        fam.add(format!("α={alpha:?} E[sy²]"), &v(1), alpha.1 * alpha.1 / 2.0);
        fam.add(format!("α={alpha:?} E[sx sy]"), &v(2), 0.0);
        println!("ensemble x/y slope correlation within a triangle: ±{:.4}", fields[0].facet_slope_correlation());
        // Power: the same facets against a Beckmann distribution 5 % rougher
        // must be rejected by the histogram test.
        let wrong = slope_histograms(&fields, alpha, 1.05);
        let mut alt = Family::new("5 % rougher", k);
        for b in 0..64 {
            let v: Vec<f64> = wrong.iter().map(|h| h[b]).collect();
            alt.add(String::new(), &v, 1.0 / 64.0);
        }
        println!("power check: 5 % rougher Beckmann gives max |t| = {:.1} (threshold {:.2})", alt.max_t(), alt.threshold());
        assert!(alt.max_t() > alt.threshold(), "the slope test cannot tell a 5 % roughness error");
        fam.finish();
    }
}

/// One masking probe: a uniformly chosen surface point, its projected area
/// towards ω per unit macro area w⁺ = max(0, ω·(−s_x, −s_y, 1)), and whether
/// the ray from it along ω escapes. Returns (w⁺·V, w⁺, height, V).
fn masking_probe(f: &HeightField, w: DVec3, rng: &mut Sampler) -> (f64, f64, f64, bool) {
    let (px, py) = f.period();
    let (x, y) = (rng.next() * px, rng.next() * py);
    let (z, tri, bx, by) = f.surface_at(x, y);
    let n = DVec3::new(-bx / f.dx, -by / f.dy, 1.0);
    let wp = w.dot(n);
    if wp <= 0.0 {
        return (0.0, 0.0, z, false);
    }
    let visible = matches!(f.trace(DVec3::new(x, y, z), w, Side::Outside, Some(tri)), Trace::Escape);
    (if visible { wp } else { 0.0 }, wp, z, visible)
}

#[test]
fn masking_matches_smith_g1_of_beckmann() {
    // For a direction ω, the visible projected area per unit macro area must be
    // cos θ (every line along ω meets the height field once: a check of the
    // tracer), the front-facing projected area cos θ·(1 + Λ(ω)) (Beckmann's Λ,
    // from the slopes), and their ratio G1(ω) = 1/(1 + Λ(ω)).
    let k = 16;
    let probes = 40_000;
    for alpha in [(0.5, 0.5), (1.0, 0.1)] {
        let p = SurfaceParams { alpha_x: alpha.0, alpha_y: alpha.1, grid: 128, corr_cells: 6.0 };
        let fields = surfaces(&p, k, 23);
        let mf = Microfacet::new(Distribution::Beckmann, alpha.0, alpha.1);
        let mut fam = Family::new(&format!("masking α={alpha:?}"), k);
        let mut rng = Sampler::new(5);
        for &(theta, phi_w) in &[(0.5f64, 0.0f64), (1.0, 0.0), (1.3, 0.0), (1.5, 0.0), (1.5, PI / 2.0), (1.0, 2.4)] {
            let w = DVec3::new(theta.sin() * phi_w.cos(), theta.sin() * phi_w.sin(), theta.cos());
            let lambda = mf.lambda(w);
            let (mut vis, mut area, mut g1) = (vec![], vec![], vec![]);
            let nb = 6;
            let (mut hv, mut hn, mut hs) = (vec![0.0; nb], vec![0.0; nb], vec![0.0; nb]);
            for f in &fields {
                let (mut sv, mut sw) = (0.0, 0.0);
                for _ in 0..probes {
                    let (v, wp, z, visible) = masking_probe(f, w, &mut rng);
                    sv += v;
                    sw += wp;
                    if wp > 0.0 {
                        // Smith's height-conditioned masking C1(h)^Λ (diagnostic).
                        let b = (((z + 3.0) / 6.0 * nb as f64).floor().max(0.0) as usize).min(nb - 1);
                        hn[b] += 1.0;
                        hv[b] += f64::from(u8::from(visible));
                        hs[b] += phi(z).powf(lambda);
                    }
                }
                vis.push(sv / probes as f64 / theta.cos());
                area.push(sw / probes as f64 / (theta.cos() * (1.0 + lambda)));
                g1.push(sv / sw);
            }
            let tag = format!("α={alpha:?} θ={theta} φ={phi_w:.2}");
            fam.add(format!("{tag} visible area / cos θ"), &vis, 1.0);
            fam.add(format!("{tag} front-facing area / (cos θ (1+Λ))"), &area, 1.0);
            fam.add(format!("{tag} G1 (Λ = {lambda:.4})"), &g1, 1.0 / (1.0 + lambda));
            let diag: Vec<String> = (0..nb)
                .filter(|&b| hn[b] > 100.0)
                .map(|b| format!("h≈{:+.1}: {:.3} vs {:.3}", -3.0 + (b as f64 + 0.5), hv[b] / hn[b], hs[b] / hn[b]))
                .collect();
            println!("{tag}: P(visible | height), measured vs Smith C1(h)^Λ (diagnostic, not tested): {}", diag.join(", "));
        }
        fam.finish();
    }
}

// ----------------------------------------------------------- single scattering

fn sim(alpha: (f64, f64), theta_i: f64, facet: Facet, rays_per_surface: u64, bins: (usize, usize)) -> Simulation {
    let cfg = SimConfig {
        surface: SurfaceParams { alpha_x: alpha.0, alpha_y: alpha.1, grid: 256, corr_cells: 8.0 },
        facet,
        theta_i,
        phi_i: 0.0,
        surfaces: 16,
        seed: 3,
        theta_bins: bins.0,
        phi_bins: bins.1,
        max_bounces: 100_000,
    };
    let mut s = Simulation::new(cfg).unwrap();
    s.run(rays_per_surface, std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1));
    s
}

/// Per-surface order-1 lobe values dE/dω of bin b.
fn order1_bin(s: &Simulation, b: usize, omega: f64) -> Vec<f64> {
    let t = s.tally();
    let bins = s.config().bins();
    (0..t.surfaces).map(|k| t.lobes[(k * 4) * bins + b] / t.rays[k] as f64 / omega).collect()
}

/// Bin (θ index, φ index) geometry: θ range, φ range (relative to φ_i = 0), solid angle.
fn bin_geometry(cfg: &SimConfig, it: usize, ip: usize) -> ((f64, f64), (f64, f64), f64) {
    let dth = PI / cfg.theta_bins as f64;
    let dph = 2.0 * PI / cfg.phi_bins as f64;
    let (t0, t1) = (it as f64 * dth, (it + 1) as f64 * dth);
    let (p0, p1) = ((ip as f64 - 0.5) * dph, (ip as f64 + 0.5) * dph);
    ((t0, t1), (p0, p1), (t0.cos() - t1.cos()) * dph)
}

/// Average of g(ω) over a bin (midpoint rule, uniform in cos θ and φ).
fn bin_average(th: (f64, f64), ph: (f64, f64), g: impl Fn(DVec3) -> f64) -> f64 {
    let n = 12;
    let mut acc = 0.0;
    for a in 0..n {
        for b in 0..n {
            let c = th.0.cos() + (a as f64 + 0.5) / n as f64 * (th.1.cos() - th.0.cos());
            let p = ph.0 + (b as f64 + 0.5) / n as f64 * (ph.1 - ph.0);
            let s = (1.0 - c * c).max(0.0).sqrt();
            acc += g(DVec3::new(s * p.cos(), s * p.sin(), c));
        }
    }
    acc / (n * n) as f64
}

#[test]
fn single_scattering_matches_walter_with_smith_g_at_normal_incidence() {
    // Order-1 lobe of a perfect mirror surface against Walter 2007 with the
    // height-correlated Smith G2 = 1/(1 + Λ(ω_i) + Λ(ω_o)): f·cos θ_o =
    // D(h) G2 / (4 cos θ_i), averaged over each bin. At normal incidence nothing
    // is shadowed, so this checks D, the masking of the outgoing rays, the
    // reflection geometry and the binning. Bins holding ≥ 0.2 % of the flux.
    // Resolution of this test: ≈ 2–4 % per bin (printed); the simulation's
    // documented departures from Smith (docs/microgeometry.md) are smaller at
    // this configuration than that resolution.
    for alpha in [(0.5, 0.5), (1.0, 0.1)] {
        let s = sim(alpha, 0.0, Facet::Conductor { eta: 0.0, k: 1.0 }, 40_000, (18, 12));
        let cfg = *s.config();
        let mf = Microfacet::new(Distribution::Beckmann, alpha.0, alpha.1);
        let wi = cfg.wi();
        let walter = |wo: DVec3| {
            if wo.z <= 0.0 {
                return 0.0;
            }
            let h = (wi + wo).normalize();
            mf.d(h) / (4.0 * wi.z) / (1.0 + mf.lambda(wi) + mf.lambda(wo))
        };
        let mut fam = Family::new(&format!("order 1 vs Walter α={alpha:?}"), cfg.surfaces);
        let (mut e_sim, mut e_walter) = (vec![0.0; cfg.surfaces], 0.0);
        for it in 0..cfg.theta_bins / 2 {
            for ip in 0..cfg.phi_bins {
                let (th, ph, omega) = bin_geometry(&cfg, it, ip);
                let expect = bin_average(th, ph, walter);
                let v = order1_bin(&s, it * cfg.phi_bins + ip, omega);
                v.iter().zip(e_sim.iter_mut()).for_each(|(x, e)| *e += x * omega);
                e_walter += expect * omega;
                if expect * omega >= 2e-3 {
                    fam.add(format!("α={alpha:?} θo∈[{:.0}°,{:.0}°] φ bin {ip}", th.0.to_degrees(), th.1.to_degrees()), &v, expect);
                }
            }
        }
        let (m, se) = mean_se(&e_sim);
        println!("α={alpha:?}: order-1 energy simulated {m:.5} ± {se:.5}, Walter/Smith {e_walter:.5} (not tested: see docs/microgeometry.md)");
        fam.finish();
    }
}

/// Point-sampled single scattering on the same surfaces: per surface and bin,
/// the flux that falls on a uniformly chosen point (projected area
/// (ω_i·n)/cos θ_i per unit macro area, if the point is lit), leaves it after
/// one facet event (reflection with F, or refraction with 1 − F) and escapes.
fn point_sampled_order1(s: &Simulation, points: usize) -> Vec<Vec<f64>> {
    let cfg = *s.config();
    let wi = cfg.wi();
    let mut rng = Sampler::new(77);
    s.fields()
        .iter()
        .map(|f| {
            let mut acc = vec![0.0; cfg.bins()];
            let (px, py) = f.period();
            for _ in 0..points {
                let (x, y) = (rng.next() * px, rng.next() * py);
                let (z, tri, bx, by) = f.surface_at(x, y);
                let n_u = DVec3::new(-bx / f.dx, -by / f.dy, 1.0);
                let lit_area = wi.dot(n_u) / wi.z;
                let p = DVec3::new(x, y, z);
                if lit_area <= 0.0 || !matches!(f.trace(p, wi, Side::Outside, Some(tri)), Trace::Escape) {
                    continue;
                }
                let n = n_u.normalize();
                let c = wi.dot(n);
                let mut out = |d: DVec3, side: Side, weight: f64| {
                    if weight > 0.0 && matches!(f.trace(p, d, side, Some(tri)), Trace::Escape) {
                        acc[cfg.bin_of(d)] += lit_area * weight;
                    }
                };
                match cfg.facet {
                    Facet::Conductor { eta, k } => {
                        out(msx::microfacet::reflect(wi, n), Side::Outside, msx::microfacet::fresnel::conductor(c, eta, k))
                    }
                    Facet::Dielectric { ior } => {
                        let (fr, cos_t, _, eta_ti) = msx::microfacet::fresnel::dielectric_full(c, ior);
                        out(msx::microfacet::reflect(wi, n), Side::Outside, fr);
                        out(msx::microfacet::refract(wi, n, cos_t, eta_ti).normalize(), Side::Inside, 1.0 - fr);
                    }
                    Facet::Diffuse { .. } => unreachable!(),
                }
            }
            acc.iter().map(|a| a / points as f64).collect()
        })
        .collect()
}

#[test]
// The bin index addresses the tallies and the per-surface point estimates alike.
#[allow(clippy::needless_range_loop)]
fn order_one_equals_point_sampled_single_scattering() {
    // At oblique incidence (shadowing and masking both present) the simulated
    // order-1 lobe must equal single scattering computed the other way round on
    // the same surfaces: from surface points, with shadow and mask rays. Both
    // are exact for the surface, so the comparison is paired per surface
    // (finite-surface error cancels) and holds without any Smith assumption.
    // Conductor with a complex IOR (Fresnel weights) and dielectric (reflection
    // and refraction into the material).
    let cases = [
        ((1.0, 1.0), 1.0, Facet::Conductor { eta: 0.2, k: 3.9 }),
        ((0.5, 0.5), 1.2, Facet::Dielectric { ior: 1.5 }),
        ((1.0, 0.1), 0.8, Facet::Dielectric { ior: 1.5 }),
    ];
    for (alpha, theta, facet) in cases {
        let s = sim(alpha, theta, facet, 30_000, (12, 8));
        let cfg = *s.config();
        let pts = point_sampled_order1(&s, 60_000);
        let t = s.tally();
        let mut fam = Family::new(&format!("order 1 vs point sampling α={alpha:?} θi={theta} {facet:?}"), cfg.surfaces);
        let mut e_diff = vec![0.0; cfg.surfaces];
        for b in 0..cfg.bins() {
            let diff: Vec<f64> = (0..cfg.surfaces).map(|k| t.lobes[(k * 4) * cfg.bins() + b] / t.rays[k] as f64 - pts[k][b]).collect();
            diff.iter().zip(e_diff.iter_mut()).for_each(|(d, e)| *e += d);
            let mean_flux = (0..cfg.surfaces).map(|k| pts[k][b]).sum::<f64>() / cfg.surfaces as f64;
            if mean_flux >= 2e-3 {
                fam.add(format!("bin ({}, {}) flux {mean_flux:.4}: simulated − point-sampled", b / cfg.phi_bins, b % cfg.phi_bins), &diff, 0.0);
            }
        }
        fam.add("order-1 energy: simulated − point-sampled".into(), &e_diff, 0.0);
        fam.finish();
    }
}

// --------------------------------------------------------- multiple scattering

#[test]
fn every_order_is_reciprocal() {
    // Helmholtz reciprocity holds for each scattering order of a real surface
    // (reversing a path keeps its number of bounces): f_k(ω_a → ω_b) =
    // f_k(ω_b → ω_a). With the surface statistically isotropic, the reverse
    // configuration is light from θ_b scattered to θ_a in the forward
    // half-plane. Directions at bin centres (θ bins of 5°: 27.5° and 57.5°, φ bin
    // centred on φ_i + π); the bin averages of these smooth lobes differ from
    // their centre values by much less than the errors here. A check of the
    // multiple-bounce transport that uses no model.
    let bins = (36, 36);
    let dth = PI / bins.0 as f64;
    let (ia, ib) = (5usize, 11usize);
    for (alpha, facet) in [((1.0, 1.0), Facet::Conductor { eta: 0.0, k: 1.0 }), ((0.7, 0.7), Facet::Diffuse { albedo: 1.0 })] {
        let theta = |i: usize| (i as f64 + 0.5) * dth;
        let sa = sim(alpha, theta(ia), facet, 100_000, bins);
        let sb = sim(alpha, theta(ib), facet, 100_000, bins);
        let cfg = *sa.config();
        let mut fam = Family::new(&format!("reciprocity {facet:?} α={alpha:?}"), cfg.surfaces);
        for order in 0..4 {
            // f_k·cos θ_o per surface in the bin of the other direction, divided by cos θ_o.
            let f = |s: &Simulation, it: usize| -> Vec<f64> {
                let b = it * bins.1 + bins.1 / 2;
                let (_, _, omega) = bin_geometry(&cfg, it, bins.1 / 2);
                let t = s.tally();
                (0..t.surfaces).map(|k| t.lobes[(k * 4 + order) * cfg.bins() + b] / t.rays[k] as f64 / omega / theta(it).cos()).collect()
            };
            // Paired by surface index: different surfaces, so the difference of
            // the two independent estimates has the variance of their sum.
            let diff: Vec<f64> = f(&sa, ib).iter().zip(f(&sb, ia)).map(|(x, y)| x - y).collect();
            fam.add(format!("order {}: f(27.5° → 57.5°) − f(57.5° → 27.5°)", order + 1), &diff, 0.0);
        }
        fam.finish();
    }
}
