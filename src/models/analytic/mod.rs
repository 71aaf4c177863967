//! Closed-form approximations of multiple scattering (no random walk): what
//! production renderers ship, compared against the walks in the evaluation.
//!
//! | file | what |
//! |---|---|
//! | `fastmsx.rs` | Fast-MSX (Rosales et al. 2023): an analytic second-bounce lobe for GGX conductors |
//! | `compensated.rs` | Turquin 2019 / Kulla & Conty 2017 energy compensation of conductors |
//! | `compensated_dielectric.rs` | the same scaling for rough dielectrics (both sides of the interface) |

pub mod compensated;
pub mod compensated_dielectric;
pub mod fastmsx;
