//! The invariance principle (Cui 2023, src/models/invariance/): one module per surface.

#[path = "../common/mod.rs"]
mod common;

mod conductor;
mod dielectric;
mod diffuse;
