//! Static configuration (surface, distribution, model, estimator) → dispatch.
//! Per-hit values (roughness, IOR, reflectance) arrive with every call as a
//! [`Material`], since Mitsuba evaluates textures at the hit.

use crate::microfacet::{Distribution, Microfacet};
use crate::models::analytic::{compensated, compensated_dielectric, fastmsx};
use crate::models::invariance::{conductor as invariance, dielectric as invariance_dielectric, general as invariance_general};
use crate::models::posfree::{
    self, bdpt_conductor as posfree_bdpt, bdpt_dielectric as posfree_bdpt_dielectric, bdpt_diffuse as posfree_bdpt_diffuse,
    dielectric as posfree_dielectric, diffuse as posfree_diffuse, Segments,
};
use crate::models::single::{conductor as single, dielectric as single_dielectric};
use crate::models::{auto, heitz, ConductorFresnel, Microsurface, WalkOptions};
use crate::tables::albedo::AlbedoTable;
use crate::rng::{hash_words, Sampler};
use crate::spectrum::{Spectrum, MAX_CHANNELS};
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;
use std::fmt;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Surface {
    Conductor,
    Dielectric,
    Diffuse,
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
    /// multiply scattered energy is under `Config::tolerance` (models/auto.rs).
    Auto,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Estimator {
    Pt,
    Bdpt,
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

/// Models implemented for a surface (README.md's parameter table), in the order of the docs.
pub fn models_for(surface: Surface) -> &'static [Model] {
    match surface {
        Surface::Conductor => &[
            Model::Single,
            Model::Uncorrelated,
            Model::Correlated,
            Model::Heitz,
            Model::Invariance,
            Model::FastMsx,
            Model::Compensated,
            Model::Auto,
        ],
        Surface::Dielectric => &[Model::Single, Model::Uncorrelated, Model::Correlated, Model::Heitz, Model::Invariance, Model::Compensated, Model::Auto],
        Surface::Diffuse => &[Model::Uncorrelated, Model::Correlated, Model::Heitz, Model::Invariance, Model::Auto],
    }
}

/// Models that accept `estimator="bdpt"`.
pub fn bdpt_models(surface: Surface) -> &'static [Model] {
    match surface {
        Surface::Conductor | Surface::Dielectric | Surface::Diffuse => &[Model::Uncorrelated, Model::Correlated, Model::Auto],
    }
}

/// Bounce cap when the user gives none. Russian roulette ends most paths far
/// earlier; the cap only bounds the cost at extreme roughness.
pub const DEFAULT_MAX_BOUNCES: u32 = 64;
pub const MAX_BOUNCES_LIMIT: u32 = 1024;

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
            tolerance: auto::DEFAULT_TOLERANCE,
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

/// Values that may vary per hit (textures).
#[derive(Clone, Copy, Debug)]
pub struct Material {
    pub alpha_u: f64,
    pub alpha_v: f64,
    pub eta: Spectrum,
    pub k: Spectrum,
    pub specular_reflectance: Spectrum,
    /// Dielectric: relative IOR η_int/η_ext.
    pub ior: f64,
    pub specular_transmittance: Spectrum,
    /// Diffuse microsurface albedo.
    pub reflectance: Spectrum,
    /// Mitsuba's TransportMode::Radiance (true) or Importance (false).
    pub radiance: bool,
}

impl Material {
    /// A perfect mirror (η = 0, k = 1: F = 1) of roughness α.
    pub fn mirror(alpha: f64) -> Self {
        Material {
            alpha_u: alpha,
            alpha_v: alpha,
            eta: Spectrum::ZERO,
            k: Spectrum::ONE,
            specular_reflectance: Spectrum::ONE,
            ior: 1.5046,
            specular_transmittance: Spectrum::ONE,
            reflectance: Spectrum::ONE,
            radiance: true,
        }
    }
}

/// Largest conductor η and k, dielectric IOR (and smallest: its inverse) and
/// tint accepted per call; values beyond are clamped. No real material comes
/// near; the bound keeps products of these values finite.
const MATERIAL_VALUE_MAX: f64 = 1e4;

/// |η − 1| up to which a dielectric counts as index-matched (no scattering).
const INDEX_MATCHED: f64 = 1e-6;

impl Material {
    /// This call's values made safe for the models (docs/conventions.md): None
    /// if a value the surface uses is NaN or infinite (the call then returns
    /// zero); tints clamped into [0, MATERIAL_VALUE_MAX], the diffuse albedo
    /// into [0, 1] (above 1 a walk would gain energy at every bounce), η and k
    /// into [0, MATERIAL_VALUE_MAX] and the IOR into
    /// [1/MATERIAL_VALUE_MAX, MATERIAL_VALUE_MAX]. α is clamped by
    /// `Microfacet::new`. Only the first `channels` channels are read.
    fn usable(&self, surface: Surface, channels: usize) -> Option<Material> {
        let finite = |s: &Spectrum| s.0[..channels].iter().all(|v| v.is_finite());
        // Channels beyond `channels` are zeroed: what the caller left there must not steer a walk
        // (Russian roulette looks at the largest channel).
        let clamp = |s: Spectrum, hi: f64| Spectrum(std::array::from_fn(|c| if c < channels { s.0[c].clamp(0.0, hi) } else { 0.0 }));
        if !(self.alpha_u.is_finite() && self.alpha_v.is_finite()) {
            return None;
        }
        let mut m = *self;
        match surface {
            Surface::Conductor => {
                if !(finite(&m.eta) && finite(&m.k) && finite(&m.specular_reflectance)) {
                    return None;
                }
                m.eta = clamp(m.eta, MATERIAL_VALUE_MAX);
                m.k = clamp(m.k, MATERIAL_VALUE_MAX);
                m.specular_reflectance = clamp(m.specular_reflectance, MATERIAL_VALUE_MAX);
            }
            Surface::Dielectric => {
                if !(m.ior.is_finite() && m.ior > 0.0 && finite(&m.specular_reflectance) && finite(&m.specular_transmittance)) {
                    return None;
                }
                // An index-matched interface does not scatter: its transmission
                // is a delta, which a rough BSDF cannot represent.
                if (m.ior - 1.0).abs() <= INDEX_MATCHED {
                    return None;
                }
                m.ior = m.ior.clamp(1.0 / MATERIAL_VALUE_MAX, MATERIAL_VALUE_MAX);
                m.specular_reflectance = clamp(m.specular_reflectance, MATERIAL_VALUE_MAX);
                m.specular_transmittance = clamp(m.specular_transmittance, MATERIAL_VALUE_MAX);
            }
            Surface::Diffuse => {
                if !finite(&m.reflectance) {
                    return None;
                }
                m.reflectance = clamp(m.reflectance, 1.0);
            }
        }
        Some(m)
    }
}

/// Result of `sample`: direction, the pdf reported for MIS, and the weight
/// f·cos θ_o / p (unbiased for the multiple-scattering models).
#[derive(Clone, Copy, Debug)]
pub struct BsdfSample {
    pub wo: DVec3,
    pub pdf: f64,
    pub weight: Spectrum,
}

#[derive(Clone, Debug)]
pub struct Bsdf {
    cfg: Config,
    /// `auto`: where order 1 alone is within the configured tolerance.
    auto_rule: Option<std::sync::Arc<auto::OrderOneRule>>,
}

fn finite_unit(v: DVec3) -> Option<DVec3> {
    if !v.is_finite() {
        return None;
    }
    let len = v.length();
    if !(len > 0.0) || !len.is_finite() {
        return None;
    }
    Some(v / len)
}

impl Bsdf {
    pub fn new(cfg: Config) -> Result<Bsdf, ParamError> {
        if cfg.channels == 0 || cfg.channels > MAX_CHANNELS {
            return Err(ParamError { parameter: "channels", message: format!("must be 1..={MAX_CHANNELS}, got {}", cfg.channels) });
        }
        let names = |ms: &[Model]| ms.iter().map(|m| m.name()).collect::<Vec<_>>().join(", ");
        let allowed = models_for(cfg.surface);
        if !allowed.contains(&cfg.model) {
            return Err(ParamError {
                parameter: "model",
                message: format!(
                    "model '{}' is not available for surface '{}'; allowed: {}",
                    cfg.model.name(),
                    cfg.surface.name(),
                    if allowed.is_empty() { "none yet (surface not implemented)".into() } else { names(allowed) }
                ),
            });
        }
        if cfg.model == Model::FastMsx && cfg.distribution != Distribution::Ggx {
            return Err(ParamError {
                parameter: "distribution",
                message: "model 'fastmsx' (Rosales 2023) is defined for distribution 'ggx' only".into(),
            });
        }
        if cfg.estimator == Estimator::Bdpt && !bdpt_models(cfg.surface).contains(&cfg.model) {
            return Err(ParamError {
                parameter: "estimator",
                message: format!(
                    "estimator 'bdpt' is not available for model '{}' on surface '{}'; bdpt models: {}",
                    cfg.model.name(),
                    cfg.surface.name(),
                    names(bdpt_models(cfg.surface))
                ),
            });
        }
        if !(cfg.tolerance > 0.0 && cfg.tolerance < 1.0) {
            return Err(ParamError {
                parameter: "auto_tolerance",
                message: format!("must lie in (0, 1) (fraction of the scattered energy), got {}", cfg.tolerance),
            });
        }
        if cfg.max_bounces == 0 || cfg.max_bounces > MAX_BOUNCES_LIMIT {
            return Err(ParamError {
                parameter: "max_bounces",
                message: format!("must be 1..={MAX_BOUNCES_LIMIT}, got {}", cfg.max_bounces),
            });
        }
        let auto_rule = (cfg.model == Model::Auto).then(|| {
            let surface = match cfg.surface {
                Surface::Conductor => auto::TableSurface::Conductor,
                Surface::Dielectric => auto::TableSurface::Dielectric,
                Surface::Diffuse => auto::TableSurface::Diffuse,
            };
            std::sync::Arc::new(auto::OrderOneRule::new(surface, cfg.distribution, cfg.tolerance))
        });
        Ok(Bsdf { cfg, auto_rule })
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }

    fn microfacet(&self, mat: &Material) -> Microfacet {
        Microfacet::new(self.cfg.distribution, mat.alpha_u, mat.alpha_v)
    }

    fn fresnel(&self, mat: &Material) -> ConductorFresnel {
        ConductorFresnel::new(mat.eta, mat.k, self.cfg.channels)
    }

    /// The model a call runs and its bounce cap: the configured ones, except
    /// that `auto` runs `correlated`, with one bounce where models/auto.rs
    /// finds order 1 alone within the tolerance for this call's roughness,
    /// incidence and IOR.
    fn resolve(&self, mat: &Material, wi: DVec3) -> (Model, u32) {
        let Some(rule) = &self.auto_rule else { return (self.cfg.model, self.cfg.max_bounces) };
        if wi.z < 0.0 && self.cfg.surface == Surface::Conductor {
            // Below the macro surface the tables (built for ω_i above) do not apply: the full model.
            return (Model::Correlated, self.cfg.max_bounces);
        }
        let eta = match self.cfg.surface {
            Surface::Dielectric if wi.z > 0.0 => mat.ior,
            Surface::Dielectric => 1.0 / mat.ior,
            _ => 1.0,
        };
        (Model::Correlated, rule.cap(mat.alpha_u.max(mat.alpha_v), wi.z.abs(), eta, self.cfg.max_bounces))
    }

    /// Walk options of `model` (segment terms of the position-free models;
    /// the others ignore them) with the bounce cap `max_bounces`.
    fn walk_options(model: Model, max_bounces: u32) -> WalkOptions {
        let segments = if model == Model::Uncorrelated { Segments::Uncorrelated } else { Segments::Correlated };
        WalkOptions { segments, max_bounces, orders: (1, max_bounces) }
    }

    /// A random stream determined by the BSDF's `seed` and the call's inputs.
    fn seeded(&self, words: &[u64]) -> Sampler {
        Sampler::new(hash_words(&[self.cfg.seed, hash_words(words)]))
    }

    /// f(ω_i, ω_o)·|cos θ_o| per channel. `key` decorrelates calls (the plugin
    /// passes a per-call counter); the same inputs, seed and key give the same result.
    pub fn eval(&self, mat: &Material, wi: DVec3, wo: DVec3, key: u64) -> Spectrum {
        self.eval_orders(mat, wi, wo, key, (1, u32::MAX))
    }

    /// `eval` restricted to scattering orders `orders.0 ..= orders.1` (1 = single).
    /// Analytic models (single, fastmsx, compensated) have no orders beyond 1
    /// in this sense: they return their whole value when order 1 is included.
    pub fn eval_orders(&self, mat: &Material, wi: DVec3, wo: DVec3, key: u64, orders: (u32, u32)) -> Spectrum {
        let (Some(wi), Some(wo)) = (finite_unit(wi), finite_unit(wo)) else { return Spectrum::ZERO };
        let Some(mat) = mat.usable(self.cfg.surface, self.cfg.channels) else { return Spectrum::ZERO };
        self.eval_checked(&mat, wi, wo, key, orders)
    }

    /// `eval_orders` on inputs already checked (unit directions, usable material).
    fn eval_checked(&self, mat: &Material, wi: DVec3, wo: DVec3, key: u64, orders: (u32, u32)) -> Spectrum {
        if orders.0 > orders.1 {
            return Spectrum::ZERO;
        }
        let mf = self.microfacet(mat);
        let first = orders.0 <= 1;
        let (model, max_bounces) = self.resolve(mat, wi);
        let mut opts = Self::walk_options(model, max_bounces);
        opts.orders = (orders.0.max(1), orders.1.min(max_bounces));
        let rng = || self.seeded(&[key, wi.x.to_bits(), wi.y.to_bits(), wi.z.to_bits(), wo.x.to_bits(), wo.y.to_bits(), wo.z.to_bits()]);
        match self.cfg.surface {
            Surface::Conductor => {
                let fresnel = self.fresnel(mat);
                let v = match model {
                    Model::Single if first => single::eval(&mf, &fresnel, wi, wo),
                    Model::FastMsx if first => fastmsx::eval(&mf, &fresnel, wi, wo),
                    Model::Compensated if first => compensated::eval(&mf, &fresnel, wi, wo),
                    Model::Single | Model::FastMsx | Model::Compensated => Spectrum::ZERO,
                    Model::Uncorrelated | Model::Correlated | Model::Auto => match self.cfg.estimator {
                        Estimator::Pt => posfree::conductor::eval_pt(&mf, &fresnel, wi, wo, &opts, &mut rng()),
                        Estimator::Bdpt => posfree_bdpt::eval_bdpt(&mf, &fresnel, wi, wo, &opts, &mut rng()),
                    },
                    Model::Heitz => heitz::eval(&mf, &Microsurface::Conductor(fresnel), wi, wo, &opts, &mut rng()),
                    Model::Invariance => invariance::eval(&mf, &fresnel, wi, wo, &opts, &mut rng()),
                };
                v * mat.specular_reflectance
            }
            Surface::Dielectric => {
                let Some(eta) = valid_ior(mat.ior) else { return Spectrum::ZERO };
                let v = match model {
                    Model::Single if first => single_dielectric::eval(&mf, eta, wi, wo, mat.radiance).0,
                    Model::Compensated if first => compensated_dielectric::eval(&mf, eta, wi, wo, mat.radiance),
                    Model::Uncorrelated | Model::Correlated => match self.cfg.estimator {
                        Estimator::Pt => posfree_dielectric::eval_pt(&mf, eta, mat.radiance, wi, wo, &opts, &mut rng()).0,
                        Estimator::Bdpt => posfree_bdpt_dielectric::eval_bdpt(&mf, eta, mat.radiance, wi, wo, &opts, &mut rng()),
                    },
                    Model::Heitz => {
                        let surf = Microsurface::Dielectric { eta, radiance: mat.radiance };
                        heitz::eval(&mf, &surf, wi, wo, &opts, &mut rng()).0[0]
                    }
                    Model::Invariance => invariance_dielectric::eval(&mf, eta, mat.radiance, wi, wo, &opts, &mut rng()),
                    _ => 0.0,
                };
                self.dielectric_tint(mat, wi, wo) * v
            }
            Surface::Diffuse => match model {
                Model::Uncorrelated | Model::Correlated => match self.cfg.estimator {
                    Estimator::Pt => posfree_diffuse::eval_pt(&mf, mat.reflectance, wi, wo, &opts, &mut rng()),
                    Estimator::Bdpt => posfree_bdpt_diffuse::eval_bdpt(&mf, mat.reflectance, wi, wo, &opts, &mut rng()),
                },
                Model::Heitz => heitz::eval(&mf, &Microsurface::Diffuse { albedo: mat.reflectance }, wi, wo, &opts, &mut rng()),
                Model::Invariance => {
                    invariance_general::eval(&mf, &Microsurface::Diffuse { albedo: mat.reflectance }, wi, wo, &opts, &mut rng())
                }
                _ => Spectrum::ZERO,
            },
        }
    }

    /// Mitsuba's tints: specular_reflectance on reflection, specular_transmittance on transmission.
    fn dielectric_tint(&self, mat: &Material, wi: DVec3, wo: DVec3) -> Spectrum {
        if wi.z * wo.z > 0.0 {
            mat.specular_reflectance
        } else {
            mat.specular_transmittance
        }
    }

    /// Density reported for MIS. Exact for `single`, `fastmsx` and
    /// `compensated` (they sample with `single`'s sampler); for the conductor
    /// random walks the exact order-1 density plus a cosine lobe with the
    /// remaining mass (see `conductor_walk_pdf`); for dielectrics a mixture of
    /// the single-scattering density and a cosine lobe on both sides weighted by
    /// [`diffuse_fraction`] (Heitz 2016); a cosine lobe for the diffuse microsurface.
    pub fn pdf(&self, mat: &Material, wi: DVec3, wo: DVec3) -> f64 {
        let (Some(wi), Some(wo)) = (finite_unit(wi), finite_unit(wo)) else { return 0.0 };
        let Some(mat) = mat.usable(self.cfg.surface, self.cfg.channels) else { return 0.0 };
        self.pdf_checked(&mat, wi, wo)
    }

    /// `pdf` on inputs already checked (unit directions, usable material).
    fn pdf_checked(&self, mat: &Material, wi: DVec3, wo: DVec3) -> f64 {
        let mf = self.microfacet(mat);
        let (model, _) = self.resolve(mat, wi);
        match self.cfg.surface {
            Surface::Conductor => match model {
                Model::Single | Model::FastMsx | Model::Compensated => single::pdf(&mf, wi, wo),
                _ => {
                    if wo.z <= 0.0 || wi.z == 0.0 {
                        0.0
                    } else if wi.z < 0.0 {
                        // The position-free walks also start below the macro surface (normal mapping):
                        // a cosine lobe for MIS there. Heitz and invariance do not (their walks start above).
                        if matches!(model, Model::Uncorrelated | Model::Correlated) {
                            wo.z * FRAC_1_PI
                        } else {
                            0.0
                        }
                    } else {
                        self.conductor_walk_pdf(model, &mf, wi, wo)
                    }
                }
            },
            Surface::Dielectric => {
                let Some(eta) = valid_ior(mat.ior) else { return 0.0 };
                let ss = single_dielectric::pdf(&mf, eta, wi, wo);
                match model {
                    Model::Single | Model::Compensated => ss,
                    _ => {
                        let k = diffuse_fraction(&mf);
                        (1.0 - k) * ss + k * wo.z.abs() * 0.5 * FRAC_1_PI
                    }
                }
            }
            Surface::Diffuse => {
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
    /// uncorrelated, L_0/(L_0 + Λ_o) height-correlated, which order 1 of heitz
    /// and invariance share) plus a cosine lobe carrying the remaining mass
    /// 1 − E_1(ω_i) from the order-1 albedo table, floored at 1e-3 so that no
    /// direction the walk can reach has density 0. Integrates to 1 up to the
    /// table's interpolation error.
    fn conductor_walk_pdf(&self, model: Model, mf: &Microfacet, wi: DVec3, wo: DVec3) -> f64 {
        let table = AlbedoTable::get(mf.dist);
        let alpha = (mf.alpha_u * mf.alpha_v).sqrt();
        let lambda_o = mf.lambda(wo);
        let (exit, e1) = if model == Model::Uncorrelated {
            (1.0 / (1.0 + lambda_o), table.e1_uncorrelated(alpha, wi.z))
        } else {
            let l0 = 1.0 + mf.lambda(wi);
            (l0 / (l0 + lambda_o), table.e1_correlated(alpha, wi.z))
        };
        mf.reflect_pdf(wi, wo) * exit + (1.0 - e1).max(1e-3) * wo.z * FRAC_1_PI
    }

    /// `eval` and `pdf` together, with the inputs checked once. The conductor's
    /// `single` shares the half vector, D and G1(ω_i) between the two.
    pub fn eval_pdf(&self, mat: &Material, wi: DVec3, wo: DVec3, key: u64) -> (Spectrum, f64) {
        let (Some(wi), Some(wo)) = (finite_unit(wi), finite_unit(wo)) else { return (Spectrum::ZERO, 0.0) };
        let Some(mat) = mat.usable(self.cfg.surface, self.cfg.channels) else { return (Spectrum::ZERO, 0.0) };
        if self.cfg.surface == Surface::Conductor && self.cfg.model == Model::Single {
            let (f, p) = single::eval_pdf(&self.microfacet(&mat), &self.fresnel(&mat), wi, wo);
            return (f * mat.specular_reflectance, p);
        }
        (self.eval_checked(&mat, wi, wo, key, (1, u32::MAX)), self.pdf_checked(&mat, wi, wo))
    }

    /// Samples ω_o given Mitsuba's `sample1` and `sample2`; the random walks
    /// draw their further numbers from a stream seeded by them and `seed`.
    pub fn sample(&self, mat: &Material, wi: DVec3, sample1: f64, sample2: (f64, f64)) -> Option<BsdfSample> {
        self.sample_with_order(mat, wi, sample1, sample2).map(|(s, _)| s)
    }

    /// `sample` together with the scattering order of the sampled path (the
    /// number of microfacet events; 1 for the analytic models, whose whole
    /// lobe counts as order 1 as in `eval_orders`). Weights binned by order
    /// estimate each order's lobe and energy (src/microgeometry/ compares them
    /// with ray tracing).
    pub fn sample_with_order(&self, mat: &Material, wi: DVec3, sample1: f64, sample2: (f64, f64)) -> Option<(BsdfSample, u32)> {
        let wi = finite_unit(wi)?;
        let mat = &mat.usable(self.cfg.surface, self.cfg.channels)?;
        let clamp01 = |u: f64| if u.is_finite() { u.clamp(0.0, 1.0 - f64::EPSILON / 2.0) } else { 0.5 };
        let (s1, u1, u2) = (clamp01(sample1), clamp01(sample2.0), clamp01(sample2.1));
        let mf = self.microfacet(mat);
        let (model, max_bounces) = self.resolve(mat, wi);
        let opts = Self::walk_options(model, max_bounces);
        let rng = || self.seeded(&[s1.to_bits(), u1.to_bits(), u2.to_bits(), wi.x.to_bits(), wi.z.to_bits()]);
        let first = (s1, u1, u2);
        let (wo, pdf, weight, order) = match self.cfg.surface {
            Surface::Conductor => {
                let fresnel = self.fresnel(mat);
                let with1 = |(wo, pdf, w)| (wo, pdf, w, 1);
                let (wo, pdf, w, order) = match model {
                    Model::Single => with1(single::sample(&mf, &fresnel, wi, u1, u2)?),
                    Model::FastMsx => with1(fastmsx::sample(&mf, &fresnel, wi, u1, u2)?),
                    Model::Compensated => with1(compensated::sample(&mf, &fresnel, wi, u1, u2)?),
                    Model::Uncorrelated | Model::Correlated | Model::Auto | Model::Heitz | Model::Invariance => {
                        let (wo, w, order) = match model {
                            Model::Heitz => heitz::sample(&mf, &Microsurface::Conductor(fresnel), wi, first, &opts, &mut rng())?,
                            Model::Invariance => invariance::sample(&mf, &fresnel, wi, first, &opts, &mut rng())?,
                            _ => posfree::conductor::sample_walk(&mf, &fresnel, wi, first, &opts, &mut rng())?,
                        };
                        (wo, self.pdf(mat, wi, wo), w, order)
                    }
                };
                (wo, pdf, w * mat.specular_reflectance, order)
            }
            Surface::Dielectric => {
                let eta = valid_ior(mat.ior)?;
                let (wo, pdf, w, order) = match model {
                    Model::Single => {
                        let (wo, pdf, w, _) = single_dielectric::sample(&mf, eta, wi, s1, u1, u2, mat.radiance)?;
                        (wo, pdf, w, 1)
                    }
                    Model::Compensated => {
                        let (wo, pdf, w) = compensated_dielectric::sample(&mf, eta, wi, s1, u1, u2, mat.radiance)?;
                        (wo, pdf, w, 1)
                    }
                    Model::Heitz => {
                        let surf = Microsurface::Dielectric { eta, radiance: mat.radiance };
                        let (wo, w, order) = heitz::sample(&mf, &surf, wi, first, &opts, &mut rng())?;
                        (wo, self.pdf(mat, wi, wo), w.0[0], order)
                    }
                    Model::Invariance => {
                        let (wo, w, order) = invariance_dielectric::sample(&mf, eta, mat.radiance, wi, first, &opts, &mut rng())?;
                        (wo, self.pdf(mat, wi, wo), w, order)
                    }
                    _ => {
                        let (wo, w, order) = posfree_dielectric::sample_walk(&mf, eta, mat.radiance, wi, first, &opts, &mut rng())?;
                        (wo, self.pdf(mat, wi, wo), w, order)
                    }
                };
                (wo, pdf, self.dielectric_tint(mat, wi, wo) * w, order)
            }
            Surface::Diffuse => {
                let (wo, w, order) = match model {
                    Model::Heitz => heitz::sample(&mf, &Microsurface::Diffuse { albedo: mat.reflectance }, wi, first, &opts, &mut rng())?,
                    Model::Invariance => {
                        invariance_general::sample(&mf, &Microsurface::Diffuse { albedo: mat.reflectance }, wi, first, &opts, &mut rng())?
                    }
                    _ => posfree_diffuse::sample_walk(&mf, mat.reflectance, wi, first, &opts, &mut rng())?,
                };
                (wo, self.pdf(mat, wi, wo), w, order)
            }
        };
        // Raw values: the C ABI rejects a sample whose pdf is not > 0 and
        // counts any non-finite or negative value (docs/conventions.md).
        Some((BsdfSample { wo, pdf, weight }, order))
    }
}

/// A dielectric's relative IOR if usable (finite, > 0).
fn valid_ior(eta: f64) -> Option<f64> {
    (eta.is_finite() && eta > 0.0).then_some(eta)
}

/// Weight of the cosine lobe in the MIS density of the multiple-scattering
/// models: grows with roughness like the multiply scattered energy does
/// (≈ 5 % at α = 0.1, 33 % at α = 1).
pub fn diffuse_fraction(mf: &Microfacet) -> f64 {
    let a = (mf.alpha_u * mf.alpha_v).sqrt();
    (a / (a + 2.0)).min(0.75)
}
