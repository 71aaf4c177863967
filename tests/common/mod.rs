//! Shared helpers of the statistical tests: running mean / standard error,
//! a checker whose tolerance is 3σ (Monte Carlo standard error) plus a stated
//! deterministic allowance, direction samplers with known densities, and
//! reference formulas for D and Λ written independently of `msx::microfacet`.
#![allow(dead_code)]

pub mod chi2;
pub mod dielectric;

use glam::DVec3;
use msx::rng::Sampler;
use msx::{Distribution, Microfacet};
use std::f64::consts::PI;

/// Running mean and variance (Welford).
#[derive(Clone, Copy, Debug, Default)]
pub struct Stat {
    pub n: u64,
    mean: f64,
    m2: f64,
}

impl Stat {
    #[inline]
    pub fn push(&mut self, x: f64) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
    }
    pub fn mean(&self) -> f64 {
        self.mean
    }
    pub fn var(&self) -> f64 {
        if self.n < 2 {
            0.0
        } else {
            self.m2 / (self.n - 1) as f64
        }
    }
    /// Standard error of the mean.
    pub fn se(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            (self.var() / self.n as f64).sqrt()
        }
    }
    /// (mean, standard error).
    pub fn est(&self) -> (f64, f64) {
        (self.mean(), self.se())
    }
}

/// Shift of the fixed seeds of the Monte Carlo tests that read it, from the
/// environment variable `MSX_TEST_SEED_OFFSET` (an integer k ≥ 0, default 0):
/// k·10⁶ is added to every seed, so k = 1, 2, … rerun a test on fresh,
/// non-overlapping streams without editing it (docs/testing.md). An
/// unparsable value panics rather than silently running at offset 0.
pub fn seed_offset() -> u64 {
    match std::env::var("MSX_TEST_SEED_OFFSET") {
        Ok(v) => v.trim().parse::<u64>().unwrap_or_else(|_| panic!("MSX_TEST_SEED_OFFSET={v:?}: not a non-negative integer")) * 1_000_000,
        Err(_) => 0,
    }
}

/// Salt of the independent replicate stream of a heavy-tailed estimator: the
/// replicate of seed s runs at s ^ REPLICATE_SALT (high bits, so it meets no
/// test's own seed).
pub const REPLICATE_SALT: u64 = 0x5851_f42d_0000_0000;

/// (mean, standard error) of a heavy-tailed estimator from two independent
/// streams `a` and `b` of the same length: the mean of `a` with the larger of
/// the two standard errors. A run that misses the rare large values has both a
/// low mean and a low sample variance; `b`'s variance is independent of `a`'s
/// mean, so such a run fails only if `b` misses them too (docs/testing.md,
/// "Heavy-tailed estimators and fixed seeds").
pub fn replicate_est(a: &Stat, b: &Stat) -> (f64, f64) {
    (a.mean(), a.se().max(b.se()))
}

/// ∫ h(ω_o) dω by importance sampling a proposal (`sample`, density `pdf`),
/// on the replicate scheme of [`replicate_est`]: `n` calls on the stream
/// `seed` + [`seed_offset`] and `n` on its replicate. `h` gets its own walk
/// stream (the proposal's seed ^ `walk_salt`); a failed or zero-density
/// proposal counts as 0.
pub fn proposal_integral(
    n: usize,
    seed: u64,
    walk_salt: u64,
    sample: impl Fn(&mut Sampler) -> Option<DVec3>,
    pdf: impl Fn(DVec3) -> f64,
    h: impl Fn(DVec3, &mut Sampler) -> f64,
) -> (f64, f64) {
    let run = |seed: u64| {
        let mut rng = Sampler::new(seed);
        let mut walk = Sampler::new(seed ^ walk_salt);
        let mut st = Stat::default();
        for _ in 0..n {
            let x = match sample(&mut rng) {
                Some(wo) => {
                    let p = pdf(wo);
                    if p > 0.0 {
                        h(wo, &mut walk) / p
                    } else {
                        0.0
                    }
                }
                None => 0.0,
            };
            st.push(x);
        }
        st
    };
    let seed = seed + seed_offset();
    replicate_est(&run(seed), &run(seed ^ REPLICATE_SALT))
}

/// A value with its standard error (0 for an exact value).
pub fn exact(v: f64) -> (f64, f64) {
    (v, 0.0)
}

/// Upper-tail standard normal quantile: z with P(Z > z) = p (bisection on erfc).
pub fn normal_upper_quantile(p: f64) -> f64 {
    let (mut lo, mut hi) = (-40.0f64, 40.0f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if 0.5 * libm::erfc(mid / std::f64::consts::SQRT_2) > p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Number of standard errors allowed per check in a family of `k` statistical
/// checks: the family-wise false-failure probability equals that of a single
/// two-sided 3σ test (0.27 %), Bonferroni-corrected. k = 1 gives exactly 3σ.
pub fn family_sigmas(k: usize) -> f64 {
    let p1 = libm::erfc(3.0 / std::f64::consts::SQRT_2); // two-sided tail of 3σ
    normal_upper_quantile(0.5 * p1 / k.max(1) as f64)
}

struct Entry {
    label: String,
    dev: f64,
    sigma: f64,
    allow: f64,
    finite: bool,
}

/// Collects statistical comparisons, prints every measured value and fails at
/// the end with the list of violations (so that everything is printed).
///
/// A statistical check passes when |estimate − expected| ≤ z·σ + allowance, with
/// σ the combined standard error and z = [`family_sigmas`] of the number of
/// statistical checks the checker holds (3 for a single check): with hundreds of
/// checks a plain 3σ rule would fail some by chance at any fixed seed.
pub struct Checker {
    name: String,
    failures: Vec<String>,
    entries: Vec<Entry>,
    deterministic: usize,
}

impl Checker {
    pub fn new(name: &str) -> Self {
        println!("=== {name} ===");
        Checker { name: name.to_string(), failures: Vec::new(), entries: Vec::new(), deterministic: 0 }
    }

    /// |est − expected| ≤ z·sqrt(σ_est² + σ_exp²) + rel_allow·|expected| + abs_allow.
    pub fn close(&mut self, label: &str, est: (f64, f64), expected: (f64, f64), rel_allow: f64, abs_allow: f64) {
        let sigma = est.1.hypot(expected.1);
        let dev = (est.0 - expected.0).abs();
        let allow = rel_allow * expected.0.abs() + abs_allow;
        let z = if sigma > 0.0 {
            dev / sigma
        } else if dev > allow {
            f64::INFINITY
        } else {
            0.0
        };
        println!(
            "{label}: measured {:.6e} ± {:.2e}, expected {:.6e} ± {:.2e}, dev {:.2e} ({:.2}σ){}",
            est.0,
            est.1,
            expected.0,
            expected.1,
            dev,
            z,
            if allow > 0.0 { format!(", allowance {allow:.2e}") } else { String::new() }
        );
        self.entries.push(Entry { label: label.to_string(), dev, sigma, allow, finite: est.0.is_finite() && expected.0.is_finite() });
    }

    /// est ≤ bound (+ z·σ).
    pub fn at_most(&mut self, label: &str, est: (f64, f64), bound: f64) {
        let dev = (est.0 - bound).max(0.0);
        println!("{label}: measured {:.6e} ± {:.2e}, bound {bound}, excess {:.2e}", est.0, est.1, dev);
        self.entries.push(Entry { label: label.to_string(), dev, sigma: est.1, allow: 0.0, finite: est.0.is_finite() });
    }

    /// A deterministic assertion.
    pub fn assert(&mut self, label: &str, ok: bool) {
        self.deterministic += 1;
        if !ok {
            println!("{label}: FAIL");
            self.failures.push(label.to_string());
        }
    }

    pub fn finish(mut self) {
        let k = self.entries.len();
        let zk = family_sigmas(k);
        let mut max_z = (0.0f64, String::new());
        let mut over3 = 0usize;
        for e in &self.entries {
            let z = if e.sigma > 0.0 {
                (e.dev - e.allow).max(0.0) / e.sigma
            } else if e.dev > e.allow {
                f64::INFINITY
            } else {
                0.0
            };
            if z > 3.0 {
                over3 += 1;
            }
            if z > max_z.0 {
                max_z = (z, e.label.clone());
            }
            if !(e.dev <= zk * e.sigma + e.allow) || !e.finite {
                println!("FAIL: {} (dev {:.3e} > {zk:.2}σ = {:.3e} + allowance {:.2e})", e.label, e.dev, zk * e.sigma, e.allow);
                self.failures.push(e.label.clone());
            }
        }
        println!(
            "=== {}: {k} statistical checks at {zk:.2}σ (family-wise 3σ), {} beyond 3σ (expected by chance ≈ {:.1}); {} deterministic; {} failed; largest z beyond allowance = {:.2} ({}) ===",
            self.name,
            over3,
            0.0027 * k as f64,
            self.deterministic,
            self.failures.len(),
            max_z.0,
            max_z.1
        );
        assert!(self.failures.is_empty(), "{}: {} failed checks: {:#?}", self.name, self.failures.len(), self.failures);
    }
}

/// Direction with polar angle θ (from +z) and azimuth φ.
pub fn dir(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

/// An orthonormal basis (t, b) completing n (Duff et al. 2017).
pub fn basis(n: DVec3) -> (DVec3, DVec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (DVec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x), DVec3::new(b, s + n.y * n.y * a, -n.y))
}

pub fn uniform_sphere(u1: f64, u2: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    DVec3::new(r * c, r * s, z)
}
pub const UNIFORM_SPHERE_PDF: f64 = 1.0 / (4.0 * PI);

/// Uniform on the hemisphere around `n`; density 1/(2π) where ω·n > 0.
pub fn uniform_hemisphere_around(n: DVec3, u1: f64, u2: f64) -> DVec3 {
    let z = u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    let (t, b) = basis(n);
    t * (r * c) + b * (r * s) + n * z
}
pub const UNIFORM_HEMISPHERE_PDF: f64 = 1.0 / (2.0 * PI);

/// Cosine-weighted upper hemisphere; density cos θ / π.
pub fn cosine_hemisphere(u1: f64, u2: f64) -> DVec3 {
    let r = u1.sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    DVec3::new(r * c, r * s, (1.0 - u1).max(0.0).sqrt())
}

// ---------------------------------------------------------------------------
// Reference formulas (written from the papers, not from msx::microfacet).

/// D(m) in (θ, φ) form: GGX 1/(π α_x α_y cos⁴θ (1 + tan²θ (cos²φ/α_x² + sin²φ/α_y²))²),
/// Beckmann exp(−tan²θ (cos²φ/α_x² + sin²φ/α_y²))/(π α_x α_y cos⁴θ).
pub fn ref_d(dist: Distribution, ax: f64, ay: f64, m: DVec3) -> f64 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let cos2 = m.z * m.z;
    let sin2 = (m.x * m.x + m.y * m.y).max(0.0);
    let tan2 = sin2 / cos2;
    let (c2p, s2p) = if sin2 > 0.0 { (m.x * m.x / sin2, m.y * m.y / sin2) } else { (1.0, 0.0) };
    let e = tan2 * (c2p / (ax * ax) + s2p / (ay * ay));
    match dist {
        Distribution::Ggx => 1.0 / (PI * ax * ay * cos2 * cos2 * (1.0 + e) * (1.0 + e)),
        Distribution::Beckmann => (-e).exp() / (PI * ax * ay * cos2 * cos2),
    }
}

/// Full-sphere Λ as in Heitz's listing: a = 1/(α_ω tan θ) carries the sign of cos θ,
/// GGX (−1 + sgn(a)√(1 + 1/a²))/2, Beckmann (erf(a) − 1)/2 + e^{−a²}/(2a√π).
pub fn ref_lambda(dist: Distribution, ax: f64, ay: f64, w: DVec3) -> f64 {
    let sin2 = w.x * w.x + w.y * w.y;
    if sin2 == 0.0 {
        return if w.z > 0.0 { 0.0 } else { -1.0 };
    }
    let alpha = ((w.x * w.x * ax * ax + w.y * w.y * ay * ay) / sin2).sqrt();
    let a = w.z / (sin2.sqrt() * alpha);
    match dist {
        Distribution::Ggx => 0.5 * (-1.0 + a.signum() * (1.0 + 1.0 / (a * a)).sqrt()),
        Distribution::Beckmann => 0.5 * (libm::erf(a) - 1.0) + (-a * a).exp() / (2.0 * a * PI.sqrt()),
    }
}

// ---------------------------------------------------------------------------
// Proposals with densities computed here (independent of msx's samplers).

/// GGX slope sampling with roughness (ax, ay): m has solid-angle density
/// P22(slope)/cos³θ_m = D_GGX(m)·cos θ_m.
pub fn ggx_slope_normal(ax: f64, ay: f64, u1: f64, u2: f64) -> DVec3 {
    let u1 = u1.min(1.0 - 1e-16);
    let r = (u1 / (1.0 - u1)).sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    DVec3::new(-ax * r * c, -ay * r * s, 1.0).normalize()
}

pub fn ggx_slope_normal_pdf(ax: f64, ay: f64, m: DVec3) -> f64 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let sx = -m.x / m.z;
    let sy = -m.y / m.z;
    let t = 1.0 + (sx / ax).powi(2) + (sy / ay).powi(2);
    let p22 = 1.0 / (PI * ax * ay * t * t);
    p22 / (m.z * m.z * m.z)
}

/// Proposal for microfacet normals m seen from ω (any direction): a mixture of
/// GGX slope sampling (roughness scaled by `stretch`), the uniform upper
/// hemisphere, and the uniform hemisphere around ω (covers the visible normals of
/// grazing and downward ω). Samples may have m.z ≤ 0 (integrands vanish there).
#[derive(Clone, Copy, Debug)]
pub struct NormalProposal {
    pub ax: f64,
    pub ay: f64,
    pub w: DVec3,
    pub weights: [f64; 3],
}

impl NormalProposal {
    pub fn new(ax: f64, ay: f64, w: DVec3) -> Self {
        // Weight on the cap around ω grows as ω leaves the zenith.
        let cap = if w.z > 0.9 { 0.1 } else { 0.4 };
        NormalProposal { ax, ay, w, weights: [0.9 - cap, 0.1, cap] }
    }

    pub fn sample(&self, rng: &mut Sampler) -> DVec3 {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.weights[0] {
            ggx_slope_normal(self.ax, self.ay, u1, u2)
        } else if c < self.weights[0] + self.weights[1] {
            uniform_hemisphere_around(DVec3::Z, u1, u2)
        } else {
            uniform_hemisphere_around(self.w, u1, u2)
        }
    }

    pub fn pdf(&self, m: DVec3) -> f64 {
        let mut p = self.weights[0] * ggx_slope_normal_pdf(self.ax, self.ay, m);
        if m.z > 0.0 {
            p += self.weights[1] * UNIFORM_HEMISPHERE_PDF;
        }
        if m.dot(self.w) > 0.0 {
            p += self.weights[2] * UNIFORM_HEMISPHERE_PDF;
        }
        p
    }
}

/// Mirror reflection of ω about m.
pub fn reflect(w: DVec3, m: DVec3) -> DVec3 {
    2.0 * w.dot(m) * m - w
}

/// Density of ω_o = reflect(ω_i, ±m) when the normal m has density `normal_pdf`:
/// (q_m(h) + q_m(−h))/(4|ω_i·h|) at the half vector h; 0 where h is undefined.
fn reflected_pdf(wi: DVec3, wo: DVec3, normal_pdf: impl Fn(DVec3) -> f64) -> f64 {
    let h = wi + wo;
    let len = h.length();
    if len > 1e-12 {
        let h = h / len;
        let c = wi.dot(h).abs();
        if c > 0.0 {
            return (normal_pdf(h) + normal_pdf(-h)) / (4.0 * c);
        }
    }
    0.0
}

/// Proposal for outgoing directions on the whole sphere: reflection of ω_i about
/// a normal from [`NormalProposal`] (density q_m(±h)/(4|ω_i·h|)) mixed with the
/// uniform sphere.
#[derive(Clone, Copy, Debug)]
pub struct SphereOutProposal {
    pub normals: NormalProposal,
    pub wi: DVec3,
    pub uniform: f64,
}

impl SphereOutProposal {
    pub fn new(ax: f64, ay: f64, wi: DVec3) -> Self {
        SphereOutProposal { normals: NormalProposal::new(ax, ay, wi), wi, uniform: 0.1 }
    }

    pub fn sample(&self, rng: &mut Sampler) -> DVec3 {
        if rng.next() < self.uniform {
            let (u1, u2) = rng.next2();
            uniform_sphere(u1, u2)
        } else {
            let m = self.normals.sample(rng);
            reflect(self.wi, m).normalize()
        }
    }

    pub fn pdf(&self, wo: DVec3) -> f64 {
        self.uniform * UNIFORM_SPHERE_PDF + (1.0 - self.uniform) * reflected_pdf(self.wi, wo, |m| self.normals.pdf(m))
    }
}

/// Proposal for outgoing directions in the upper hemisphere (BSDF integrals):
/// reflection of ω_i about GGX-slope normals of roughness (ax, ay) (own
/// sampler, heavier tails than Beckmann) mixed with a cosine lobe of weight `k`.
/// Samples below the horizon are returned as they are (zero integrand).
#[derive(Clone, Copy, Debug)]
pub struct HemisphereOutProposal {
    pub ax: f64,
    pub ay: f64,
    pub wi: DVec3,
    pub k: f64,
}

impl HemisphereOutProposal {
    pub fn new(ax: f64, ay: f64, wi: DVec3) -> Self {
        HemisphereOutProposal { ax, ay, wi, k: 0.3 }
    }

    pub fn sample(&self, rng: &mut Sampler) -> DVec3 {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.k {
            cosine_hemisphere(u1, u2)
        } else {
            let m = ggx_slope_normal(self.ax, self.ay, u1, u2);
            reflect(self.wi, m).normalize()
        }
    }

    pub fn pdf(&self, wo: DVec3) -> f64 {
        if wo.z <= 0.0 {
            return 0.0;
        }
        self.k * wo.z / PI + (1.0 - self.k) * reflected_pdf(self.wi, wo, |m| ggx_slope_normal_pdf(self.ax, self.ay, m))
    }
}

/// Upper quantile of χ²_k at tail probability p = 1e-4 (Wilson–Hilferty).
pub fn chi2_quantile_1e4(k: usize) -> f64 {
    let k = k as f64;
    let z = 3.719; // Φ⁻¹(1 − 1e−4)
    let c = 2.0 / (9.0 * k);
    k * (1.0 - c + z * c.sqrt()).powi(3)
}

/// Means and standard errors of many estimators of which each sample feeds one
/// (indicator-weighted bins): only the hit bin is updated, the others get 0.
#[derive(Clone, Debug)]
pub struct BinStats {
    pub n: u64,
    s: Vec<f64>,
    s2: Vec<f64>,
}

impl BinStats {
    pub fn new(bins: usize) -> Self {
        BinStats { n: 0, s: vec![0.0; bins], s2: vec![0.0; bins] }
    }
    /// One sample: value `v` in bin `b` (None: every bin gets 0).
    #[inline]
    pub fn push(&mut self, b: Option<usize>, v: f64) {
        self.n += 1;
        if let Some(b) = b {
            self.s[b] += v;
            self.s2[b] += v * v;
        }
    }
    pub fn est(&self, b: usize) -> (f64, f64) {
        let n = self.n as f64;
        let mean = self.s[b] / n;
        let var = ((self.s2[b] - n * mean * mean) / (n - 1.0)).max(0.0);
        (mean, (var / n).sqrt())
    }
}

/// Proposal for outgoing directions in the upper hemisphere using msx's own
/// visible-normal sampler (validated by tests/microfacet.rs): reflection about
/// m ~ D_{ω_i} with density `Microfacet::reflect_pdf`, mixed with a cosine lobe of
/// weight `k`. Samples below the horizon are returned as they are.
#[derive(Clone, Copy, Debug)]
pub struct VndfOutProposal {
    pub mf: msx::Microfacet,
    pub wi: DVec3,
    pub k: f64,
}

impl VndfOutProposal {
    pub fn new(mf: msx::Microfacet, wi: DVec3, k: f64) -> Self {
        VndfOutProposal { mf, wi, k }
    }

    pub fn sample(&self, rng: &mut Sampler) -> DVec3 {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.k {
            cosine_hemisphere(u1, u2)
        } else {
            match self.mf.sample_visible(self.wi, u1, u2) {
                Some(m) => reflect(self.wi, m).normalize(),
                None => cosine_hemisphere(u1, u2),
            }
        }
    }

    pub fn pdf(&self, wo: DVec3) -> f64 {
        if wo.z <= 0.0 {
            return 0.0;
        }
        self.k * wo.z / PI + (1.0 - self.k) * self.mf.reflect_pdf(self.wi, wo)
    }
}

/// Full-sphere proposal for a dielectric: reflection and refraction about a
/// visible normal of ω_i (msx's VNDF sampler, validated in tests/microfacet.rs)
/// and the uniform sphere. Works in the local frame of ω_i's side.
pub struct DielectricProposal {
    mf: Microfacet,
    wi_l: DVec3,
    eta_l: f64,
    flip: bool,
    w: [f64; 3],
}

impl DielectricProposal {
    pub fn new(mf: Microfacet, wi: DVec3, eta: f64) -> Self {
        let flip = wi.z < 0.0;
        let wi_l = if flip { -wi } else { wi };
        DielectricProposal { mf, wi_l, eta_l: if flip { 1.0 / eta } else { eta }, flip, w: [0.35, 0.35, 0.3] }
    }

    pub fn to_global(&self, v: DVec3) -> DVec3 {
        if self.flip {
            -v
        } else {
            v
        }
    }

    pub fn sample(&self, rng: &mut Sampler) -> Option<DVec3> {
        let c = rng.next();
        let (u1, u2) = rng.next2();
        if c < self.w[2] {
            return Some(uniform_sphere(u1, u2));
        }
        let m = self.mf.sample_visible(self.wi_l, u1, u2)?;
        let ci = self.wi_l.dot(m);
        if c < self.w[2] + self.w[0] {
            return Some(self.to_global(reflect(self.wi_l, m).normalize()));
        }
        let e = self.eta_l;
        let s2 = (1.0 - ci * ci) / (e * e);
        if s2 >= 1.0 {
            return None; // TIR: a failed sample of the refraction component
        }
        let o = m * (ci / e - (1.0 - s2).sqrt()) - self.wi_l / e;
        Some(self.to_global(o.normalize()))
    }

    pub fn pdf(&self, wo: DVec3) -> f64 {
        let wo_l = if self.flip { -wo } else { wo };
        // Both components can land on either side (a steep facet reflects below
        // the macro horizon or refracts above it): add both densities everywhere.
        let mut p = self.w[2] * UNIFORM_SPHERE_PDF + self.w[0] * self.mf.reflect_pdf(self.wi_l, wo_l);
        {
            let e = self.eta_l;
            let h = -(self.wi_l + wo_l * e);
            let len = h.length();
            if len > 1e-12 {
                let mut h = h / len;
                if h.z < 0.0 {
                    h = -h;
                }
                let (ci, co) = (self.wi_l.dot(h), wo_l.dot(h));
                if ci > 0.0 && co < 0.0 {
                    let denom = ci + e * co;
                    p += self.w[1] * self.mf.d_visible(self.wi_l, h) * e * e * (-co) / (denom * denom);
                }
            }
        }
        p
    }
}

/// Dielectric reciprocity (Heitz 2016 §4.4.2, Walter 2007): with a = eval(ω_i,
/// ω_o) and b = eval(ω_o, ω_i) (each f·|cos| of its outgoing direction, with
/// its standard error), returns the two sides that must agree: f(i,o)/η_o² and
/// f(o,i)/η_i² in Importance mode, η_o² f(i,o) and η_i² f(o,i) in Radiance
/// mode, η the absolute IOR of each direction's side (outside 1, inside `eta`).
pub fn dielectric_reciprocal_pair(a: (f64, f64), b: (f64, f64), wi: DVec3, wo: DVec3, eta: f64, radiance: bool) -> ((f64, f64), (f64, f64)) {
    let ior = |w: DVec3| if w.z > 0.0 { 1.0 } else { eta };
    let (ni, no) = (ior(wi), ior(wo));
    let (sa, sb) = if radiance { (no * no, ni * ni) } else { (1.0 / (no * no), 1.0 / (ni * ni)) };
    let (ka, kb) = (sa / wo.z.abs(), sb / wi.z.abs());
    ((a.0 * ka, a.1 * ka), (b.0 * kb, b.1 * kb))
}

/// Walter 2007 reflection, F·D·G2/(4|cos θ_i|), G2 = 1/(1 + Λ(ω_i) + Λ(ω_o)) in
/// the local frame of the side of ω_i (F(c) the Fresnel at ω_i·h).
pub fn walter_reflection(mf: &Microfacet, wi_l: DVec3, wo_l: DVec3, f: impl Fn(f64) -> f64) -> f64 {
    let h = (wi_l + wo_l).normalize();
    let g2 = 1.0 / (1.0 + mf.lambda(wi_l) + mf.lambda(wo_l));
    f(wi_l.dot(h)) * mf.d(h) * g2 / (4.0 * wi_l.z)
}

/// Walter 2007 transmission times |cos θ_o| with a given G (local frame of ω_i's
/// side, relative IOR `e`): |ωi·h||ωo·h| e² (1−F) D G / (|cos θi| (ωi·h + e ωo·h)²).
pub fn walter_transmission(mf: &Microfacet, wi_l: DVec3, wo_l: DVec3, e: f64, g: f64) -> f64 {
    let mut h = -(wi_l + wo_l * e).normalize();
    if h.z < 0.0 {
        h = -h;
    }
    let (ci, co) = (wi_l.dot(h), wo_l.dot(h));
    if !(ci > 0.0 && co < 0.0) {
        return 0.0;
    }
    let f = msx::microfacet::fresnel::dielectric(ci, e);
    ci * (-co) * e * e * (1.0 - f) * mf.d(h) * g / (wi_l.z * (ci + e * co).powi(2))
}

/// The C ABI's counters of cleaned outputs (`msx_diagnostics`) must not have
/// grown since `before`: the core produced no NaN, ±Inf or negative value
/// and no panic was caught. Counters are process-wide; every test of a
/// binary must keep them at 0, so a concurrent test cannot mask a defect.
pub fn assert_no_raw_defects(before: msx::ffi::MsxDiagnostics, what: &str) {
    let after = msx::ffi::msx_diagnostics();
    let (nf, neg, pan) = (after.nonfinite - before.nonfinite, after.negative - before.negative, after.panics - before.panics);
    assert!(nf == 0 && neg == 0 && pan == 0, "{what}: the C ABI cleaned {nf} non-finite and {neg} negative raw values and caught {pan} panics");
}

/// SplitMix64: a tiny fixed-seed generator for sweeps and fuzzing,
/// independent of the crate's own generator.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn f(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.f()
    }
    pub fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + self.f() * (hi.ln() - lo.ln())).exp()
    }
    /// Uniform in 0..n.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    pub fn pick<T: Copy>(&mut self, v: &[T]) -> T {
        v[self.below(v.len())]
    }
}
