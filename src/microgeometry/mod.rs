//! Ground truth from explicit microgeometry: random periodic height fields
//! with Beckmann slope statistics (`surface`), exact ray traversal of them
//! (`trace`) and a multiple-bounce light transport simulation on them
//! (`simulate`). Independent of the models: nothing here uses Smith's
//! assumptions; the simulation is what the models are measured against
//! (docs/microgeometry.md).

pub mod fft;
pub mod simulate;
pub mod surface;
pub mod trace;

pub use simulate::{Facet, RayOutcome, SimConfig, Simulation, Tally};
pub use surface::{HeightField, SurfaceParams};
pub use trace::{Side, Trace};
