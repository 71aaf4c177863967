//! Static configuration (surface, distribution, model, estimator) → dispatch.
//! Per-hit values (roughness, IOR, reflectance) arrive with every call as a
//! [`Material`], since Mitsuba evaluates textures at the hit.

use crate::config::{Config, Distribution, Estimator, Model, ModelInfo, ParamError, Surface, ALL_SURFACES, MAX_BOUNCES_LIMIT, MODELS};
use crate::microfacet::mitsuba::Sampling;
use crate::microfacet::Microfacet;
use crate::microfacet::{ConductorFresnel, Microsurface};
use crate::models::analytic::{Compensated, FastMsx};
use crate::models::auto::Auto;
use crate::models::heitz::Heitz;
use crate::models::invariance::Invariance;
use crate::models::posfree::{PosFree, Segments};
use crate::models::single::Single;
use crate::models::{Call, ScatteringModel, Stream};
use crate::rng::unit_interval;
use crate::spectrum::{ChannelMask, Spectrum, MAX_CHANNELS};
use glam::DVec3;
use std::sync::{Arc, OnceLock};

/// The code of a model: the one place that maps the configuration to an
/// implementation of [`ScatteringModel`].
fn implementation(model: Model, estimator: Estimator, surface: Surface, dist: Distribution, tolerance: f64) -> Arc<dyn ScatteringModel> {
    match model {
        Model::Single => Arc::new(Single),
        Model::Uncorrelated => Arc::new(PosFree { segments: Segments::Uncorrelated, estimator }),
        Model::Correlated => Arc::new(PosFree { segments: Segments::Correlated, estimator }),
        Model::Heitz => Arc::new(Heitz),
        Model::Invariance => Arc::new(Invariance { estimator }),
        Model::FastMsx => Arc::new(FastMsx),
        Model::Compensated => Arc::new(Compensated),
        Model::Auto => Arc::new(Auto::new(surface, dist, tolerance, estimator)),
    }
}

/// Per surface: its models, and those of them that accept `estimator="bdpt"`,
/// as the table of models declares them (`MODELS` in config.rs).
fn support() -> &'static [(Vec<Model>, Vec<Model>); 3] {
    static SUPPORT: OnceLock<[(Vec<Model>, Vec<Model>); 3]> = OnceLock::new();
    SUPPORT.get_or_init(|| {
        ALL_SURFACES.map(|surface| {
            let on = |list: fn(&ModelInfo) -> &[Surface]| MODELS.iter().filter(|m| list(m).contains(&surface)).map(|m| m.model).collect();
            (on(|m| m.surfaces), on(|m| m.bdpt))
        })
    })
}

/// Models implemented for a surface, in the order of the docs.
pub fn models_for(surface: Surface) -> &'static [Model] {
    &support()[surface as usize].0
}

/// Models that accept `estimator="bdpt"` on a surface.
pub fn bdpt_models(surface: Surface) -> &'static [Model] {
    &support()[surface as usize].1
}

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
            ior: crate::microfacet::dielectric::BK7_IOR,
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
    #[inline]
    fn usable(&self, surface: Surface, channels: usize) -> Option<Material> {
        // Channels beyond `channels` are zeroed: what the caller left there must not steer a walk
        // (Russian roulette looks at the largest channel).
        let keep = ChannelMask::first(channels);
        let finite = |s: Spectrum| s.masked(keep).is_finite();
        let clamp = |s: Spectrum, hi: f64| s.map(|v| v.clamp(0.0, hi)).masked(keep);
        if !(self.alpha_u.is_finite() && self.alpha_v.is_finite()) {
            return None;
        }
        match surface {
            Surface::Conductor => {
                if !(finite(self.eta) && finite(self.k) && finite(self.specular_reflectance)) {
                    return None;
                }
                Some(Material {
                    eta: clamp(self.eta, MATERIAL_VALUE_MAX),
                    k: clamp(self.k, MATERIAL_VALUE_MAX),
                    specular_reflectance: clamp(self.specular_reflectance, MATERIAL_VALUE_MAX),
                    ..*self
                })
            }
            Surface::Dielectric => {
                if !(self.ior.is_finite() && self.ior > 0.0 && finite(self.specular_reflectance) && finite(self.specular_transmittance)) {
                    return None;
                }
                // An index-matched interface does not scatter: its transmission
                // is a delta, which a rough BSDF cannot represent.
                if (self.ior - 1.0).abs() <= INDEX_MATCHED {
                    return None;
                }
                Some(Material {
                    ior: self.ior.clamp(1.0 / MATERIAL_VALUE_MAX, MATERIAL_VALUE_MAX),
                    specular_reflectance: clamp(self.specular_reflectance, MATERIAL_VALUE_MAX),
                    specular_transmittance: clamp(self.specular_transmittance, MATERIAL_VALUE_MAX),
                    ..*self
                })
            }
            Surface::Diffuse => {
                if !finite(self.reflectance) {
                    return None;
                }
                Some(Material { reflectance: clamp(self.reflectance, 1.0), ..*self })
            }
        }
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
    model: Arc<dyn ScatteringModel>,
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
        let distributions = cfg.model.info().distributions;
        if !distributions.contains(&cfg.distribution) {
            let names = distributions.iter().map(|d| format!("'{}'", d.name())).collect::<Vec<_>>().join(", ");
            return Err(ParamError {
                parameter: "distribution",
                message: format!("model '{}' is defined for distribution {} only", cfg.model.name(), names),
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
            return Err(ParamError { parameter: "max_bounces", message: format!("must be 1..={MAX_BOUNCES_LIMIT}, got {}", cfg.max_bounces) });
        }
        let model = implementation(cfg.model, cfg.estimator, cfg.surface, cfg.distribution, cfg.tolerance);
        Ok(Bsdf { cfg, model })
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// What the model sees of one call: the material as microfacet statistics
    /// and a microsurface, the orders (clamped to the bounce cap) and the
    /// words its random stream derives from.
    fn call(&self, mat: &Material, orders: (u32, u32), words: &[u64]) -> Call {
        let surf = match self.cfg.surface {
            Surface::Conductor => Microsurface::Conductor(ConductorFresnel::new(mat.eta, mat.k, self.cfg.channels)),
            Surface::Dielectric => Microsurface::Dielectric { eta: mat.ior, radiance: mat.radiance },
            Surface::Diffuse => Microsurface::Diffuse { albedo: mat.reflectance },
        };
        Call {
            mf: Microfacet::new(self.cfg.distribution, mat.alpha_u, mat.alpha_v),
            surf,
            max_bounces: self.cfg.max_bounces,
            orders: (orders.0.max(1), orders.1.min(self.cfg.max_bounces)),
            stream: Stream::new(self.cfg.seed, words),
            mis: self.cfg.mis_density,
            sampling: if self.cfg.sample_visible { Sampling::Visible } else { Sampling::AllNormals },
        }
    }

    /// Mitsuba's tints of a value of (ω_i, ω_o): specular_reflectance on a
    /// conductor and on a dielectric's reflection, specular_transmittance on
    /// a transmission.
    fn tinted(&self, mat: &Material, wi: DVec3, wo: DVec3, v: Spectrum) -> Spectrum {
        match self.cfg.surface {
            Surface::Conductor => v * mat.specular_reflectance,
            Surface::Dielectric if wi.z * wo.z > 0.0 => mat.specular_reflectance * v,
            Surface::Dielectric => mat.specular_transmittance * v,
            Surface::Diffuse => v,
        }
    }

    /// The words of an evaluation's random stream: the key and both directions.
    fn eval_words(key: u64, wi: DVec3, wo: DVec3) -> [u64; 7] {
        [key, wi.x.to_bits(), wi.y.to_bits(), wi.z.to_bits(), wo.x.to_bits(), wo.y.to_bits(), wo.z.to_bits()]
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
        if orders.0 > orders.1 {
            return Spectrum::ZERO;
        }
        let call = self.call(&mat, orders, &Self::eval_words(key, wi, wo));
        self.tinted(&mat, wi, wo, self.model.eval(&call, wi, wo))
    }

    /// Density reported for MIS (docs/conventions.md): exact for `single`,
    /// `fastmsx` and `compensated` (they sample with `single`'s sampler), the
    /// densities of models/mis.rs for the random walks.
    pub fn pdf(&self, mat: &Material, wi: DVec3, wo: DVec3) -> f64 {
        let (Some(wi), Some(wo)) = (finite_unit(wi), finite_unit(wo)) else { return 0.0 };
        let Some(mat) = mat.usable(self.cfg.surface, self.cfg.channels) else { return 0.0 };
        self.model.pdf(&self.call(&mat, (1, u32::MAX), &[]), wi, wo)
    }

    /// `eval` and `pdf` together, with the inputs checked once.
    pub fn eval_pdf(&self, mat: &Material, wi: DVec3, wo: DVec3, key: u64) -> (Spectrum, f64) {
        let (Some(wi), Some(wo)) = (finite_unit(wi), finite_unit(wo)) else { return (Spectrum::ZERO, 0.0) };
        let Some(mat) = mat.usable(self.cfg.surface, self.cfg.channels) else { return (Spectrum::ZERO, 0.0) };
        let call = self.call(&mat, (1, u32::MAX), &Self::eval_words(key, wi, wo));
        let (v, pdf) = self.model.eval_pdf(&call, wi, wo);
        (self.tinted(&mat, wi, wo, v), pdf)
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
        let clamp01 = |u: f64| unit_interval(u).unwrap_or(0.5);
        let (s1, u1, u2) = (clamp01(sample1), clamp01(sample2.0), clamp01(sample2.1));
        let words = [s1.to_bits(), u1.to_bits(), u2.to_bits(), wi.x.to_bits(), wi.z.to_bits()];
        let call = self.call(mat, (1, u32::MAX), &words);
        let s = self.model.sample(&call, wi, (s1, u1, u2))?;
        let pdf = match s.pdf {
            Some(p) => p,
            // As `pdf` would compute it, without checking the material and ω_i again.
            None => finite_unit(s.wo).map_or(0.0, |wo| self.model.pdf(&call, wi, wo)),
        };
        // Raw values: the C ABI rejects a sample whose pdf is not > 0 and
        // counts any non-finite or negative value (docs/conventions.md).
        Some((BsdfSample { wo: s.wo, pdf, weight: self.tinted(mat, wi, s.wo, s.weight) }, s.order))
    }
}
