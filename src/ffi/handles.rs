//! A BSDF handle and its single calls.

use super::output::{caught_panic, out_f32, out_sample, out_spectrum};
use super::params::{config_from, material, vec3, MsxEvalPdf, MsxMaterial, MsxParams, MsxSample, MsxSpectrum, MsxVec3};
use super::{report_panic, write_error, MSX_ERR_INVALID_PARAMETER, MSX_ERR_NULL_POINTER, MSX_OK};
use crate::bsdf::{Bsdf, Material};
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Opaque BSDF handle.
pub struct MsxBsdf {
    pub(super) bsdf: Bsdf,
}

/// Creates a BSDF. On success writes the handle to `*out` and returns MSX_OK;
/// otherwise returns an MSX_ERR_* code and writes a NUL-terminated message
/// naming the parameter into `err` (capacity `err_len`, may be null).
#[no_mangle]
pub extern "C" fn msx_bsdf_new(params: *const MsxParams, out: *mut *mut MsxBsdf, err: *mut c_char, err_len: usize) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if params.is_null() || out.is_null() {
            write_error(err, err_len, "null pointer passed to msx_bsdf_new");
            return MSX_ERR_NULL_POINTER;
        }
        // SAFETY: checked non-null above.
        let p = unsafe { *params };
        let cfg = match config_from(&p) {
            Ok(cfg) => cfg,
            Err((name, msg)) => {
                write_error(err, err_len, &format!("invalid parameter '{name}': {msg}"));
                return MSX_ERR_INVALID_PARAMETER;
            }
        };
        match Bsdf::new(cfg) {
            Ok(bsdf) => {
                let handle = Box::into_raw(Box::new(MsxBsdf { bsdf }));
                // SAFETY: checked non-null above.
                unsafe { *out = handle };
                MSX_OK
            }
            Err(e) => {
                write_error(err, err_len, &e.to_string());
                MSX_ERR_INVALID_PARAMETER
            }
        }
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "msx_bsdf_new"))
}

/// Frees a BSDF created by `msx_bsdf_new` (null is ignored).
#[no_mangle]
pub extern "C" fn msx_bsdf_free(bsdf: *mut MsxBsdf) {
    if bsdf.is_null() {
        return;
    }
    if catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: the pointer came from Box::into_raw in msx_bsdf_new.
        drop(unsafe { Box::from_raw(bsdf) });
    }))
    .is_err()
    {
        caught_panic();
    }
}

/// Runs `f` on the handle and material, or returns `fallback` on null
/// pointers and panics.
pub(super) fn with_bsdf<T>(bsdf: *const MsxBsdf, mat: *const MsxMaterial, fallback: T, f: impl FnOnce(&Bsdf, Material) -> T) -> T {
    if bsdf.is_null() || mat.is_null() {
        return fallback;
    }
    // SAFETY: non-null pointers from the caller; the handle is immutable.
    let (b, m) = unsafe { (&(*bsdf).bsdf, material(&*mat)) };
    catch_unwind(AssertUnwindSafe(|| f(b, m))).unwrap_or_else(|_| {
        caught_panic();
        fallback
    })
}

/// The key of one BSDF call from where it happens: the hit position and uv
/// (two samples of a render never share them). Passing it as the `key` of
/// `msx_eval*` makes every estimate a function of its own inputs and the seed,
/// so that a render does not depend on thread scheduling or call order.
#[no_mangle]
pub extern "C" fn msx_call_key(px: f32, py: f32, pz: f32, u: f32, v: f32) -> u64 {
    crate::rng::hash_words(&[px.to_bits() as u64, py.to_bits() as u64, pz.to_bits() as u64, u.to_bits() as u64, v.to_bits() as u64])
}

/// f(ω_i, ω_o)·|cos θ_o| per channel (Mitsuba's `eval`). `key` is any 64-bit
/// value that decorrelates calls (e.g. a per-call counter); the result is a
/// deterministic function of the inputs, the BSDF's seed and `key`.
#[no_mangle]
pub extern "C" fn msx_eval(bsdf: *const MsxBsdf, mat: *const MsxMaterial, wi: MsxVec3, wo: MsxVec3, key: u64) -> MsxSpectrum {
    with_bsdf(bsdf, mat, MsxSpectrum::default(), |b, m| out_spectrum(b.eval(&m, vec3(wi), vec3(wo), key), b.config().channels))
}

/// `msx_eval` restricted to scattering orders first..=last (1 = single scattering).
#[no_mangle]
pub extern "C" fn msx_eval_orders(
    bsdf: *const MsxBsdf,
    mat: *const MsxMaterial,
    wi: MsxVec3,
    wo: MsxVec3,
    key: u64,
    first: u32,
    last: u32,
) -> MsxSpectrum {
    with_bsdf(bsdf, mat, MsxSpectrum::default(), |b, m| out_spectrum(b.eval_orders(&m, vec3(wi), vec3(wo), key, (first, last)), b.config().channels))
}

/// Density that `msx_sample` reports for ω_o (for MIS).
#[no_mangle]
pub extern "C" fn msx_pdf(bsdf: *const MsxBsdf, mat: *const MsxMaterial, wi: MsxVec3, wo: MsxVec3) -> f32 {
    with_bsdf(bsdf, mat, 0.0, |b, m| out_f32(b.pdf(&m, vec3(wi), vec3(wo))))
}

/// `msx_eval` and `msx_pdf` in one call.
#[no_mangle]
pub extern "C" fn msx_eval_pdf(bsdf: *const MsxBsdf, mat: *const MsxMaterial, wi: MsxVec3, wo: MsxVec3, key: u64) -> MsxEvalPdf {
    with_bsdf(bsdf, mat, MsxEvalPdf::default(), |b, m| {
        let (v, p) = b.eval_pdf(&m, vec3(wi), vec3(wo), key);
        MsxEvalPdf { value: out_spectrum(v, b.config().channels), pdf: out_f32(p) }
    })
}

/// Samples ω_o from Mitsuba's `sample1` and `sample2` (in [0, 1)).
#[no_mangle]
pub extern "C" fn msx_sample(bsdf: *const MsxBsdf, mat: *const MsxMaterial, wi: MsxVec3, sample1: f32, u: f32, v: f32) -> MsxSample {
    with_bsdf(bsdf, mat, MsxSample::default(), |b, m| out_sample(b.sample(&m, vec3(wi), sample1 as f64, (u as f64, v as f64)), b.config().channels))
}
