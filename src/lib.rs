//! msx: multiple-scattering microfacet BSDFs (Wang et al. 2022 position-free
//! segment terms, Walter 2007 single scattering as Mitsuba 3 computes it) for
//! Mitsuba 3, behind a C ABI (`ffi`, header `include/msx.h`).

// The C ABI is `ffi` alone: cbindgen (include/msx.h) skips the modules marked
// `cbindgen:ignore`, so their public constants and types stay out of the header.

/// cbindgen:ignore
pub mod bsdf;
/// cbindgen:ignore
pub mod config;
pub mod ffi;
/// cbindgen:ignore
pub mod microfacet;
/// cbindgen:ignore
pub mod microgeometry;
/// cbindgen:ignore
pub mod models;
/// cbindgen:ignore
pub mod rng;
/// cbindgen:ignore
pub mod spectrum;
/// cbindgen:ignore
pub mod tables;
/// cbindgen:ignore
pub mod walk;

pub use bsdf::{Bsdf, BsdfSample, Material};
pub use config::{Config, Distribution, Estimator, Model, ParamError, Surface};
pub use microfacet::Microfacet;
pub use spectrum::Spectrum;
