//! Entry points of the evaluation, not of a renderer: the stability study of
//! Bitterli & d'Eon's p_exit, and light transport simulated on generated
//! Beckmann microgeometry (docs/microgeometry.md).

use super::output::caught_panic;
use super::params::*;
use super::{report_panic, write_error, MSX_ERR_INVALID_PARAMETER, MSX_ERR_NULL_POINTER, MSX_ERR_PANIC, MSX_OK};
use glam::DVec3;
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Stability of Bitterli & d'Eon's p_exit (a diagnostic for the evaluation
/// report): relative error of its sum-of-exponentials form against the stable
/// invariance-principle form on up to `paths` conductor random-walk paths of
/// `vertices` bounces from an incident direction at `theta_i` radians, GGX or
/// Beckmann of roughness `alpha`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxPexitStudy {
    pub median_rel_error: f64,
    pub max_rel_error: f64,
    /// Fraction of paths where the p_exit form is not finite (exact division by zero).
    pub nonfinite_fraction: f64,
}

/// See `MsxPexitStudy`. Invalid arguments give all zeros.
#[no_mangle]
pub extern "C" fn msx_pexit_study(distribution: u32, alpha: f64, theta_i: f64, vertices: u32, paths: u32, seed: u64) -> MsxPexitStudy {
    let Some(dist) = distribution_from(distribution) else { return MsxPexitStudy::default() };
    if !(alpha.is_finite() && alpha > 0.0 && theta_i.is_finite()) || vertices == 0 || vertices > 64 {
        return MsxPexitStudy::default();
    }
    catch_unwind(AssertUnwindSafe(|| {
        let mf = crate::microfacet::Microfacet::new(dist, alpha, alpha);
        let wi = DVec3::new(theta_i.sin(), 0.0, theta_i.cos());
        let mut rng = crate::rng::Sampler::new(seed);
        let (median_rel_error, max_rel_error, nonfinite_fraction) =
            crate::models::invariance::p_exit_error_study(&mf, wi, vertices as usize, paths as usize, &mut rng);
        MsxPexitStudy { median_rel_error, max_rel_error, nonfinite_fraction }
    }))
    .unwrap_or_else(|_| {
        caught_panic();
        MsxPexitStudy::default()
    })
}

/// Scattering orders a simulation tallies apart: 1, 2, 3 and 4+ (index 3).
pub const MSX_SIM_ORDERS: u32 = 4;
const _: () = assert!(MSX_SIM_ORDERS as usize == crate::microgeometry::simulate::ORDERS);

/// Configuration of a light transport simulation on generated Beckmann
/// surfaces (docs/microgeometry.md). Zero selects the default where noted.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxSimParams {
    /// MSX_SURFACE_*: what the facets do
    pub surface: u32,
    /// Beckmann roughness along x and y (α_v = 0: α_v = α_u)
    pub alpha_u: f64,
    pub alpha_v: f64,
    /// Direction towards the light: θ_i in [0, π/2) and φ_i (radians)
    pub theta_i: f64,
    pub phi_i: f64,
    /// Conductor complex IOR (η = 0, k = 1: perfect mirror, F = 1)
    pub eta: f64,
    pub k: f64,
    /// Dielectric relative IOR η_int/η_ext
    pub ior: f64,
    /// Diffuse facets' albedo
    pub albedo: f64,
    /// Vertices per side of each surface, a power of two (0 = 1024)
    pub grid: u32,
    /// Correlation length in cells (0 = 16)
    pub corr_cells: f64,
    /// Independent surface realisations, the batches of the error estimate (0 = 16)
    pub surfaces: u32,
    /// Direction bins: θ_o uniform on [0, π], φ_o uniform with bin 0 centred on φ_i (0 = 36 each)
    pub theta_bins: u32,
    pub phi_bins: u32,
    /// Rays still bouncing after this many events are dropped and counted (0 = 100000)
    pub max_bounces: u32,
    pub seed: u64,
}

/// Opaque simulation handle.
pub struct MsxSim {
    sim: crate::microgeometry::Simulation,
}

fn sim_config(p: &MsxSimParams) -> Result<crate::microgeometry::SimConfig, String> {
    use crate::microgeometry::{Facet, SimConfig, SurfaceParams};
    let facet = match p.surface {
        MSX_SURFACE_CONDUCTOR => Facet::Conductor { eta: p.eta, k: p.k },
        MSX_SURFACE_DIELECTRIC => Facet::Dielectric { ior: p.ior },
        MSX_SURFACE_DIFFUSE => Facet::Diffuse { albedo: p.albedo },
        v => {
            return Err(format!(
                "invalid parameter 'surface': unknown value {v}; allowed: {}",
                <crate::config::Surface as crate::config::Choice>::allowed()
            ))
        }
    };
    let or = |v: u32, d: u32| if v == 0 { d } else { v };
    let alpha_v = if p.alpha_v == 0.0 { p.alpha_u } else { p.alpha_v };
    let cfg = SimConfig {
        surface: SurfaceParams {
            alpha_x: p.alpha_u,
            alpha_y: alpha_v,
            grid: or(p.grid, 1024) as usize,
            corr_cells: if p.corr_cells == 0.0 { 16.0 } else { p.corr_cells },
        },
        facet,
        theta_i: p.theta_i,
        phi_i: p.phi_i,
        surfaces: or(p.surfaces, 16) as usize,
        seed: p.seed,
        theta_bins: or(p.theta_bins, 36) as usize,
        phi_bins: or(p.phi_bins, 36) as usize,
        max_bounces: or(p.max_bounces, 100_000),
    };
    cfg.validate().map_err(|e| format!("invalid simulation parameter: {e}"))?;
    Ok(cfg)
}

/// Generates the surfaces of a simulation. On success writes the handle to
/// `*out` and returns MSX_OK; otherwise an MSX_ERR_* code and a message in `err`.
#[no_mangle]
pub extern "C" fn msx_sim_new(params: *const MsxSimParams, out: *mut *mut MsxSim, err: *mut c_char, err_len: usize) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if params.is_null() || out.is_null() {
            write_error(err, err_len, "null pointer passed to msx_sim_new");
            return MSX_ERR_NULL_POINTER;
        }
        // SAFETY: checked non-null above.
        let cfg = match sim_config(unsafe { &*params }) {
            Ok(c) => c,
            Err(msg) => {
                write_error(err, err_len, &msg);
                return MSX_ERR_INVALID_PARAMETER;
            }
        };
        match crate::microgeometry::Simulation::new(cfg) {
            Ok(sim) => {
                // SAFETY: checked non-null above.
                unsafe { *out = Box::into_raw(Box::new(MsxSim { sim })) };
                MSX_OK
            }
            Err(msg) => {
                write_error(err, err_len, &msg);
                MSX_ERR_INVALID_PARAMETER
            }
        }
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "msx_sim_new"))
}

/// Frees a simulation (null is ignored).
#[no_mangle]
pub extern "C" fn msx_sim_free(sim: *mut MsxSim) {
    if sim.is_null() {
        return;
    }
    if catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: the pointer came from Box::into_raw in msx_sim_new.
        drop(unsafe { Box::from_raw(sim) });
    }))
    .is_err()
    {
        caught_panic();
    }
}

/// Traces `rays_per_surface` more rays on every surface with `threads`
/// threads (0 = all cores). The tallies depend only on the parameters and the
/// total number of rays, not on the threads or on how the rays are split
/// between calls (the caller can show progress between calls).
#[no_mangle]
pub extern "C" fn msx_sim_run(sim: *mut MsxSim, rays_per_surface: u64, threads: u32, err: *mut c_char, err_len: usize) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if sim.is_null() {
            write_error(err, err_len, "null pointer passed to msx_sim_run");
            return MSX_ERR_NULL_POINTER;
        }
        let threads = if threads == 0 { std::thread::available_parallelism().map(|t| t.get()).unwrap_or(1) } else { threads as usize };
        // SAFETY: non-null handle from msx_sim_new; the caller does not share it during the call.
        unsafe { (*sim).sim.run(rays_per_surface, threads) };
        MSX_OK
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "msx_sim_run"))
}

/// Copies `src` to the caller's buffer `dst` of `len` elements if the lengths match.
fn copy_out<T: Copy>(src: &[T], dst: *mut T, len: usize) -> i32 {
    if dst.is_null() {
        return MSX_ERR_NULL_POINTER;
    }
    if len != src.len() {
        return MSX_ERR_INVALID_PARAMETER;
    }
    // SAFETY: the caller promises `len` writable elements at `dst`.
    unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), dst, len) };
    MSX_OK
}

/// Reads the tallies. `lobes` receives Σ weight per [surface][order][θ bin][φ
/// bin] (surfaces·MSX_SIM_ORDERS·theta_bins·phi_bins values), `energy` Σ weight
/// per [surface][order][reflected, transmitted] (surfaces·MSX_SIM_ORDERS·2),
/// `counts` per [surface][rays, lost, capped, Σ bounces] (surfaces·4). A null
/// pointer skips that array; a length that does not match is an error.
#[no_mangle]
pub extern "C" fn msx_sim_read(
    sim: *const MsxSim,
    lobes: *mut f64,
    lobes_len: usize,
    energy: *mut f64,
    energy_len: usize,
    counts: *mut u64,
    counts_len: usize,
) -> i32 {
    if sim.is_null() {
        return MSX_ERR_NULL_POINTER;
    }
    catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: non-null handle from msx_sim_new.
        let t = unsafe { (*sim).sim.tally() };
        let mut rc = MSX_OK;
        if !lobes.is_null() {
            rc = rc.max(copy_out(&t.lobes, lobes, lobes_len));
        }
        if !energy.is_null() {
            rc = rc.max(copy_out(&t.energy, energy, energy_len));
        }
        if !counts.is_null() {
            let c: Vec<u64> = (0..t.surfaces).flat_map(|s| [t.rays[s], t.lost[s], t.capped[s], t.bounces[s]]).collect();
            rc = rc.max(copy_out(&c, counts, counts_len));
        }
        rc
    }))
    .unwrap_or_else(|_| {
        caught_panic();
        MSX_ERR_PANIC
    })
}

/// Copies the heights of surface `index` (grid² values, row-major, x fastest;
/// units of the height deviation σ) and its cell sizes (in the same units).
#[no_mangle]
pub extern "C" fn msx_sim_surface(sim: *const MsxSim, index: u32, heights: *mut f64, len: usize, dx: *mut f64, dy: *mut f64) -> i32 {
    if sim.is_null() {
        return MSX_ERR_NULL_POINTER;
    }
    catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: non-null handle from msx_sim_new.
        let fields = unsafe { (*sim).sim.fields() };
        let Some(f) = fields.get(index as usize) else { return MSX_ERR_INVALID_PARAMETER };
        if !dx.is_null() {
            // SAFETY: non-null pointer from the caller.
            unsafe { *dx = f.dx };
        }
        if !dy.is_null() {
            // SAFETY: non-null pointer from the caller.
            unsafe { *dy = f.dy };
        }
        if heights.is_null() {
            return MSX_OK;
        }
        let n = f.grid() as i64;
        let h: Vec<f64> = (0..n).flat_map(|j| (0..n).map(move |i| (i, j))).map(|(i, j)| f.vertex(i, j)).collect();
        copy_out(&h, heights, len)
    }))
    .unwrap_or_else(|_| {
        caught_panic();
        MSX_ERR_PANIC
    })
}
