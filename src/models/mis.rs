//! Densities the random-walk models report for multiple importance sampling.
//!
//! A multiple-scattering BSDF has no closed-form density for its sampler (the
//! walk). Mitsuba still needs one for MIS, so `pdf` (and `sample`'s reported
//! pdf) return a density that is close to the walk's and positive wherever
//! the walk can go; the sample weights stay the walk's own, so any positive
//! density keeps the estimates unbiased (docs/conventions.md).

use super::single::dielectric::pdf as single_dielectric_pdf;
use super::Call;
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
/// - conductor: [`conductor_walk_pdf`] for ω_i above the surface; below it
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
                conductor_walk_pdf(exit, mf, wi, wo)
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
}
