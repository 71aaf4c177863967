//! Tables the models read at run time, computed by this project's own
//! quadrature on first use and cached for the process.

pub mod albedo;
