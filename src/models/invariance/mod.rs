//! The invariance principle, Cui et al. 2023 (with Bitterli & d'Eon 2022's
//! exit probability): Heitz's random walk with the microsurface heights
//! integrated out exactly by the segment term S_k.
//!
//! | file | what |
//! |---|---|
//! | `recursion.rs` | the complete S_k recursion, p_exit and its stability study, the incremental exit table of monotone (conductor) paths |
//! | `conductor.rs` | eval and sample on conductor facets |
//! | `general.rs` | the complete recursion for non-monotone paths (the diffuse microsurface) |
//! | `dielectric.rs` | heights integrated exactly up to the first refraction, Heitz's walk after it |

pub mod conductor;
pub mod dielectric;
pub mod general;
pub mod recursion;

pub use recursion::{p_exit, p_exit_error_study, p_exit_with_bound, segment_term, segment_term_monotone, MonotoneExit};
