//! What every random walk over the microsurface shares, whichever paper it
//! implements: Russian roulette, the uniform numbers of a sampled vertex and
//! the Lambertian direction of a diffuse facet; and the bidirectional
//! estimator of a position-free path integral (`bdpt.rs`), written once for
//! every surface; the conductor sampling walk of the position-free and the
//! invariance models ([`sample_conductor`]); and the height-explicit walk of
//! Heitz 2016 (`height.rs`), used by `heitz` and by `invariance` on dielectrics.

pub mod bdpt;
pub mod height;

use crate::microfacet::{ConductorFresnel, Microfacet};
use crate::rng::Sampler;
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::f64::consts::PI;

/// The bounds of one walk (every random-walk model; the position-free
/// models' `posfree::Options` adds their segment terms).
#[derive(Clone, Copy, Debug)]
pub struct WalkOptions {
    /// Maximum number of scattering events (vertices).
    pub max_bounces: u32,
    /// Scattering orders counted, 1-based inclusive (k = 1 is single scattering).
    pub orders: (u32, u32),
}

impl WalkOptions {
    /// The order of the last vertex a walk may reach, min(orders.1,
    /// max_bounces); None when that leaves no order to count.
    #[inline]
    pub fn last_order(&self) -> Option<u32> {
        let last = self.orders.1.min(self.max_bounces);
        (last > 0 && self.orders.0 <= last).then_some(last)
    }

    /// The orders counted, from 1 and within the bounce cap (may be empty).
    #[inline]
    pub fn clamped_orders(&self) -> (u32, u32) {
        (self.orders.0.max(1), self.orders.1.min(self.max_bounces))
    }
}

/// First vertex at which Russian roulette may end a walk, in every walk of the
/// crate: the roulette is played from the first continuation on (after vertex
/// 1's estimates). The continuation factor is small for most directions at
/// moderate roughness, and ending those walks early cut the position-free
/// conductor's eval time at GGX α = 0.5 ≈ 3× for ≈ 1.3× the variance per call
/// (measured off-specular), a net efficiency gain; starting at vertex 3 spent
/// most of the time on walks that carried almost no weight.
pub const RR_START: u32 = 1;

/// Russian roulette on the largest channel of a throughput that is ≤ 1 per
/// channel: returns false when the path ends, otherwise divides the
/// throughput by the survival probability (unbiased).
#[inline]
pub fn russian_roulette(throughput: &mut Spectrum, rng: &mut Sampler) -> bool {
    russian_roulette_keep(throughput, rng, 1.0)
}

/// Russian roulette that keeps a path surely while its largest channel is
/// ≥ `keep` and otherwise survives with probability max/keep (unbiased: the
/// throughput is divided by it).
#[inline]
pub fn russian_roulette_keep(throughput: &mut Spectrum, rng: &mut Sampler, keep: f64) -> bool {
    match survival(throughput.max_value() / keep, rng) {
        Some(q) => {
            *throughput *= 1.0 / q;
            true
        }
        None => false,
    }
}

/// [`russian_roulette_keep`] for a scalar throughput (≥ 0).
#[inline]
pub fn roulette_scalar(throughput: &mut f64, rng: &mut Sampler, keep: f64) -> bool {
    match survival(*throughput / keep, rng) {
        Some(q) => {
            *throughput /= q;
            true
        }
        None => false,
    }
}

/// Plays the roulette with survival probability min(1, `ratio`): the
/// probability the throughput must be divided by, or None when the path ends
/// (always for a ratio ≤ 0 or NaN).
#[inline]
fn survival(ratio: f64, rng: &mut Sampler) -> Option<f64> {
    let q = ratio.min(1.0);
    if !(q > 0.0) {
        return None;
    }
    if q < 1.0 && rng.next() >= q {
        return None;
    }
    Some(q)
}

/// How a conductor walk leaves the microsurface, the one part in which the
/// sampling walks of the position-free models and of the invariance model
/// differ: the probability of going on along an upward direction, and the
/// bookkeeping of a downward one.
pub trait ConductorExit {
    /// The probability that the walk goes on along an upward direction of
    /// Λ = `lambda` (it leaves otherwise); None ends the walk without a sample.
    fn up(&mut self, lambda: f64) -> Option<f64>;
    /// A downward direction of |Λ| = `l`; false ends the walk without a sample.
    fn down(&mut self, l: f64) -> bool;
}

/// The sampling walk on specular conductor facets: each vertex reflects about a
/// visible normal, and at each upward direction the walk leaves with the
/// probability `exit` gives, so that the weight is the product of the Fresnel
/// terms. The first vertex uses the caller's (u_exit, u1, u2). At most
/// `max_vertices` vertices; returns (ω_o, weight, order) or None.
pub fn sample_conductor<E: ConductorExit>(
    mf: &Microfacet,
    fresnel: &ConductorFresnel,
    wi: DVec3,
    first: (f64, f64, f64),
    max_vertices: u32,
    exit: &mut E,
    rng: &mut Sampler,
) -> Option<(DVec3, Spectrum, u32)> {
    let mut w = wi;
    let mut weight = Spectrum::ONE;
    for j in 0..max_vertices {
        let (u_exit, u1, u2) = vertex_numbers(j, first, rng);
        let (_, cos_wm, d_next) = mf.reflect_visible(w, u1, u2)?;
        weight *= fresnel.eval(cos_wm);
        if d_next.z > 0.0 {
            let cont = exit.up(mf.lambda(d_next))?;
            if u_exit >= cont {
                return Some((d_next, weight, j + 1));
            }
        } else if !exit.down(mf.abs_lambda(d_next)) {
            return None;
        }
        w = -d_next;
    }
    None
}

/// The three uniform numbers (u_choice, u1, u2) of vertex `j` of a sampled
/// walk: the caller's (from Mitsuba's sample1/sample2) at the first vertex,
/// the walk's own stream after it.
#[inline]
pub fn vertex_numbers(j: u32, first: (f64, f64, f64), rng: &mut Sampler) -> (f64, f64, f64) {
    if j == 0 {
        first
    } else {
        let (a, b) = rng.next2();
        (rng.next(), a, b)
    }
}

/// Cosine-distributed direction about the unit vector n (density ⟨ω,n⟩⁺/π).
#[inline]
pub fn cosine_about(n: DVec3, u1: f64, u2: f64) -> DVec3 {
    // Orthonormal basis (Duff et al. 2017).
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    let r = u1.sqrt();
    let (sp, cp) = (2.0 * PI * u2).sin_cos();
    let z = (1.0 - u1).max(0.0).sqrt();
    (t * (r * cp) + bt * (r * sp) + n * z).normalize()
}
