//! Densities the random-walk models report for multiple importance sampling.
//!
//! A multiple-scattering BSDF has no closed-form density for its sampler (the
//! walk). Mitsuba still needs one for MIS, so `pdf` (and `sample`'s reported
//! pdf) return a density that is close to the walk's and positive wherever
//! the walk can go; the sample weights stay the walk's own, so any positive
//! density keeps the estimates unbiased (docs/conventions.md).

use super::single::dielectric::pdf as single_dielectric_pdf;
use super::Call;
use crate::config::MisDensity;
use crate::microfacet::Microfacet;
use crate::microfacet::Microsurface;
use crate::tables::albedo::AlbedoTable;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// How order 1 of a conductor walk leaves the surface (the exact part of the
/// conductor density).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OrderOneExit {
    /// Separable masking: leaves with G1(ω_o) (`uncorrelated`).
    Separable,
    /// Height-correlated G2: leaves with L_0/(L_0 + Λ_o) (`correlated`,
    /// `heitz`, `invariance`).
    HeightCorrelated,
}

/// The MIS density of the random walks:
/// - conductor: [`conductor_walk_pdf`] (`single_cosine`) or [`cui_pdf`]
///   (`cui`, `cui_typo`), as `call.mis` says, for ω_i above the surface; below it
///   (normal mapping, position-free walks only: `below`) a cosine lobe;
/// - dielectric: the single-scattering density mixed with a cosine lobe on
///   both sides, weighted by [`diffuse_fraction`] (Heitz 2016);
/// - diffuse microsurface: a cosine lobe.
pub fn walk_pdf(call: &Call, exit: OrderOneExit, below: bool, wi: DVec3, wo: DVec3) -> f64 {
    let mf = &call.mf;
    match call.surf {
        Microsurface::Conductor(_) => {
            if wo.z <= 0.0 || wi.z == 0.0 {
                0.0
            } else if wi.z < 0.0 {
                if below {
                    wo.z * FRAC_1_PI
                } else {
                    0.0
                }
            } else {
                match call.mis {
                    MisDensity::SingleCosine => conductor_walk_pdf(exit, mf, wi, wo),
                    MisDensity::Cui => cui_pdf(mf, wi, wo, HForm::Classic),
                    MisDensity::CuiTypo => cui_pdf(mf, wi, wo, HForm::Printed),
                }
            }
        }
        Microsurface::Dielectric { eta, .. } => {
            let ss = single_dielectric_pdf(mf, eta, wi, wo);
            let k = diffuse_fraction(mf);
            (1.0 - k) * ss + k * wo.z.abs() * 0.5 * FRAC_1_PI
        }
        Microsurface::Diffuse { .. } => {
            if wi.z <= 0.0 || wo.z <= 0.0 {
                0.0
            } else {
                wo.z * FRAC_1_PI
            }
        }
    }
}

/// MIS density of the conductor random walks: the exact density of leaving
/// after one bounce (visible-normal reflection × exit probability: G1(ω_o)
/// separable, L_0/(L_0 + Λ_o) height-correlated) plus a cosine lobe carrying
/// the remaining mass 1 − E_1(ω_i) from the order-1 albedo table, floored at
/// 1e-3 so that no direction the walk can reach has density 0. Integrates to 1
/// up to the table's interpolation error.
pub fn conductor_walk_pdf(exit: OrderOneExit, mf: &Microfacet, wi: DVec3, wo: DVec3) -> f64 {
    let lambda_o = mf.lambda(wo);
    let (l0, e1) = order_one_of(exit, mf, wi);
    let exit = match exit {
        OrderOneExit::Separable => 1.0 / (1.0 + lambda_o),
        OrderOneExit::HeightCorrelated => l0 / (l0 + lambda_o),
    };
    mf.reflect_pdf(wi, wo) * exit + (1.0 - e1).max(1e-3) * wo.z * FRAC_1_PI
}

/// Which approximation of Chandrasekhar's H-function [`cui_pdf`] uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HForm {
    /// H(μ) = (1 + 2μ)/(1 + 2√(1 − ϖ) μ), the classic approximation: H ≥ 1,
    /// so the multiple-scattering term is ≥ 0.
    Classic,
    /// H(μ) = (1 + 2μ)/(1 + 2 + √(1 − ϖ) μ), as the authors' released code
    /// prints it: H < 1 on (0, 1), so the "multiple-scattering" term is
    /// negative (docs/paper-notes.md). Floored like `single_cosine`.
    Printed,
}

/// Largest single-scattering albedo ϖ Cui's density maps a roughness to.
pub const CUI_ALBEDO_MAX: f64 = 0.975;

/// Cui et al. 2023's MIS density of the multiple-bounce conductors
/// (docs/paper-notes.md): the visible-normal reflection density of single
/// scattering, p_1 = D(h) G1(ω_i)/(4 μ_i), plus Chandrasekhar's
/// multiple-scattering term of a half space of isotropic scatterers,
/// (ϖ/4π)·(H(μ_i) H(μ_o) − 1)/(μ_i + μ_o), with the roughness mapped to the
/// albedo ϖ = min((α_u + α_v)/2, 0.975). Note the term has no factor μ_o.
///
/// `Classic`: H − 1 = 2μ(1 − s)/(1 + 2sμ) with s = √(1 − ϖ) and
/// 1 − s = ϖ/(1 + s), and H_i H_o − 1 = (H_i − 1)(H_o − 1) + (H_i − 1) +
/// (H_o − 1): a sum of positive terms, so the density is > 0 for every
/// μ_i, μ_o > 0 without cancellation, and finite at grazing angles (the
/// ratio (H − 1)/(μ_i + μ_o) stays ≤ 2(1 − s)).
/// `Printed`: may be negative; floored at the 1e-3 cosine lobe of
/// [`conductor_walk_pdf`], so that the density is > 0 wherever the walk goes
/// (the C ABI rejects a sample whose pdf is not > 0).
pub fn cui_pdf(mf: &Microfacet, wi: DVec3, wo: DVec3, form: HForm) -> f64 {
    let (mu_i, mu_o) = (wi.z, wo.z);
    let albedo = (0.5 * (mf.alpha_u + mf.alpha_v)).min(CUI_ALBEDO_MAX);
    let s = (1.0 - albedo).sqrt();
    let p1 = mf.reflect_pdf(wi, wo);
    let scale = albedo * 0.25 * FRAC_1_PI;
    match form {
        HForm::Classic => {
            let one_minus_s = albedo / (1.0 + s);
            let hm1 = |mu: f64| 2.0 * mu * one_minus_s / (1.0 + 2.0 * s * mu);
            let (a, b) = (hm1(mu_i), hm1(mu_o));
            p1 + scale * (a * b + a + b) / (mu_i + mu_o)
        }
        HForm::Printed => {
            let h = |mu: f64| (1.0 + 2.0 * mu) / (3.0 + s * mu);
            let p = p1 + scale * (h(mu_i) * h(mu_o) - 1.0) / (mu_i + mu_o);
            p.max(1e-3 * mu_o * FRAC_1_PI)
        }
    }
}

/// (L_0 = 1 + Λ(ω_i), the order-1 albedo E_1(ω_i)) of [`conductor_walk_pdf`],
/// which depend on ω_i and the microsurface only. A renderer asks for two
/// densities at the same ω_i in a row (the light sample's, then the BSDF
/// sample's), so the last result is kept per thread: the second table lookup
/// was ≈ 5 % of the instructions of a `correlated` conductor's eval_pdf +
/// sample (benches/README.md, "Per-call overhead"). The memo returns exactly
/// what the computation would.
fn order_one_of(exit: OrderOneExit, mf: &Microfacet, wi: DVec3) -> (f64, f64) {
    type Key = [u64; 6];
    thread_local! {
        static LAST: std::cell::Cell<Option<(Key, (f64, f64))>> = const { std::cell::Cell::new(None) };
    }
    let key: Key = [
        (mf.dist as u64) << 1 | (exit == OrderOneExit::Separable) as u64,
        mf.alpha_u.to_bits(),
        mf.alpha_v.to_bits(),
        wi.x.to_bits(),
        wi.y.to_bits(),
        wi.z.to_bits(),
    ];
    if let Some((k, v)) = LAST.get() {
        // (Word by word: `==` on the arrays calls memcmp, which costs more than the rest.)
        if k.iter().zip(&key).fold(0, |acc, (a, b)| acc | (a ^ b)) == 0 {
            return v;
        }
    }
    let table = AlbedoTable::get(mf.dist);
    let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
    let v = match exit {
        OrderOneExit::Separable => (0.0, table.e1_uncorrelated(alpha, wi.z)),
        OrderOneExit::HeightCorrelated => (1.0 + mf.lambda(wi), table.e1_correlated(alpha, wi.z)),
    };
    LAST.set(Some((key, v)));
    v
}

/// Weight of the cosine lobe in the MIS density of the dielectric walks:
/// grows with roughness like the multiply scattered energy does (≈ 5 % at
/// α = 0.1, 33 % at α = 1).
pub fn diffuse_fraction(mf: &Microfacet) -> f64 {
    let a = (mf.alpha_u * mf.alpha_v).sqrt();
    (a / (a + 2.0)).min(0.75)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Distribution;

    /// The per-thread memo of `order_one_of` never returns another call's
    /// values: densities asked in an interleaved order equal the direct formula.
    #[test]
    fn memo_returns_each_calls_own_values() {
        let mut st = 7u64;
        let mut rnd = || {
            st = crate::rng::mix64(st.wrapping_add(1));
            (st >> 11) as f64 / (1u64 << 53) as f64
        };
        let dirs: Vec<DVec3> = (0..6).map(|_| DVec3::new(rnd() - 0.5, rnd() - 0.5, 0.05 + rnd()).normalize()).collect();
        let mfs = [
            Microfacet::new(Distribution::Ggx, 0.3, 0.3),
            Microfacet::new(Distribution::Ggx, 0.3, 0.9),
            Microfacet::new(Distribution::Beckmann, 0.3, 0.3),
        ];
        for _ in 0..3000 {
            let mf = &mfs[(rnd() * 3.0) as usize];
            let exit = if rnd() < 0.5 { OrderOneExit::Separable } else { OrderOneExit::HeightCorrelated };
            let (wi, wo) = (dirs[(rnd() * 6.0) as usize], dirs[(rnd() * 6.0) as usize]);
            let table = AlbedoTable::get(mf.dist);
            let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
            let lambda_o = mf.lambda(wo);
            let (exit_p, e1) = match exit {
                OrderOneExit::Separable => (1.0 / (1.0 + lambda_o), table.e1_uncorrelated(alpha, wi.z)),
                OrderOneExit::HeightCorrelated => {
                    let l0 = 1.0 + mf.lambda(wi);
                    (l0 / (l0 + lambda_o), table.e1_correlated(alpha, wi.z))
                }
            };
            let direct = mf.reflect_pdf(wi, wo) * exit_p + (1.0 - e1).max(1e-3) * wo.z * FRAC_1_PI;
            assert_eq!(conductor_walk_pdf(exit, mf, wi, wo).to_bits(), direct.to_bits());
        }
    }

    /// Cui's density, both H forms, is finite and > 0 wherever a conductor
    /// walk can leave (μ_i, μ_o > 0): grazing to normal incidence, α from the
    /// clamp's 1e-4 to its 1e4, isotropic and anisotropic, both distributions.
    /// The classic H makes the multiple-scattering term ≥ 0 (density ≥ p_1),
    /// the printed H makes it < 0; at α = 1e-4 the classic density is p_1 to
    /// 1e-3 relative wherever p_1 is not negligible.
    #[test]
    fn cui_density_is_positive_and_finite() {
        let mus = [1e-9, 1e-6, 1e-3, 0.05, 0.3, 0.7, 1.0];
        let phis = [0.0, 0.4, 1.7, std::f64::consts::PI];
        let dir = |mu: f64, phi: f64| {
            let s = (1.0 - mu * mu).max(0.0).sqrt();
            DVec3::new(s * phi.cos(), s * phi.sin(), mu)
        };
        let mut printed_negative = 0;
        for dist in [Distribution::Ggx, Distribution::Beckmann] {
            for (au, av) in [(1e-4, 1e-4), (0.01, 0.01), (0.1, 0.1), (0.5, 0.5), (1.0, 1.0), (1.5, 1.5), (4.0, 4.0), (1e4, 1e4), (0.05, 1.2)] {
                let mf = Microfacet::new(dist, au, av);
                for &mi in &mus {
                    for &mo in &mus {
                        for &phi in &phis {
                            let (wi, wo) = (dir(mi, 0.0), dir(mo, phi));
                            let p1 = mf.reflect_pdf(wi, wo);
                            let c = cui_pdf(&mf, wi, wo, HForm::Classic);
                            let t = cui_pdf(&mf, wi, wo, HForm::Printed);
                            let what = format!("{dist:?} α ({au}, {av}) μ_i {mi} μ_o {mo} φ {phi}: p1 {p1} classic {c} printed {t}");
                            assert!(c.is_finite() && c > 0.0 && c >= p1, "{what}");
                            assert!(t.is_finite() && t > 0.0, "{what}");
                            if (t - 1e-3 * mo * FRAC_1_PI).abs() > 0.0 && t < p1 {
                                printed_negative += 1;
                            }
                            if au == 1e-4 && p1 > 1e-6 {
                                assert!((c - p1) <= 1e-3 * p1, "{what}");
                            }
                        }
                    }
                }
            }
        }
        assert!(printed_negative > 0, "the printed H never lowered the density below p_1");
    }
}
