//! The configuration vocabulary: what a user chooses once per BSDF (surface,
//! distribution, model, estimator, bounce cap, `auto`'s tolerance), the names
//! these choices have in scenes and in the C ABI, and their defaults.
//!
//! This module depends on nothing else in the crate, so every layer may use it
//! (docs/architecture.md): the models read `Surface` and `Estimator` from here,
//! and `bsdf.rs` maps a [`Config`] to one model.

use std::fmt;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    Conductor,
    Dielectric,
    Diffuse,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Distribution {
    Beckmann,
    Ggx,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    Single,
    Uncorrelated,
    Correlated,
    Heitz,
    Invariance,
    FastMsx,
    Compensated,
    /// `correlated`, reduced per call to its analytic order 1 where the
    /// multiply scattered energy is under `Config::tolerance` (models/auto/).
    Auto,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimator {
    Pt,
    Bdpt,
}

/// The density the conductor walks report for multiple importance sampling
/// (`src/models/mis.rs`). It changes the noise of a render, never its
/// expected value. Dielectric and diffuse walks and the analytic models have
/// one density each and ignore it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MisDensity {
    /// Exact order-1 exit density plus a cosine lobe carrying 1 − E_1.
    SingleCosine,
    /// Cui et al. 2023: visible-normal reflection density plus Chandrasekhar's
    /// multiple-scattering term with the classic H approximation.
    Cui,
    /// `Cui` with the H approximation as the authors' released code prints it
    /// (docs/paper-notes.md): kept for the measurement in benches/README.md.
    CuiTypo,
}

impl Surface {
    pub fn name(self) -> &'static str {
        match self {
            Surface::Conductor => "conductor",
            Surface::Dielectric => "dielectric",
            Surface::Diffuse => "diffuse",
        }
    }
}

impl Model {
    pub fn name(self) -> &'static str {
        match self {
            Model::Single => "single",
            Model::Uncorrelated => "uncorrelated",
            Model::Correlated => "correlated",
            Model::Heitz => "heitz",
            Model::Invariance => "invariance",
            Model::FastMsx => "fastmsx",
            Model::Compensated => "compensated",
            Model::Auto => "auto",
        }
    }
}

impl MisDensity {
    pub fn name(self) -> &'static str {
        match self {
            MisDensity::SingleCosine => "single_cosine",
            MisDensity::Cui => "cui",
            MisDensity::CuiTypo => "cui_typo",
        }
    }
}

/// Every MIS density, in the order of the docs.
pub const ALL_MIS_DENSITIES: [MisDensity; 3] = [MisDensity::SingleCosine, MisDensity::Cui, MisDensity::CuiTypo];

/// The MIS density of the conductor walks when the user gives none.
pub const DEFAULT_MIS_DENSITY: MisDensity = MisDensity::SingleCosine;

/// Every surface, in the order of the docs (and of `Surface as usize`).
pub const ALL_SURFACES: [Surface; 3] = [Surface::Conductor, Surface::Dielectric, Surface::Diffuse];

/// Every model, in the order of the docs.
pub const ALL_MODELS: [Model; 8] =
    [Model::Single, Model::Uncorrelated, Model::Correlated, Model::Heitz, Model::Invariance, Model::FastMsx, Model::Compensated, Model::Auto];

/// Bounce cap when the user gives none. Russian roulette ends most paths far
/// earlier; the cap only bounds the cost at extreme roughness.
pub const DEFAULT_MAX_BOUNCES: u32 = 64;
pub const MAX_BOUNCES_LIMIT: u32 = 1024;

/// `auto`'s default tolerance: 1 % of the scattered energy may be omitted.
pub const DEFAULT_TOLERANCE: f64 = 0.01;

#[derive(Clone, Copy, Debug)]
pub struct Config {
    pub surface: Surface,
    pub distribution: Distribution,
    pub model: Model,
    pub estimator: Estimator,
    pub max_bounces: u32,
    pub channels: usize,
    pub seed: u64,
    /// `auto` only: fraction of the scattered energy order 1 alone may omit.
    pub tolerance: f64,
    /// The conductor walks' MIS density (ignored by every other model).
    pub mis_density: MisDensity,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            surface: Surface::Conductor,
            distribution: Distribution::Beckmann,
            model: Model::Correlated,
            estimator: Estimator::Pt,
            max_bounces: DEFAULT_MAX_BOUNCES,
            channels: 3,
            seed: 0,
            tolerance: DEFAULT_TOLERANCE,
            mis_density: DEFAULT_MIS_DENSITY,
        }
    }
}

/// An invalid parameter: its name and what is allowed.
#[derive(Clone, Debug, PartialEq)]
pub struct ParamError {
    pub parameter: &'static str,
    pub message: String,
}

impl fmt::Display for ParamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "invalid parameter '{}': {}", self.parameter, self.message)
    }
}

impl std::error::Error for ParamError {}
