//! Densities the random-walk models report for multiple importance sampling.
//!
//! A multiple-scattering BSDF has no closed-form density for its sampler (the
//! walk). Mitsuba still needs one for MIS, so `pdf` (and `sample`'s reported
//! pdf) return a density that is close to the walk's and positive wherever
//! the walk can go; the sample weights stay the walk's own, so any positive
//! density keeps the estimates unbiased (docs/conventions.md).

use super::{Call, Microsurface};
use crate::microfacet::Microfacet;
use super::single::dielectric::pdf as single_dielectric_pdf;
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
    let table = AlbedoTable::get(mf.dist);
    let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
    let lambda_o = mf.lambda(wo);
    let (exit, e1) = match exit {
        OrderOneExit::Separable => (1.0 / (1.0 + lambda_o), table.e1_uncorrelated(alpha, wi.z)),
        OrderOneExit::HeightCorrelated => {
            let l0 = 1.0 + mf.lambda(wi);
            (l0 / (l0 + lambda_o), table.e1_correlated(alpha, wi.z))
        }
    };
    mf.reflect_pdf(wi, wo) * exit + (1.0 - e1).max(1e-3) * wo.z * FRAC_1_PI
}

/// Weight of the cosine lobe in the MIS density of the dielectric walks:
/// grows with roughness like the multiply scattered energy does (≈ 5 % at
/// α = 0.1, 33 % at α = 1).
pub fn diffuse_fraction(mf: &Microfacet) -> f64 {
    let a = (mf.alpha_u * mf.alpha_v).sqrt();
    (a / (a + 2.0)).min(0.75)
}
