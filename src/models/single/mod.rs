//! Single scattering, Walter et al. 2007, exactly as Mitsuba 3's built-in
//! `roughconductor` (`conductor.rs`) and `roughdielectric` (`dielectric.rs`)
//! compute it: the reference every multiple-scattering model reduces to at
//! order 1, and `model="single"`.

pub mod conductor;
pub mod dielectric;
