//! Closed-form approximations (src/models/analytic/): Fast-MSX and energy compensation.

#[path = "../common/mod.rs"]
mod common;

mod fastmsx_compensated;
mod compensated_dielectric;
