//! Position-free multiple scattering (Wang 2022, src/models/posfree/): one module per surface and estimator.

#[path = "../common/mod.rs"]
mod common;

mod conductor;
mod conductor_bdpt;
mod dielectric;
mod dielectric_bdpt;
mod diffuse;
mod diffuse_bdpt;
mod fireflies;
mod full_sphere;
mod shared;
