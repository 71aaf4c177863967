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

/// One choice of a configuration parameter: its value, its name in scenes
/// and error messages, and its code in the C ABI (`MSX_SURFACE_*`, …).
#[derive(Clone, Copy, Debug)]
pub struct Entry<T> {
    pub value: T,
    pub name: &'static str,
    pub code: u32,
}

/// Every surface, in the order of the docs; the code is `Surface as u32`.
pub const SURFACES: [Entry<Surface>; 3] = [
    Entry { value: Surface::Conductor, name: "conductor", code: 0 },
    Entry { value: Surface::Dielectric, name: "dielectric", code: 1 },
    Entry { value: Surface::Diffuse, name: "diffuse", code: 2 },
];

pub const DISTRIBUTIONS: [Entry<Distribution>; 2] =
    [Entry { value: Distribution::Beckmann, name: "beckmann", code: 0 }, Entry { value: Distribution::Ggx, name: "ggx", code: 1 }];

pub const ESTIMATORS: [Entry<Estimator>; 2] =
    [Entry { value: Estimator::Pt, name: "pt", code: 0 }, Entry { value: Estimator::Bdpt, name: "bdpt", code: 1 }];

/// The conductor walks' MIS densities. Code 0 is not a density: in the C ABI it
/// asks for the default (`MSX_MIS_DENSITY_DEFAULT`, [`DEFAULT_MIS_DENSITY`]).
pub const MIS_DENSITIES: [Entry<MisDensity>; 3] = [
    Entry { value: MisDensity::SingleCosine, name: "single_cosine", code: 1 },
    Entry { value: MisDensity::Cui, name: "cui", code: 2 },
    Entry { value: MisDensity::CuiTypo, name: "cui_typo", code: 3 },
];

/// A model's row of [`MODELS`]: its name and code, and the facts about it
/// that the rest of the project branches on (checks in `bsdf.rs`, the C ABI's
/// `msx_choice`, the Python package, the native plugin, the evaluation).
#[derive(Clone, Copy, Debug)]
pub struct ModelInfo {
    pub model: Model,
    pub name: &'static str,
    /// Its `MSX_MODEL_*` code; never reused.
    pub code: u32,
    /// The surfaces it is implemented for.
    pub surfaces: &'static [Surface],
    /// The surfaces on which it accepts `estimator="bdpt"` (every model has `pt`).
    pub bdpt: &'static [Surface],
    /// The distributions it is defined for.
    pub distributions: &'static [Distribution],
    /// `eval` is one unbiased estimate of a random walk (else a closed form, deterministic).
    pub random_walk: bool,
    /// `eval` restricted to scattering orders gives the model's own value per order
    /// (a closed form that is not `single` reports its whole value as order 1).
    pub per_order: bool,
    /// It estimates the Smith microsurface's multiple-scattering BSDF itself, without
    /// approximation (the reference the others are measured against).
    pub exact: bool,
    /// The model whose walk it runs: itself, or (for `auto`) the model it shortcuts.
    pub runs: Model,
}

const ALL_THREE: &[Surface] = &[Surface::Conductor, Surface::Dielectric, Surface::Diffuse];
const BOTH_DISTRIBUTIONS: &[Distribution] = &[Distribution::Beckmann, Distribution::Ggx];

/// Every model, in the order of the docs. The one table of models: a new model
/// is a variant of [`Model`], a row here and its implementation in `bsdf.rs`
/// (docs/adding-a-model.md).
pub const MODELS: [ModelInfo; 8] = [
    ModelInfo {
        model: Model::Single,
        name: "single",
        code: 0,
        surfaces: &[Surface::Conductor, Surface::Dielectric],
        bdpt: &[],
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: false,
        per_order: true,
        exact: false,
        runs: Model::Single,
    },
    ModelInfo {
        model: Model::Uncorrelated,
        name: "uncorrelated",
        code: 1,
        surfaces: ALL_THREE,
        bdpt: ALL_THREE,
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: true,
        per_order: true,
        exact: false,
        runs: Model::Uncorrelated,
    },
    ModelInfo {
        model: Model::Correlated,
        name: "correlated",
        code: 2,
        surfaces: ALL_THREE,
        bdpt: ALL_THREE,
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: true,
        per_order: true,
        exact: false,
        runs: Model::Correlated,
    },
    ModelInfo {
        model: Model::Heitz,
        name: "heitz",
        code: 3,
        surfaces: ALL_THREE,
        bdpt: &[],
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: true,
        per_order: true,
        exact: true,
        runs: Model::Heitz,
    },
    // BDPT on conductors only: its segment term S_k is the whole path's exit probability
    // (src/models/invariance/recursion.rs). On a dielectric the heights are integrated only up
    // to the first refraction (dielectric.rs), and the diffuse microsurface's complete recursion
    // has no BDPT here (yet).
    ModelInfo {
        model: Model::Invariance,
        name: "invariance",
        code: 4,
        surfaces: ALL_THREE,
        bdpt: &[Surface::Conductor],
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: true,
        per_order: true,
        exact: true,
        runs: Model::Invariance,
    },
    // Rosales 2023 is defined for GGX only (src/models/analytic/fastmsx.rs).
    ModelInfo {
        model: Model::FastMsx,
        name: "fastmsx",
        code: 5,
        surfaces: &[Surface::Conductor],
        bdpt: &[],
        distributions: &[Distribution::Ggx],
        random_walk: false,
        per_order: false,
        exact: false,
        runs: Model::FastMsx,
    },
    ModelInfo {
        model: Model::Compensated,
        name: "compensated",
        code: 6,
        surfaces: &[Surface::Conductor, Surface::Dielectric],
        bdpt: &[],
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: false,
        per_order: false,
        exact: false,
        runs: Model::Compensated,
    },
    ModelInfo {
        model: Model::Auto,
        name: "auto",
        code: 7,
        surfaces: ALL_THREE,
        bdpt: ALL_THREE,
        distributions: BOTH_DISTRIBUTIONS,
        random_walk: true,
        per_order: true,
        exact: false,
        runs: Model::Correlated,
    },
];

/// A configuration parameter with a fixed set of named choices: its tables
/// above give every name and code once; these functions read them.
pub trait Choice: Copy + PartialEq + fmt::Debug + 'static {
    /// The parameter's name in scenes and error messages.
    const PARAMETER: &'static str;
    /// How many choices there are.
    fn count() -> usize;
    /// The index-th choice (value, name, code), in the order of the docs.
    fn nth(index: usize) -> Option<(Self, &'static str, u32)>;

    fn all() -> impl Iterator<Item = (Self, &'static str, u32)> {
        (0..Self::count()).filter_map(Self::nth)
    }
    fn name(self) -> &'static str {
        Self::all().find(|c| c.0 == self).map_or("?", |c| c.1)
    }
    fn code(self) -> u32 {
        Self::all().find(|c| c.0 == self).map_or(u32::MAX, |c| c.2)
    }
    fn from_code(code: u32) -> Option<Self> {
        Self::all().find(|c| c.2 == code).map(|c| c.0)
    }
    fn from_name(name: &str) -> Option<Self> {
        Self::all().find(|c| c.1 == name).map(|c| c.0)
    }
    /// The allowed values for an error message: "conductor (0), dielectric (1), diffuse (2)".
    fn allowed() -> String {
        Self::all().map(|(_, name, code)| format!("{name} ({code})")).collect::<Vec<_>>().join(", ")
    }
}

macro_rules! entry_choice {
    ($ty:ty, $param:literal, $table:expr) => {
        impl Choice for $ty {
            const PARAMETER: &'static str = $param;
            fn count() -> usize {
                $table.len()
            }
            fn nth(index: usize) -> Option<(Self, &'static str, u32)> {
                $table.get(index).map(|e| (e.value, e.name, e.code))
            }
        }
        impl $ty {
            /// Its name in scenes (its table row).
            pub fn name(self) -> &'static str {
                <Self as Choice>::name(self)
            }
        }
    };
}

entry_choice!(Surface, "surface", SURFACES);
entry_choice!(Distribution, "distribution", DISTRIBUTIONS);
entry_choice!(Estimator, "estimator", ESTIMATORS);
entry_choice!(MisDensity, "mis_density", MIS_DENSITIES);

impl Choice for Model {
    const PARAMETER: &'static str = "model";
    fn count() -> usize {
        MODELS.len()
    }
    fn nth(index: usize) -> Option<(Self, &'static str, u32)> {
        MODELS.get(index).map(|m| (m.model, m.name, m.code))
    }
}

impl Model {
    /// Its name in scenes (its row of [`MODELS`]).
    pub fn name(self) -> &'static str {
        self.info().name
    }
    /// Its row of [`MODELS`].
    pub fn info(self) -> &'static ModelInfo {
        // Every variant has a row (the test `every_model_has_one_row` below).
        MODELS.iter().find(|m| m.model == self).unwrap_or(&MODELS[0])
    }
}

/// The MIS density of the conductor walks when the user gives none.
pub const DEFAULT_MIS_DENSITY: MisDensity = MisDensity::SingleCosine;

/// Every surface, in the order of the docs (and of `Surface as usize`).
pub const ALL_SURFACES: [Surface; 3] = {
    let mut out = [Surface::Conductor; 3];
    let mut i = 0;
    while i < SURFACES.len() {
        out[i] = SURFACES[i].value;
        i += 1;
    }
    out
};

/// Every model, in the order of the docs.
pub const ALL_MODELS: [Model; MODELS.len()] = {
    let mut out = [Model::Single; MODELS.len()];
    let mut i = 0;
    while i < MODELS.len() {
        out[i] = MODELS[i].model;
        i += 1;
    }
    out
};

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
    /// Mitsuba's `sample_visible`: false makes `single`, `fastmsx` and
    /// `compensated` draw microfacet normals from D(m)·cos θ_m instead of the
    /// visible normals (on a dielectric with roughdielectric's widened α). It
    /// changes their noise, not their expected value. The random walks draw
    /// visible normals by construction and ignore it.
    pub sample_visible: bool,
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
            sample_visible: true,
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    fn check<T: Choice>() {
        let all: Vec<_> = T::all().collect();
        assert_eq!(all.len(), T::count());
        let codes: HashSet<_> = all.iter().map(|c| c.2).collect();
        let names: HashSet<_> = all.iter().map(|c| c.1).collect();
        assert_eq!(codes.len(), all.len(), "{}: codes must be unique", T::PARAMETER);
        assert_eq!(names.len(), all.len(), "{}: names must be unique", T::PARAMETER);
        for (value, name, code) in all {
            assert!(!name.is_empty() && name.bytes().all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_'), "{name}");
            assert_eq!(T::from_name(name), Some(value));
            assert_eq!(T::from_code(code), Some(value));
            assert_eq!(value.name(), name);
            assert_eq!(value.code(), code);
        }
        assert_eq!(T::from_name("no such name"), None);
        assert_eq!(T::from_code(u32::MAX), None);
    }

    #[test]
    fn codes_are_unique_and_names_round_trip() {
        check::<Surface>();
        check::<Distribution>();
        check::<Model>();
        check::<Estimator>();
        check::<MisDensity>();
    }

    #[test]
    fn every_model_has_one_row_and_sane_capabilities() {
        for (i, m) in ALL_MODELS.iter().enumerate() {
            assert_eq!(MODELS.iter().filter(|r| r.model == *m).count(), 1, "{m:?}");
            let info = m.info();
            assert_eq!((info.model, info.code), (MODELS[i].model, MODELS[i].code));
            assert!(!info.surfaces.is_empty() && !info.distributions.is_empty(), "{}", info.name);
            assert!(info.bdpt.iter().all(|s| info.surfaces.contains(s)), "{}: bdpt on a surface it does not support", info.name);
            assert!(info.bdpt.is_empty() || info.random_walk, "{}: a closed form has no BDPT", info.name);
            assert!(!info.exact || info.random_walk, "{}", info.name);
            let runs = info.runs.info();
            assert_eq!(runs.runs, runs.model, "{}: runs a model that itself runs another", info.name);
            assert!(info.surfaces.iter().all(|s| runs.surfaces.contains(s)), "{}", info.name);
        }
        for (i, s) in ALL_SURFACES.iter().enumerate() {
            assert_eq!(*s as usize, i);
            assert_eq!(s.code(), i as u32);
        }
    }

    #[test]
    fn allowed_lists_every_name_with_its_code() {
        assert_eq!(Surface::allowed(), "conductor (0), dielectric (1), diffuse (2)");
        assert_eq!(Estimator::allowed(), "pt (0), bdpt (1)");
        let expected: Vec<_> = MODELS.iter().map(|m| format!("{} ({})", m.name, m.code)).collect();
        assert_eq!(Model::allowed(), expected.join(", "));
        assert!(Model::allowed().starts_with("single (0), uncorrelated (1), correlated (2), heitz (3), invariance (4)"));
    }
}
