//! The core's tables for the Dr.Jit engine (mitsuba_plugin/msx/jit/), which
//! computes nothing it can take from the core: it reads the tables once and
//! uploads them as textures, interpolating them as `tables::Grid::at` does.

use super::params::*;
use super::{report_panic, write_error, MSX_ERR_INVALID_PARAMETER, MSX_ERR_NULL_POINTER, MSX_OK};
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// `msx_table` kinds: directional albedos with F = 1 over (α, cos θ_i) — of
/// `single` (Mitsuba's G1), and of order 1 of the uncorrelated and the
/// height-correlated models (the walks' MIS density, src/models/mis.rs).
pub const MSX_TABLE_ALBEDO_SINGLE: u32 = 0;
pub const MSX_TABLE_E1_UNCORRELATED: u32 = 1;
pub const MSX_TABLE_E1_CORRELATED: u32 = 2;
/// E_avg(α) = 2∫E(μ)μ dμ of `single` (F = 1), over α alone.
pub const MSX_TABLE_ALBEDO_AVG: u32 = 3;
/// E_r + E_t of `single` on a dielectric (Importance mode) over (α, n, μ),
/// entering a denser medium (η_r = n ≥ 1) and leaving it (η_r = 1/n).
pub const MSX_TABLE_DIELECTRIC_ENTER: u32 = 4;
pub const MSX_TABLE_DIELECTRIC_LEAVE: u32 = 5;

/// `MsxAxis::warp`: the coordinate u = warp(x) in which an axis's nodes are uniform.
pub const MSX_WARP_IDENTITY: u32 = 0;
pub const MSX_WARP_SQRT: u32 = 1;
/// x clamped into [0, 1], squared.
pub const MSX_WARP_SQUARE: u32 = 2;
pub const MSX_WARP_LN: u32 = 3;
/// √(1 − 1/x²).
pub const MSX_WARP_CRITICAL_COSINE: u32 = 4;

/// One axis of a table: `n` nodes uniform in u = warp(x) from `lo` to `hi`
/// (u values), at the ends of n − 1 steps (`centred` = 0) or at the centres
/// of n cells (`centred` = 1). A lookup clamps x's node position to [0, n − 1]
/// and interpolates linearly between nodes, axis by axis.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxAxis {
    pub warp: u32,
    pub lo: f64,
    pub hi: f64,
    pub n: u32,
    pub centred: u32,
}

/// The shape of a table: `naxes` axes (the last varies fastest in the values)
/// and `len` values.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxTableShape {
    pub naxes: u32,
    pub axes: [MsxAxis; 3],
    pub len: usize,
}

fn axis_out(a: &crate::tables::Axis) -> MsxAxis {
    use crate::tables::Warp;
    let warp = match a.warp {
        Warp::Identity => MSX_WARP_IDENTITY,
        Warp::Sqrt => MSX_WARP_SQRT,
        Warp::Square => MSX_WARP_SQUARE,
        Warp::Ln => MSX_WARP_LN,
        Warp::CriticalCosine => MSX_WARP_CRITICAL_COSINE,
    };
    MsxAxis { warp, lo: a.lo, hi: a.hi, n: a.n as u32, centred: a.centred as u32 }
}

/// Writes the shape of table `kind` (MSX_TABLE_*) of `distribution` to
/// `*shape` and, when `out_values` is not null and `len` ≥ the table's length,
/// its values. Computes the table on first use (as the models do).
#[no_mangle]
pub extern "C" fn msx_table(
    kind: u32,
    distribution: u32,
    shape: *mut MsxTableShape,
    out_values: *mut f64,
    len: usize,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if shape.is_null() {
            write_error(err, err_len, "null pointer passed to msx_table");
            return MSX_ERR_NULL_POINTER;
        }
        let Some(dist) = choice_arg::<crate::config::Distribution>(distribution, err, err_len) else { return MSX_ERR_INVALID_PARAMETER };
        let albedo = || crate::tables::albedo::AlbedoTable::get(dist);
        let dielectric = || crate::models::analytic::dielectric_albedo::DielectricAlbedoTable::get(dist).grids();
        let (axes, values): (&[crate::tables::Axis], &[f64]) = match kind {
            MSX_TABLE_ALBEDO_SINGLE => (&albedo().grids()[0].axes, &albedo().grids()[0].values),
            MSX_TABLE_E1_UNCORRELATED => (&albedo().grids()[1].axes, &albedo().grids()[1].values),
            MSX_TABLE_E1_CORRELATED => (&albedo().grids()[2].axes, &albedo().grids()[2].values),
            MSX_TABLE_ALBEDO_AVG => (&albedo().e_avg_grid().axes, &albedo().e_avg_grid().values),
            MSX_TABLE_DIELECTRIC_ENTER => (&dielectric()[0].axes, &dielectric()[0].values),
            MSX_TABLE_DIELECTRIC_LEAVE => (&dielectric()[1].axes, &dielectric()[1].values),
            _ => {
                write_error(err, err_len, &format!("invalid parameter 'kind': unknown table {kind}"));
                return MSX_ERR_INVALID_PARAMETER;
            }
        };
        let mut out = MsxTableShape { naxes: axes.len() as u32, len: values.len(), ..Default::default() };
        for (o, a) in out.axes.iter_mut().zip(axes) {
            *o = axis_out(a);
        }
        // SAFETY: checked non-null above.
        unsafe { *shape = out };
        if !out_values.is_null() && len >= values.len() {
            // SAFETY: the caller provides `len` writable values.
            unsafe { std::ptr::copy_nonoverlapping(values.as_ptr(), out_values, values.len()) };
        }
        MSX_OK
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "msx_table"))
}

/// The rule of `model="auto"` (src/models/auto/) for a surface (MSX_SURFACE_*),
/// distribution, tolerance (0 = MSX_DEFAULT_AUTO_TOLERANCE) and the relative
/// IOR seen from ω_i (1 for conductors and diffuse surfaces): writes the μ axis
/// of its cells to `*mu_axis` (nodes at the cells' ends; μ below √lo runs the
/// full model) and, when `len` ≥ n − 1, each cell's α threshold to
/// `thresholds`: order 1 alone suffices where max(α_u, α_v) ≤ the threshold of
/// the cell of |cos θ_i|, the cell i = ⌊(μ² − lo)(n − 1)/(hi − lo)⌋ clamped to
/// [0, n − 2] (64 cells: the most a caller needs room for). Computes the rule
/// on first use (once per process and IOR; src/models/auto/).
#[no_mangle]
pub extern "C" fn msx_auto_rule(
    surface: u32,
    distribution: u32,
    tolerance: f64,
    eta: f64,
    mu_axis: *mut MsxAxis,
    thresholds: *mut f64,
    len: usize,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if mu_axis.is_null() {
            write_error(err, err_len, "null pointer passed to msx_auto_rule");
            return MSX_ERR_NULL_POINTER;
        }
        let Some(surface) = choice_arg::<crate::config::Surface>(surface, err, err_len) else { return MSX_ERR_INVALID_PARAMETER };
        let Some(dist) = choice_arg::<crate::config::Distribution>(distribution, err, err_len) else { return MSX_ERR_INVALID_PARAMETER };
        let tolerance = if tolerance == 0.0 { MSX_DEFAULT_AUTO_TOLERANCE } else { tolerance };
        if !(tolerance > 0.0 && tolerance < 1.0 && eta.is_finite()) {
            write_error(err, err_len, "invalid parameter 'auto_tolerance' or 'eta' passed to msx_auto_rule");
            return MSX_ERR_INVALID_PARAMETER;
        }
        let rule = crate::models::auto::OrderOneRule::new(surface, dist, tolerance);
        let axis = crate::models::auto::table::MU;
        // SAFETY: checked non-null above.
        unsafe { *mu_axis = axis_out(&axis) };
        let values = rule.thresholds(eta);
        if !thresholds.is_null() && len >= values.len() {
            // SAFETY: the caller provides `len` writable values.
            unsafe { std::ptr::copy_nonoverlapping(values.as_ptr(), thresholds, values.len()) };
        }
        MSX_OK
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "msx_auto_rule"))
}
