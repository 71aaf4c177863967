//! msx: multiple-scattering microfacet BSDFs (Wang et al. 2022 position-free
//! segment terms, Walter 2007 single scattering as Mitsuba 3 computes it) for
//! Mitsuba 3, behind a C ABI (`ffi`, header `include/msx.h`).

pub mod bsdf;
pub mod ffi;
pub mod microfacet;
pub mod microgeometry;
pub mod models;
pub mod rng;
pub mod spectrum;
pub mod tables;
pub mod walk;

pub use bsdf::{Bsdf, BsdfSample, Config, Estimator, Material, Model, ParamError, Surface};
pub use microfacet::{Distribution, Microfacet};
pub use spectrum::Spectrum;
