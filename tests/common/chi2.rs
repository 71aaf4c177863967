//! Pearson's χ² test of a BSDF sampler against its pdf (tests/sample_visible.rs
//! and tests/auto.rs): equal-area cells of the sphere (z × φ), expected counts
//! from cell integrals of `Bsdf::pdf`, one more cell for the samples that come
//! back invalid (N·(1 − ∫pdf)); cells with an expected count under 5 pooled (as
//! Mitsuba's `mi.chi2`); the p-value from the χ² distribution with (cells − 1)
//! degrees of freedom.

use super::seed_offset;
use glam::DVec3;
use msx::rng::Sampler;
use msx::{Bsdf, Material};
use std::f64::consts::PI;

/// ln Γ(a) and the regularised upper incomplete gamma Q(a, x) = P(χ²_{2a} > 2x):
/// the series of P below a + 1, a continued fraction (modified Lentz) above.
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let ln_pre = -x + a * x.ln() - libm::lgamma(a);
    if x < a + 1.0 {
        let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
        for _ in 0..100_000 {
            n += 1.0;
            term *= x / n;
            sum += term;
            if term.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * ln_pre.exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..100_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-15 {
                break;
            }
        }
        ln_pre.exp() * h
    }
}

/// P(χ²_k > x).
pub fn chi2_p_value(x: f64, k: usize) -> f64 {
    gamma_q(0.5 * k as f64, 0.5 * x)
}

const NZ: usize = 48;
const NP: usize = 96;
/// Sub-points per cell side of the midpoint rule of the cell integrals.
const SUB: usize = 12;

/// The cell of a direction: z in NZ equal slices of [−1, 1], φ in NP equal slices.
fn cell(w: DVec3) -> usize {
    let iz = (((w.z + 1.0) * 0.5 * NZ as f64) as usize).min(NZ - 1);
    let phi = w.y.atan2(w.x).rem_euclid(2.0 * PI);
    let ip = ((phi / (2.0 * PI) * NP as f64) as usize).min(NP - 1);
    iz * NP + ip
}

/// (χ² statistic, degrees of freedom, largest |O − E|/√E) of `n` draws of `sampler` against `density`'s pdf.
pub fn chi2_of(sampler: &Bsdf, density: &Bsdf, mat: &Material, wi: DVec3, seed: u64, n: usize) -> (f64, usize, f64) {
    let (dz, dp) = (2.0 / NZ as f64, 2.0 * PI / NP as f64);
    let sub_area = (dz / SUB as f64) * (dp / SUB as f64); // the solid angle of a sub-cell (z, φ are equal-area)
    let mut expected = vec![0.0; NZ * NP + 1];
    for iz in 0..NZ {
        for ip in 0..NP {
            let mut sum = 0.0;
            for a in 0..SUB {
                let z = -1.0 + dz * (iz as f64 + (a as f64 + 0.5) / SUB as f64);
                let r = (1.0 - z * z).max(0.0).sqrt();
                for c in 0..SUB {
                    let phi = dp * (ip as f64 + (c as f64 + 0.5) / SUB as f64);
                    sum += density.pdf(mat, wi, DVec3::new(r * phi.cos(), r * phi.sin(), z));
                }
            }
            expected[iz * NP + ip] = sum * sub_area * n as f64;
        }
    }
    let inside: f64 = expected[..NZ * NP].iter().sum();
    expected[NZ * NP] = (n as f64 - inside).max(0.0);
    let mut observed = vec![0.0; NZ * NP + 1];
    let mut rng = Sampler::new(seed + seed_offset());
    for _ in 0..n {
        let s1 = rng.next();
        let (u1, u2) = rng.next2();
        match sampler.sample(mat, wi, s1, (u1, u2)) {
            // As mi.chi2's BSDFAdapter: a sample of weight 0 is not counted (ω_o on the wrong side of its facet).
            Some(s) if s.pdf > 0.0 && s.weight.0[..3].iter().any(|&w| w != 0.0) => observed[cell(s.wo)] += 1.0,
            _ => observed[NZ * NP] += 1.0,
        }
    }
    // Pool the cells expected under 5 (and those observed where nothing is expected) into one.
    let (mut stat, mut cells, mut worst) = (0.0, 0usize, 0.0f64);
    let (mut pool_o, mut pool_e) = (0.0, 0.0);
    for (o, e) in observed.iter().zip(&expected) {
        if *e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            stat += (o - e) * (o - e) / e;
            worst = worst.max((o - e).abs() / e.sqrt());
            cells += 1;
        }
    }
    if pool_e >= 5.0 {
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        cells += 1;
    } else if pool_o > 0.0 {
        // Samples where the pdf says there is (almost) nothing: counted against the pooled expectation.
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e.max(1.0);
        cells += 1;
    }
    (stat, cells - 1, worst)
}
