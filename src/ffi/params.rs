//! The codes and structs a C caller configures a BSDF and describes a hit
//! with, and their conversion to the core's `Config` and `Material`.

use super::write_error;
use crate::bsdf::Material;
use crate::config::{Choice, Config, Distribution, Estimator, MisDensity, Model, Surface, DEFAULT_MAX_BOUNCES, DEFAULT_MIS_DENSITY, MODELS};
use crate::spectrum::{Spectrum, MAX_CHANNELS};
use glam::DVec3;
use std::os::raw::c_char;

pub const MSX_SURFACE_CONDUCTOR: u32 = 0;
pub const MSX_SURFACE_DIELECTRIC: u32 = 1;
pub const MSX_SURFACE_DIFFUSE: u32 = 2;

pub const MSX_DISTRIBUTION_BECKMANN: u32 = 0;
pub const MSX_DISTRIBUTION_GGX: u32 = 1;

/// The models' codes as constants, kept for C callers that use them; every
/// model's code (these and any newer) is in the table of names, read with
/// `msx_choice` (src/ffi/choices.rs).
pub const MSX_MODEL_SINGLE: u32 = 0;
pub const MSX_MODEL_UNCORRELATED: u32 = 1;
pub const MSX_MODEL_CORRELATED: u32 = 2;
pub const MSX_MODEL_HEITZ: u32 = 3;
pub const MSX_MODEL_INVARIANCE: u32 = 4;
pub const MSX_MODEL_FASTMSX: u32 = 5;
pub const MSX_MODEL_COMPENSATED: u32 = 6;
pub const MSX_MODEL_AUTO: u32 = 7;

pub const MSX_ESTIMATOR_PT: u32 = 0;
pub const MSX_ESTIMATOR_BDPT: u32 = 1;

/// `MsxParams::mis_density`: 0 = the library's default (single_cosine).
pub const MSX_MIS_DENSITY_DEFAULT: u32 = 0;
pub const MSX_MIS_DENSITY_SINGLE_COSINE: u32 = 1;
pub const MSX_MIS_DENSITY_CUI: u32 = 2;
pub const MSX_MIS_DENSITY_CUI_TYPO: u32 = 3;

/// `MsxParams::sample_all_normals`: 0 = visible normals (Mitsuba's
/// `sample_visible=true`, the default), 1 = normals from D·cos θ_m
/// (`sample_visible=false`).
pub const MSX_SAMPLE_VISIBLE_NORMALS: u32 = 0;
pub const MSX_SAMPLE_ALL_NORMALS: u32 = 1;

pub const MSX_MODE_RADIANCE: u32 = 0;
pub const MSX_MODE_IMPORTANCE: u32 = 1;

/// Bounce cap used when `MsxParams::max_bounces` is 0.
pub const MSX_DEFAULT_MAX_BOUNCES: u32 = 64;
/// `MsxParams::auto_tolerance` used when it is 0.
pub const MSX_DEFAULT_AUTO_TOLERANCE: f64 = 0.01;
/// Relative IOR of `MsxMaterial::ior` when a caller sets none: Mitsuba's BK7
/// glass, the default `int_ior` of `roughdielectric`.
pub const MSX_DEFAULT_IOR: f64 = 1.5046;
/// Largest accepted `MsxParams::max_bounces`.
pub const MSX_MAX_BOUNCES_LIMIT: u32 = 1024;
/// Channels per call at most.
pub const MSX_MAX_CHANNELS: u32 = 4;
/// Roughness is clamped into [MSX_ALPHA_MIN, MSX_ALPHA_MAX] per call.
pub const MSX_ALPHA_MIN: f64 = 1e-4;
pub const MSX_ALPHA_MAX: f64 = 1e4;

// The header's literals must agree with the core.
const _: () = assert!(MSX_DEFAULT_MAX_BOUNCES == crate::config::DEFAULT_MAX_BOUNCES);
const _: () = assert!(MSX_MAX_BOUNCES_LIMIT == crate::config::MAX_BOUNCES_LIMIT);
const _: () = assert!(MSX_MAX_CHANNELS as usize == MAX_CHANNELS);
const _: () = assert!(MSX_DEFAULT_AUTO_TOLERANCE == crate::config::DEFAULT_TOLERANCE);
const _: () = assert!(MSX_DEFAULT_IOR == crate::microfacet::dielectric::BK7_IOR);
const _: () = assert!(MSX_ALPHA_MIN == crate::microfacet::ALPHA_MIN && MSX_ALPHA_MAX == crate::microfacet::ALPHA_MAX);

/// Static configuration of a BSDF.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxParams {
    /// MSX_SURFACE_*
    pub surface: u32,
    /// MSX_DISTRIBUTION_*
    pub distribution: u32,
    /// MSX_MODEL_*
    pub model: u32,
    /// MSX_ESTIMATOR_*
    pub estimator: u32,
    /// Bounce cap (0 = default chosen by the library)
    pub max_bounces: u32,
    /// Spectral channels per call, 1..=4 (RGB: 3, Mitsuba spectral: 4)
    pub channels: u32,
    /// Decorrelates / reproduces the stochastic estimates
    pub seed: u64,
    /// MSX_MODEL_AUTO only: fraction of the scattered energy that evaluating
    /// single scattering alone may omit, in (0, 1) (0 = MSX_DEFAULT_AUTO_TOLERANCE)
    pub auto_tolerance: f64,
    /// MSX_MIS_DENSITY_*: the density the conductor walks (uncorrelated,
    /// correlated, heitz, invariance, auto) report for MIS; any other
    /// surface or model accepts MSX_MIS_DENSITY_DEFAULT (0) only
    pub mis_density: u32,
    /// MSX_SAMPLE_VISIBLE_NORMALS (0, the default: Mitsuba's sample_visible=true)
    /// or MSX_SAMPLE_ALL_NORMALS (1: sample_visible=false, microfacet normals
    /// drawn from D·cos θ_m — on a dielectric with roughdielectric's widened α)
    /// in single, fastmsx and compensated, whose pdf and weight follow the
    /// sampler; the random walks draw visible normals either way
    pub sample_all_normals: u32,
}

/// Per-hit material values (textures evaluated at the hit).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxMaterial {
    pub alpha_u: f32,
    pub alpha_v: f32,
    /// Conductor complex IOR, real part, per channel
    pub eta: [f32; 4],
    /// Conductor complex IOR, imaginary part, per channel
    pub k: [f32; 4],
    pub specular_reflectance: [f32; 4],
    /// Dielectric relative IOR η_int/η_ext
    pub ior: f32,
    /// Dielectric transmission tint, per channel
    pub specular_transmittance: [f32; 4],
    /// Diffuse microsurface albedo, per channel
    pub reflectance: [f32; 4],
    /// MSX_MODE_RADIANCE or MSX_MODE_IMPORTANCE (Mitsuba's TransportMode)
    pub mode: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxVec3 {
    pub x: f32,
    pub y: f32,
    pub z: f32,
}

/// Per-channel values; channels beyond `MsxParams::channels` are zero.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxSpectrum {
    pub v: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxEvalPdf {
    pub value: MsxSpectrum,
    pub pdf: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxSample {
    pub wo: MsxVec3,
    pub pdf: f32,
    /// f·|cos θ_o| / pdf (unbiased random-walk estimate for multiple scattering)
    pub weight: MsxSpectrum,
    /// 1 if the sample is valid, 0 otherwise (then everything else is zero)
    pub valid: u32,
}

impl Default for MsxMaterial {
    /// α = 0.1, perfect mirror, bk7/air dielectric, unit tints, reflectance 0.5, Radiance mode.
    fn default() -> Self {
        MsxMaterial {
            alpha_u: 0.1,
            alpha_v: 0.1,
            eta: [0.0; 4],
            k: [1.0; 4],
            specular_reflectance: [1.0; 4],
            ior: MSX_DEFAULT_IOR as f32,
            specular_transmittance: [1.0; 4],
            reflectance: [0.5; 4],
            mode: MSX_MODE_RADIANCE,
        }
    }
}

/// The distribution of an MSX_DISTRIBUTION_* code.
pub(super) fn distribution_from(code: u32) -> Option<Distribution> {
    Distribution::from_code(code)
}

/// The choice of a code, or the error naming the parameter and every allowed
/// value of the table (src/config.rs).
pub(super) fn choice<T: Choice>(code: u32) -> Result<T, (&'static str, String)> {
    T::from_code(code).ok_or_else(|| (T::PARAMETER, format!("unknown value {code}; allowed: {}", T::allowed())))
}

/// The choice of an entry point's argument `code`; None, with the message in
/// `err`, for an unknown code.
pub(super) fn choice_arg<T: Choice>(code: u32, err: *mut c_char, err_len: usize) -> Option<T> {
    match choice::<T>(code) {
        Ok(v) => Some(v),
        Err((parameter, message)) => {
            write_error(err, err_len, &format!("invalid parameter '{parameter}': {message}"));
            None
        }
    }
}

pub(super) fn config_from(p: &MsxParams) -> Result<Config, (&'static str, String)> {
    let surface = choice::<Surface>(p.surface)?;
    let distribution = choice::<Distribution>(p.distribution)?;
    let model = choice::<Model>(p.model)?;
    let estimator = choice::<Estimator>(p.estimator)?;
    let max_bounces = if p.max_bounces == 0 { DEFAULT_MAX_BOUNCES } else { p.max_bounces };
    if p.auto_tolerance != 0.0 && model != Model::Auto {
        return Err(("auto_tolerance", format!("applies to model 'auto' only (model is '{}')", model.name())));
    }
    let tolerance = if p.auto_tolerance == 0.0 { MSX_DEFAULT_AUTO_TOLERANCE } else { p.auto_tolerance };
    let mis_density = if p.mis_density == MSX_MIS_DENSITY_DEFAULT {
        DEFAULT_MIS_DENSITY
    } else {
        choice::<MisDensity>(p.mis_density).map_err(|(name, message)| (name, format!("{message}, or default ({MSX_MIS_DENSITY_DEFAULT})")))?
    };
    if p.mis_density != MSX_MIS_DENSITY_DEFAULT && !mis_density_applies(surface, model) {
        return Err((
            "mis_density",
            format!(
                "applies to the conductor walks only ({} on a conductor; here {} {})",
                MODELS.iter().filter(|m| mis_density_applies(Surface::Conductor, m.model)).map(|m| m.name).collect::<Vec<_>>().join(", "),
                surface.name(),
                model.name()
            ),
        ));
    }
    let sample_visible = match p.sample_all_normals {
        MSX_SAMPLE_VISIBLE_NORMALS => true,
        MSX_SAMPLE_ALL_NORMALS => false,
        other => {
            return Err((
                "sample_visible",
                format!(
                    "MsxParams::sample_all_normals must be {MSX_SAMPLE_VISIBLE_NORMALS} (visible normals, sample_visible=true) or \
                     {MSX_SAMPLE_ALL_NORMALS} (all normals, sample_visible=false), got {other}"
                ),
            ))
        }
    };
    Ok(Config {
        surface,
        distribution,
        model,
        estimator,
        max_bounces,
        channels: p.channels as usize,
        seed: p.seed,
        tolerance,
        mis_density,
        sample_visible,
    })
}

/// Whether `MsxParams::mis_density` changes anything: the conductor walks.
pub(super) fn mis_density_applies(surface: Surface, model: Model) -> bool {
    // The conductor's random walks (the table's `random_walk` models that run on a conductor).
    surface == Surface::Conductor && model.info().random_walk && model.info().surfaces.contains(&Surface::Conductor)
}

pub(super) fn vec3(v: MsxVec3) -> DVec3 {
    DVec3::new(v.x as f64, v.y as f64, v.z as f64)
}

#[inline]
pub(super) fn spectrum4(v: [f32; 4]) -> Spectrum {
    Spectrum([v[0] as f64, v[1] as f64, v[2] as f64, v[3] as f64])
}

pub(super) fn material(m: &MsxMaterial) -> Material {
    Material {
        alpha_u: m.alpha_u as f64,
        alpha_v: m.alpha_v as f64,
        eta: spectrum4(m.eta),
        k: spectrum4(m.k),
        specular_reflectance: spectrum4(m.specular_reflectance),
        ior: m.ior as f64,
        specular_transmittance: spectrum4(m.specular_transmittance),
        reflectance: spectrum4(m.reflectance),
        radiance: m.mode != MSX_MODE_IMPORTANCE,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The header's MSX_* codes (kept for compatibility) are the table's codes.
    #[test]
    fn header_codes_are_the_tables() {
        let pairs = [
            (MSX_MODEL_SINGLE, Model::Single),
            (MSX_MODEL_UNCORRELATED, Model::Uncorrelated),
            (MSX_MODEL_CORRELATED, Model::Correlated),
            (MSX_MODEL_HEITZ, Model::Heitz),
            (MSX_MODEL_INVARIANCE, Model::Invariance),
            (MSX_MODEL_FASTMSX, Model::FastMsx),
            (MSX_MODEL_COMPENSATED, Model::Compensated),
            (MSX_MODEL_AUTO, Model::Auto),
        ];
        for (code, model) in pairs {
            assert_eq!(model.code(), code, "{model:?}");
        }
        for (code, s) in
            [(MSX_SURFACE_CONDUCTOR, Surface::Conductor), (MSX_SURFACE_DIELECTRIC, Surface::Dielectric), (MSX_SURFACE_DIFFUSE, Surface::Diffuse)]
        {
            assert_eq!(s.code(), code);
        }
        assert_eq!((Distribution::Beckmann.code(), Distribution::Ggx.code()), (MSX_DISTRIBUTION_BECKMANN, MSX_DISTRIBUTION_GGX));
        assert_eq!((Estimator::Pt.code(), Estimator::Bdpt.code()), (MSX_ESTIMATOR_PT, MSX_ESTIMATOR_BDPT));
        assert_eq!(
            (MisDensity::SingleCosine.code(), MisDensity::Cui.code(), MisDensity::CuiTypo.code()),
            (MSX_MIS_DENSITY_SINGLE_COSINE, MSX_MIS_DENSITY_CUI, MSX_MIS_DENSITY_CUI_TYPO)
        );
        assert_eq!(MisDensity::from_code(MSX_MIS_DENSITY_DEFAULT), None, "0 asks for the default");
    }

    #[test]
    fn unknown_codes_list_the_table() {
        let p = MsxParams {
            surface: 0,
            distribution: 0,
            model: 99,
            estimator: 0,
            max_bounces: 0,
            channels: 3,
            seed: 0,
            auto_tolerance: 0.0,
            mis_density: 0,
            sample_all_normals: 0,
        };
        let (parameter, message) = config_from(&p).unwrap_err();
        assert_eq!(parameter, "model");
        assert_eq!(message, format!("unknown value 99; allowed: {}", Model::allowed()));
    }
}
