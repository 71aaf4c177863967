//! The scattering models, one folder per paper, each behind the one interface
//! [`ScatteringModel`]:
//!
//! | folder | paper | conductor | dielectric | diffuse |
//! |---|---|---|---|---|
//! | `single/` | Walter 2007 as Mitsuba computes it | ✓ | ✓ | |
//! | `posfree/` | Wang 2022, uncorrelated and correlated segment terms, PT and BDPT | ✓ | ✓ | ✓ |
//! | `heitz/` | Heitz 2016 random walk | ✓ | ✓ | ✓ |
//! | `invariance/` | Cui 2023 invariance principle, PT and BDPT | ✓ | ✓ | ✓ |
//! | `analytic/` | Fast-MSX (Rosales 2023), energy compensation (Turquin 2019) | ✓ | compensation | |
//! | `auto/` | `correlated`, reduced to order 1 where its table (`auto/table.rs`) says it suffices | ✓ | ✓ | ✓ |
//!
//! A model sees one call at a time ([`Call`]): the microfacet statistics, the
//! microsurface's material, the orders to count and a random stream derived
//! from the call's inputs. `mis.rs` holds the densities the random walks
//! report for multiple importance sampling.

pub mod analytic;
pub mod auto;
pub mod heitz;
pub mod invariance;
pub mod mis;
pub mod posfree;
pub mod single;

use crate::config::MisDensity;
use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::{Microfacet, Microsurface};
use crate::rng::{hash_words, Sampler};
use crate::spectrum::Spectrum;
use crate::walk::WalkOptions;
use glam::DVec3;

/// What one BSDF call gives a model: unit directions and a usable material
/// are guaranteed by the caller (`bsdf.rs`).
#[derive(Clone, Copy, Debug)]
pub struct Call {
    pub mf: Microfacet,
    pub surf: Microsurface,
    /// Most vertices a walk may have.
    pub max_bounces: u32,
    /// Scattering orders counted (1 = single scattering), 1-based inclusive,
    /// already within `1..=max_bounces` (may be empty: lo > hi).
    pub orders: (u32, u32),
    /// What the call's random stream is derived from ([`Call::rng`]).
    pub stream: Stream,
    /// The conductor walks' MIS density (`mis.rs`).
    pub mis: MisDensity,
    /// The normals `single`, `fastmsx` and `compensated` sample (`sample_visible`);
    /// the walks draw visible normals whatever it says.
    pub sampling: Sampling,
}

/// The inputs a call's random stream is derived from: the BSDF's `seed` and up
/// to seven words of the call (bit patterns of directions, a key, sample
/// numbers). Hashed only when a stochastic model asks for the stream.
#[derive(Clone, Copy, Debug)]
pub struct Stream {
    seed: u64,
    words: [u64; 7],
    len: usize,
}

impl Stream {
    pub fn new(seed: u64, words: &[u64]) -> Self {
        let mut w = [0u64; 7];
        let len = words.len().min(7);
        w[..len].copy_from_slice(&words[..len]);
        Stream { seed, words: w, len }
    }
}

impl Call {
    /// The call's random stream: the same inputs give the same stream.
    #[inline]
    pub fn rng(&self) -> Sampler {
        let st = &self.stream;
        Sampler::new(hash_words(&[st.seed, hash_words(&st.words[..st.len])]))
    }

    /// The call's bounce cap and orders, as the walks take them.
    #[inline]
    pub fn walk(&self) -> WalkOptions {
        WalkOptions { max_bounces: self.max_bounces, orders: self.orders }
    }

    /// Whether order 1 is counted (the analytic models have no other order).
    #[inline]
    pub fn includes_order_one(&self) -> bool {
        self.orders.0 <= 1
    }
}

/// A sampled direction: `weight` = f·|cos θ_o| / (density of the sampler),
/// `order` the number of microfacet events of the sampled path (1 for the
/// analytic models), `pdf` the density for MIS when the sampler's own density
/// is known in closed form, None when the caller reports the model's `pdf`.
#[derive(Clone, Copy, Debug)]
pub struct Sampled {
    pub wo: DVec3,
    pub weight: Spectrum,
    pub order: u32,
    pub pdf: Option<f64>,
}

/// The interface of every model. Values exclude Mitsuba's specular tints
/// (`bsdf.rs` applies them); dielectric models return the same value in every
/// channel.
pub trait ScatteringModel: Send + Sync + std::fmt::Debug {
    // The surfaces, estimators and distributions a model supports are its row
    // of `MODELS` in config.rs (the one table of names), not methods here.
    /// One estimate of f(ω_i, ω_o)·|cos θ_o| restricted to `call.orders`
    /// (deterministic for the analytic models).
    fn eval(&self, call: &Call, wi: DVec3, wo: DVec3) -> Spectrum;
    /// The density reported for MIS (`sample` reports the same one).
    fn pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> f64;
    /// `eval` and `pdf` together (a model may share work between them).
    fn eval_pdf(&self, call: &Call, wi: DVec3, wo: DVec3) -> (Spectrum, f64) {
        (self.eval(call, wi, wo), self.pdf(call, wi, wo))
    }
    /// Samples ω_o; `first` = (sample1, u1, u2) of the caller drives the
    /// first vertex, the call's stream the rest.
    fn sample(&self, call: &Call, wi: DVec3, first: (f64, f64, f64)) -> Option<Sampled>;
}
