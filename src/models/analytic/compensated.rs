//! Energy compensation (`model="compensated"`): Turquin 2019 albedo scaling of
//! the single-scattering lobe with the Kulla & Conty 2017 Fresnel term — what
//! production renderers ship instead of a random walk. A comparison row, not
//! a multiple-scattering simulation:
//!
//!   f = f_ss · (1 + (F_ms/F_avg) · (1 − E(μ_i))/E(μ_i)),
//!   F_ms = F_avg² E_avg / (1 − F_avg (1 − E_avg))      (Kulla-Conty, per channel)
//!
//! E(μ) is the directional albedo of `single` with F = 1, E_avg = 2∫E(μ)μ dμ,
//! F_avg = 2∫F(μ)μ dμ. With F = 1 the scaled lobe has albedo exactly 1 at the
//! tabulated nodes; with Fresnel it adds F_ms·(1 − E) like Kulla-Conty's lobe.
//! The albedo table (`src/tables/albedo.rs`) is computed by this project's own code on
//! first use (deterministic stratified quadrature over visible normals).

use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::ConductorFresnel;
use crate::microfacet::Microfacet;
use crate::models::single::conductor as single;
use crate::spectrum::{Spectrum, MAX_CHANNELS};
pub use crate::tables::albedo::{single_albedo, AlbedoTable};
use glam::DVec3;
use std::cell::Cell;

/// The last (η, k) seen on this thread and its average Fresnel term.
type LastAverage = Option<([f64; MAX_CHANNELS], [f64; MAX_CHANNELS], Spectrum)>;

/// Hemispherical average F_avg = 2∫F(μ)μ dμ of the conductor Fresnel per
/// channel (16-point Gauss-Legendre in μ), memoised per thread for the last IOR.
// The Gauss-Legendre nodes and weights are kept as published.
#[allow(clippy::excessive_precision)]
pub fn fresnel_average(fresnel: &ConductorFresnel) -> Spectrum {
    if fresnel.mirror {
        return Spectrum::ONE;
    }
    thread_local! {
        static LAST: Cell<LastAverage> = const { Cell::new(None) };
    }
    if let Some((eta, k, avg)) = LAST.with(|c| c.get()) {
        if eta == fresnel.eta.0 && k == fresnel.k.0 {
            return avg;
        }
    }
    const X: [f64; 8] = [
        0.0950125098376374,
        0.2816035507792589,
        0.4580167776572274,
        0.6178762444026438,
        0.7554044083550030,
        0.8656312023878318,
        0.9445750230732326,
        0.9894009349916499,
    ];
    const W: [f64; 8] = [
        0.1894506104550685,
        0.1826034150449236,
        0.1691565193950025,
        0.1495959888165767,
        0.1246289712555339,
        0.0951585116824928,
        0.0622535239386479,
        0.0271524594117541,
    ];
    let mut avg = Spectrum::ZERO;
    for s in [-1.0, 1.0] {
        for (x, w) in X.iter().zip(W.iter()) {
            let mu = 0.5 * (1.0 + s * x);
            // 2∫₀¹ F μ dμ = ∫₋₁¹ F(μ) μ dx with μ = (1+x)/2.
            avg += fresnel.eval(mu) * (w * mu);
        }
    }
    LAST.with(|c| c.set(Some((fresnel.eta.0, fresnel.k.0, avg))));
    avg
}

/// Per-channel scale applied to `single` for incidence ω_i.
pub fn scale(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3) -> Spectrum {
    let table = AlbedoTable::get(mf.dist);
    let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
    let e = table.e(alpha, wi.z);
    let e_avg = table.e_avg(alpha);
    let f_avg = fresnel_average(fresnel);
    let ratio = (1.0 - e) / e;
    f_avg.map(|fa| {
        let f_ms = fa * fa * e_avg / (1.0 - fa * (1.0 - e_avg));
        let s = 1.0 + if fa > 0.0 { f_ms / fa * ratio } else { 0.0 };
        if s.is_finite() {
            s
        } else {
            1.0
        }
    })
}

pub fn eval(mf: &Microfacet, fresnel: &ConductorFresnel, wi: DVec3, wo: DVec3) -> Spectrum {
    if wi.z <= 0.0 || wo.z <= 0.0 {
        return Spectrum::ZERO;
    }
    single::eval(mf, fresnel, wi, wo) * scale(mf, fresnel, wi)
}

/// Samples as `single` (with its `sampling`); weight = eval/pdf.
pub fn sample(mf: &Microfacet, fresnel: &ConductorFresnel, sampling: Sampling, wi: DVec3, u1: f64, u2: f64) -> Option<(DVec3, f64, Spectrum)> {
    let (wo, pdf, weight) = single::sample(mf, fresnel, sampling, wi, u1, u2)?;
    Some((wo, pdf, weight * scale(mf, fresnel, wi)))
}
