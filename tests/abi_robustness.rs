//! Robustness of the C ABI, called from Rust through `msx::ffi::*` exactly as
//! a C caller would: bad input never yields NaN, Inf or negative values and
//! never panics (not even a panic caught by the ABI's `catch_unwind`: a panic
//! hook counts them per thread); invalid configuration returns an error code
//! and a message naming the parameter; results are deterministic in
//! (inputs, seed, key); batched calls equal per-call calls lane by lane.

// Lints relaxed for this test file: the sweeps use values near π/2 and 2π on purpose (grazing, not exactly horizontal); tuple types of test tables.
#![allow(clippy::approx_constant, clippy::type_complexity)]

mod common;

use common::Rng;
use msx::ffi::*;
use std::cell::Cell;
use std::collections::HashSet;
use std::ffi::CStr;
use std::os::raw::c_char;
use std::ptr;
use std::sync::Once;

// ------------------------------------------------------------ panic counting

thread_local! {
    static PANICS: Cell<usize> = const { Cell::new(0) };
}

/// Installs (once) a panic hook that counts panics on the current thread, so
/// that panics swallowed by the ABI's `catch_unwind` are still detected.
/// A panic in a batch worker thread re-panics on the calling thread when the
/// thread scope ends, so it is counted there too.
fn count_panics() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICS.with(|p| p.set(p.get() + 1));
            previous(info);
        }));
    });
}

fn panics() -> usize {
    PANICS.with(|p| p.get())
}

/// Runs `f` and asserts that no panic (caught or not) happened on this thread.
fn no_panic<T>(what: &str, f: impl FnOnce() -> T) -> T {
    count_panics();
    let before = panics();
    let out = f();
    assert_eq!(panics(), before, "{what}: a panic happened inside the ABI (caught by catch_unwind)");
    out
}

// ------------------------------------------------------------ helpers

const MODELS: [u32; 3] = [MSX_MODEL_SINGLE, MSX_MODEL_UNCORRELATED, MSX_MODEL_CORRELATED];
const DISTRIBUTIONS: [u32; 2] = [MSX_DISTRIBUTION_BECKMANN, MSX_DISTRIBUTION_GGX];
const CU_ETA: [f32; 4] = [0.200438, 0.924033, 1.10221, 0.5];
const CU_K: [f32; 4] = [3.91295, 2.45285, 2.14219, 3.0];

fn params(model: u32, distribution: u32) -> MsxParams {
    MsxParams {
        surface: MSX_SURFACE_CONDUCTOR,
        distribution,
        model,
        estimator: MSX_ESTIMATOR_PT,
        max_bounces: 0,
        channels: 4,
        seed: 1234,
        auto_tolerance: 0.0,
        mis_density: 0,
        sample_all_normals: 0,
    }
}

/// An owned handle, freed on drop.
struct Handle(*mut MsxBsdf);

impl Drop for Handle {
    fn drop(&mut self) {
        msx_bsdf_free(self.0);
    }
}

fn try_new(p: &MsxParams) -> Result<Handle, (i32, String)> {
    let mut out: *mut MsxBsdf = ptr::null_mut();
    let mut err = [0 as c_char; 512];
    let rc = no_panic("msx_bsdf_new", || msx_bsdf_new(p, &mut out, err.as_mut_ptr(), err.len()));
    if rc == MSX_OK {
        assert!(!out.is_null(), "MSX_OK without a handle");
        Ok(Handle(out))
    } else {
        assert!(out.is_null(), "an error must not write a handle");
        let msg = unsafe { CStr::from_ptr(err.as_ptr()) }.to_string_lossy().into_owned();
        Err((rc, msg))
    }
}

fn new(p: &MsxParams) -> Handle {
    try_new(p).unwrap_or_else(|(rc, msg)| panic!("msx_bsdf_new({p:?}) failed: {rc} {msg}"))
}

fn material(alpha_u: f32, alpha_v: f32, eta: [f32; 4], k: [f32; 4]) -> MsxMaterial {
    MsxMaterial { alpha_u, alpha_v, eta, k, specular_reflectance: [1.0; 4], ..Default::default() }
}

fn mirror(alpha: f32) -> MsxMaterial {
    material(alpha, alpha, [0.0; 4], [1.0; 4])
}

fn v3(x: f64, y: f64, z: f64) -> MsxVec3 {
    MsxVec3 { x: x as f32, y: y as f32, z: z as f32 }
}

fn dir(theta: f64, phi: f64) -> MsxVec3 {
    v3(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

fn ok_f(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

fn check_spectrum(s: &MsxSpectrum, channels: usize, ctx: &dyn Fn() -> String) {
    for (c, &x) in s.v.iter().enumerate() {
        assert!(ok_f(x), "{}: channel {c} = {x}", ctx());
        if c >= channels {
            assert_eq!(x, 0.0, "{}: channel {c} beyond `channels` must be 0", ctx());
        }
    }
}

fn check_sample(s: &MsxSample, channels: usize, ctx: &dyn Fn() -> String) {
    assert!(s.valid == 0 || s.valid == 1, "{}: valid = {}", ctx(), s.valid);
    check_spectrum(&s.weight, channels, ctx);
    assert!(ok_f(s.pdf), "{}: sample pdf = {}", ctx(), s.pdf);
    if s.valid == 1 {
        let len = ((s.wo.x as f64).powi(2) + (s.wo.y as f64).powi(2) + (s.wo.z as f64).powi(2)).sqrt();
        assert!((len - 1.0).abs() < 1e-4, "{}: sampled wo {:?} has length {len}", ctx(), s.wo);
        assert!(s.pdf > 0.0, "{}: valid sample with pdf {}", ctx(), s.pdf);
    } else {
        let zero = s.pdf == 0.0 && s.wo.x == 0.0 && s.wo.y == 0.0 && s.wo.z == 0.0 && s.weight.v.iter().all(|&x| x == 0.0);
        assert!(zero, "{}: an invalid sample must be all zero: {s:?}", ctx());
    }
}

/// Calls every per-call entry point on (wi, wo) and checks the outputs.
fn exercise(h: &Handle, channels: usize, m: &MsxMaterial, wi: MsxVec3, wo: MsxVec3, key: u64, ctx: &dyn Fn() -> String) {
    no_panic(&ctx(), || {
        let e = msx_eval(h.0, m, wi, wo, key);
        check_spectrum(&e, channels, &|| format!("{} eval", ctx()));
        for (first, last) in [(1, 1), (2, 3), (0, u32::MAX), (5, 2)] {
            let o = msx_eval_orders(h.0, m, wi, wo, key, first, last);
            check_spectrum(&o, channels, &|| format!("{} eval_orders({first}, {last})", ctx()));
        }
        let p = msx_pdf(h.0, m, wi, wo);
        assert!(ok_f(p), "{} pdf = {p}", ctx());
        let ep = msx_eval_pdf(h.0, m, wi, wo, key);
        check_spectrum(&ep.value, channels, &|| format!("{} eval_pdf", ctx()));
        assert!(ok_f(ep.pdf), "{} eval_pdf pdf = {}", ctx(), ep.pdf);
        for (s1, u, v) in [(0.5, 0.3, 0.7), (0.0, 0.0, 0.0), (0.999_999_9, 0.999_999_9, 0.999_999_9), (0.1, 0.9, 0.01)] {
            let s = msx_sample(h.0, m, wi, s1, u, v);
            check_sample(&s, channels, &|| format!("{} sample({s1}, {u}, {v})", ctx()));
        }
    });
}

// ------------------------------------------------------------ bad per-call input

fn bad_directions() -> Vec<(&'static str, MsxVec3)> {
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    vec![
        ("nan x", MsxVec3 { x: nan, y: 0.0, z: 1.0 }),
        ("nan z", MsxVec3 { x: 0.3, y: 0.2, z: nan }),
        ("all nan", MsxVec3 { x: nan, y: nan, z: nan }),
        ("inf z", MsxVec3 { x: 0.0, y: 0.0, z: inf }),
        ("-inf x", MsxVec3 { x: -inf, y: 0.0, z: 1.0 }),
        ("inf, inf", MsxVec3 { x: inf, y: 0.0, z: inf }),
        ("zero", MsxVec3 { x: 0.0, y: 0.0, z: 0.0 }),
        ("negative zero", MsxVec3 { x: -0.0, y: -0.0, z: -0.0 }),
        ("subnormal", MsxVec3 { x: 1e-45, y: 0.0, z: 1e-45 }),
        ("tiny", MsxVec3 { x: 1e-30, y: 2e-30, z: 3e-30 }),
        ("long", MsxVec3 { x: 3.0, y: -4.0, z: 12.0 }),
        ("huge", MsxVec3 { x: f32::MAX, y: f32::MAX, z: f32::MAX }),
        ("f32::MAX z", MsxVec3 { x: 0.0, y: 0.0, z: f32::MAX }),
        ("below horizon", dir(2.0, 0.3)),
        ("straight down", MsxVec3 { x: 0.0, y: 0.0, z: -1.0 }),
        ("horizontal", MsxVec3 { x: 1.0, y: 0.0, z: 0.0 }),
        ("grazing", MsxVec3 { x: 1.0, y: 0.0, z: 1e-7 }),
        ("grazing below", MsxVec3 { x: 1.0, y: 0.0, z: -1e-7 }),
        ("normal", MsxVec3 { x: 0.0, y: 0.0, z: 1.0 }),
        ("unit 45°", dir(std::f64::consts::FRAC_PI_4, 1.0)),
    ]
}

fn bad_alphas() -> Vec<f32> {
    vec![0.0, -0.0, -1.0, f32::NAN, 1e30, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN_POSITIVE, 1e-45, 1e-30, 1e4, 1e5, 0.5]
}

#[test]
fn bad_directions_and_roughness_are_harmless() {
    let diag = msx_diagnostics();
    let dirs = bad_directions();
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            let h = new(&params(model, dist));
            for &alpha in &bad_alphas() {
                for (m_name, m) in [("mirror", mirror(alpha)), ("Cu", material(alpha, 0.3, CU_ETA, CU_K))] {
                    for (i, (wi_name, wi)) in dirs.iter().enumerate() {
                        for (j, (wo_name, wo)) in dirs.iter().enumerate() {
                            // Full cross product for the mirror, a diagonal band for Cu.
                            if m_name == "Cu" && (i + j) % 4 != 0 {
                                continue;
                            }
                            let ctx = || format!("model {model} dist {dist} α {alpha} {m_name} wi {wi_name} wo {wo_name}");
                            exercise(&h, 4, &m, *wi, *wo, (i * 31 + j) as u64, &ctx);
                        }
                    }
                }
            }
        }
    }
    common::assert_no_raw_defects(diag, "bad_directions_and_roughness_are_harmless");
}

#[test]
fn bad_ior_and_reflectance_are_harmless() {
    let diag = msx_diagnostics();
    let nan = f32::NAN;
    let inf = f32::INFINITY;
    let iors: Vec<(&str, [f32; 4], [f32; 4])> = vec![
        ("huge eta", [1e30; 4], [1.0; 4]),
        ("huge k", [0.2; 4], [1e30; 4]),
        ("huge both", [f32::MAX; 4], [f32::MAX; 4]),
        ("nan eta", [nan; 4], [1.0; 4]),
        ("nan k", [0.2; 4], [nan; 4]),
        ("inf eta", [inf; 4], [3.0; 4]),
        ("inf k", [0.2; 4], [inf; 4]),
        ("-inf", [-inf; 4], [-inf; 4]),
        ("negative", [-1.0; 4], [-2.0; 4]),
        ("zero", [0.0; 4], [0.0; 4]),
        ("tiny", [1e-38; 4], [1e-38; 4]),
        ("mixed", [nan, 0.2, 1e30, -1.0], [1.0, inf, 0.0, nan]),
    ];
    let reflectances: [[f32; 4]; 5] = [[1.0; 4], [nan; 4], [-1.0; 4], [inf; 4], [1e30, 0.5, -0.0, f32::MAX]];
    let wis = [dir(0.3, 0.1), dir(1.2, 2.0), dir(1.570796, 0.0)];
    let wos = [dir(0.4, 3.0), dir(0.9, 0.2), dir(1.5, 1.0)];
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            let h = new(&params(model, dist));
            for (name, eta, k) in &iors {
                for spec in &reflectances {
                    for alpha in [0.05f32, 0.5, 2.0] {
                        let mut m = material(alpha, alpha, *eta, *k);
                        m.specular_reflectance = *spec;
                        for wi in wis {
                            for wo in wos {
                                let ctx = || format!("model {model} dist {dist} {name} spec {spec:?} α {alpha} wi {wi:?} wo {wo:?}");
                                exercise(&h, 4, &m, wi, wo, 9, &ctx);
                            }
                        }
                    }
                }
            }
        }
    }
    common::assert_no_raw_defects(diag, "bad_ior_and_reflectance_are_harmless");
}

#[test]
fn bad_sample_values_are_harmless() {
    let diag = msx_diagnostics();
    let values = [f32::NAN, -1.0, -0.0, 0.0, 1.0, 1.5, 2.0, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, 1e-45, 0.999_999_94];
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            let h = new(&params(model, dist));
            for alpha in [0.0f32, 0.01, 0.5, 3.0, f32::NAN] {
                let m = material(alpha, alpha, CU_ETA, CU_K);
                for wi in [dir(0.2, 0.3), dir(1.5, 4.0), v3(0.0, 0.0, 1.0)] {
                    for &a in &values {
                        for &b in &values {
                            for &c in &[values[0], values[1], values[4], values[5], 0.5] {
                                let s = no_panic("msx_sample", || msx_sample(h.0, &m, wi, c, a, b));
                                check_sample(&s, 4, &|| format!("model {model} dist {dist} α {alpha} wi {wi:?} samples ({c}, {a}, {b})"));
                            }
                        }
                    }
                }
            }
        }
    }
    common::assert_no_raw_defects(diag, "bad_sample_values_are_harmless");
}

// ------------------------------------------------------------ null pointers

fn message(err: &[c_char]) -> String {
    unsafe { CStr::from_ptr(err.as_ptr()) }.to_string_lossy().into_owned()
}

#[test]
fn null_pointers_everywhere() {
    let diag = msx_diagnostics();
    no_panic("null pointers", || {
        let p = params(MSX_MODEL_CORRELATED, MSX_DISTRIBUTION_GGX);
        let mut out: *mut MsxBsdf = ptr::null_mut();
        let mut err = [0 as c_char; 256];

        // msx_bsdf_new: null params, null out, null/short error buffers.
        assert_eq!(msx_bsdf_new(ptr::null(), &mut out, err.as_mut_ptr(), err.len()), MSX_ERR_NULL_POINTER);
        assert!(out.is_null());
        assert!(message(&err).contains("null"), "message: {}", message(&err));
        assert_eq!(msx_bsdf_new(&p, ptr::null_mut(), err.as_mut_ptr(), err.len()), MSX_ERR_NULL_POINTER);
        assert_eq!(msx_bsdf_new(ptr::null(), ptr::null_mut(), ptr::null_mut(), 0), MSX_ERR_NULL_POINTER);
        assert_eq!(msx_bsdf_new(ptr::null(), ptr::null_mut(), ptr::null_mut(), 100), MSX_ERR_NULL_POINTER);
        assert_eq!(msx_bsdf_new(ptr::null(), ptr::null_mut(), err.as_mut_ptr(), 0), MSX_ERR_NULL_POINTER);
        // err_len = 1: only the terminator fits; nothing after it is touched.
        let mut small = [b'x' as c_char; 4];
        assert_eq!(msx_bsdf_new(ptr::null(), &mut out, small.as_mut_ptr(), 1), MSX_ERR_NULL_POINTER);
        assert_eq!(small, [0, b'x' as c_char, b'x' as c_char, b'x' as c_char]);
        // A valid call with a null error buffer works.
        assert_eq!(msx_bsdf_new(&p, &mut out, ptr::null_mut(), 0), MSX_OK);
        let h = Handle(out);

        msx_bsdf_free(ptr::null_mut());
        let version = msx_version();
        assert!(!version.is_null());
        assert!(!unsafe { CStr::from_ptr(version) }.to_bytes().is_empty());

        // Per-call entry points: null handle and/or material give zeros.
        let m = mirror(0.5);
        let (wi, wo) = (dir(0.4, 0.0), dir(0.5, 2.0));
        for (bsdf, mat) in [(ptr::null(), &m as *const MsxMaterial), (h.0 as *const MsxBsdf, ptr::null()), (ptr::null(), ptr::null())] {
            assert_eq!(msx_eval(bsdf, mat, wi, wo, 1).v, [0.0; 4]);
            assert_eq!(msx_eval_orders(bsdf, mat, wi, wo, 1, 1, 10).v, [0.0; 4]);
            assert_eq!(msx_pdf(bsdf, mat, wi, wo), 0.0);
            let ep = msx_eval_pdf(bsdf, mat, wi, wo, 1);
            assert_eq!((ep.value.v, ep.pdf), ([0.0; 4], 0.0));
            let s = msx_sample(bsdf, mat, wi, 0.5, 0.5, 0.5);
            assert_eq!(s.valid, 0);
            check_sample(&s, 4, &|| "null sample".into());
        }
        // ... while the same call with valid pointers gives a value.
        assert!(msx_eval(h.0, &m, wi, wo, 1).v[0] > 0.0);

        // Batched entry points: null handle / input / output.
        let n = 4usize;
        let xs = [0.1f32; 4];
        let mut val = [0.0f32; 4];
        let mut input = empty_batch(n, 0);
        input.wi[0] = MsxF32Array { ptr: xs.as_ptr(), len: n };
        let mut output = empty_out();
        output.value[0] = val.as_mut_ptr();
        type BatchFn = extern "C" fn(*const MsxBsdf, *const MsxBatchIn, *const MsxBatchOut, *mut c_char, usize) -> i32;
        let fns: [(&str, BatchFn); 4] =
            [("eval", msx_eval_batch), ("pdf", msx_pdf_batch), ("eval_pdf", msx_eval_pdf_batch), ("sample", msx_sample_batch)];
        for (name, f) in fns {
            for (b, i, o) in [
                (ptr::null(), &input as *const _, &output as *const _),
                (h.0 as *const _, ptr::null(), &output as *const _),
                (h.0 as *const _, &input as *const _, ptr::null()),
            ] {
                err[0] = 0;
                assert_eq!(f(b, i, o, err.as_mut_ptr(), err.len()), MSX_ERR_NULL_POINTER, "{name}");
                assert!(message(&err).contains("null"), "{name}: {}", message(&err));
                assert_eq!(f(b, i, o, ptr::null_mut(), 0), MSX_ERR_NULL_POINTER, "{name}");
            }
            // All output pointers null: nothing is written, no error.
            assert_eq!(f(h.0, &input, &empty_out(), err.as_mut_ptr(), err.len()), MSX_OK, "{name}");
            // A null array pointer with a non-zero length selects the default.
            let mut i2 = input;
            i2.wo[2] = MsxF32Array { ptr: ptr::null(), len: n };
            assert_eq!(f(h.0, &i2, &output, err.as_mut_ptr(), err.len()), MSX_OK, "{name}");
            assert!(val.iter().all(|&x| ok_f(x)));
            // n = 0 writes nothing.
            let mut i3 = input;
            i3.n = 0;
            i3.wi[0].len = 0;
            val = [-7.0; 4];
            assert_eq!(f(h.0, &i3, &output, err.as_mut_ptr(), err.len()), MSX_OK, "{name}");
            assert_eq!(val, [-7.0; 4], "{name}: n = 0 must not write");
        }
    });
    common::assert_no_raw_defects(diag, "null_pointers_everywhere");
}

// ------------------------------------------------------------ invalid configuration

fn expect_error(p: &MsxParams, name: &str) {
    match try_new(p) {
        Ok(_) => panic!("{p:?} accepted; expected an error naming '{name}'"),
        Err((rc, msg)) => {
            assert_eq!(rc, MSX_ERR_INVALID_PARAMETER, "{p:?}: {msg}");
            assert!(msg.contains(&format!("'{name}'")), "message for {p:?} must name '{name}': {msg}");
        }
    }
}

#[test]
fn invalid_configuration_is_reported_by_name() {
    let base = params(MSX_MODEL_CORRELATED, MSX_DISTRIBUTION_GGX);
    for v in [3, 7, u32::MAX] {
        expect_error(&MsxParams { surface: v, ..base }, "surface");
    }
    for v in [2, 3, 100, u32::MAX] {
        expect_error(&MsxParams { distribution: v, ..base }, "distribution");
    }
    for v in [8, 99, u32::MAX] {
        expect_error(&MsxParams { model: v, ..base }, "model");
    }
    // Known values in a combination that does not exist name the parameter at fault.
    expect_error(&MsxParams { model: MSX_MODEL_FASTMSX, distribution: MSX_DISTRIBUTION_BECKMANN, ..base }, "distribution");
    expect_error(&MsxParams { model: MSX_MODEL_SINGLE, estimator: MSX_ESTIMATOR_BDPT, ..base }, "estimator");
    for v in [2, 3, u32::MAX] {
        expect_error(&MsxParams { estimator: v, ..base }, "estimator");
    }
    for v in [MSX_MAX_BOUNCES_LIMIT + 1, 100_000, u32::MAX] {
        expect_error(&MsxParams { max_bounces: v, ..base }, "max_bounces");
    }
    for v in [0, 5, 16, u32::MAX] {
        expect_error(&MsxParams { channels: v, ..base }, "channels");
    }
    for v in [-0.5, 1.0, 3.0, f64::NAN, f64::INFINITY] {
        expect_error(&MsxParams { model: MSX_MODEL_AUTO, auto_tolerance: v, ..base }, "auto_tolerance");
    }
    for v in [4, 99, u32::MAX] {
        expect_error(&MsxParams { mis_density: v, ..base }, "mis_density");
    }
    // An explicit MIS density where it changes nothing (not a conductor walk) is refused by name.
    expect_error(&MsxParams { model: MSX_MODEL_SINGLE, mis_density: MSX_MIS_DENSITY_CUI, ..base }, "mis_density");
    expect_error(&MsxParams { surface: MSX_SURFACE_DIELECTRIC, mis_density: MSX_MIS_DENSITY_SINGLE_COSINE, ..base }, "mis_density");
    for mis_density in [MSX_MIS_DENSITY_DEFAULT, MSX_MIS_DENSITY_SINGLE_COSINE, MSX_MIS_DENSITY_CUI, MSX_MIS_DENSITY_CUI_TYPO] {
        new(&MsxParams { mis_density, ..base });
    }
    // sample_visible: 0 (visible normals) or 1 (all normals); a walk takes 1 too (it draws visible normals).
    for v in [2, 99, u32::MAX] {
        expect_error(&MsxParams { sample_all_normals: v, ..base }, "sample_visible");
    }
    for (model, surface) in
        [(MSX_MODEL_SINGLE, MSX_SURFACE_CONDUCTOR), (MSX_MODEL_SINGLE, MSX_SURFACE_DIELECTRIC), (MSX_MODEL_CORRELATED, MSX_SURFACE_CONDUCTOR)]
    {
        new(&MsxParams { model, surface, sample_all_normals: MSX_SAMPLE_ALL_NORMALS, ..base });
    }
    // The boundaries are accepted.
    for max_bounces in [0, 1, MSX_DEFAULT_MAX_BOUNCES, MSX_MAX_BOUNCES_LIMIT] {
        new(&MsxParams { max_bounces, ..base });
    }
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            for channels in 1..=MSX_MAX_CHANNELS {
                let h = new(&MsxParams { model, distribution: dist, channels, seed: u64::MAX, ..base });
                let m = material(0.4, 0.4, CU_ETA, CU_K);
                let ctx = || format!("model {model} dist {dist} channels {channels}");
                exercise(&h, channels as usize, &m, dir(0.5, 0.0), dir(0.7, 2.5), 3, &ctx);
                let e = msx_eval(h.0, &m, dir(0.5, 0.0), dir(0.7, 2.5), 3);
                assert!(e.v[..channels as usize].iter().all(|&x| x > 0.0), "{}: {e:?}", ctx());
            }
        }
    }
}

// ------------------------------------------------------------ random sweep

#[test]
fn random_sweep_all_outputs_finite_and_nonnegative() {
    let diag = msx_diagnostics();
    let mut rng = Rng(0x5eed_0001);
    let n_per_config = 3000;
    let mut valid_samples = 0usize;
    let mut total_samples = 0usize;
    let mut pdf_mismatch = Vec::new();
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            let h = new(&params(model, dist));
            for i in 0..n_per_config {
                let alpha = rng.log_uniform(1e-4, 4.0);
                let ratio = rng.log_uniform(1.0, 100.0);
                let (au, av) = if rng.f() < 0.5 { (alpha, alpha / ratio) } else { (alpha / ratio, alpha) };
                let (eta, k) = match i % 3 {
                    0 => ([0.0; 4], [1.0; 4]),
                    1 => (CU_ETA, CU_K),
                    _ => (std::array::from_fn(|_| rng.log_uniform(0.05, 5.0) as f32), std::array::from_fn(|_| rng.log_uniform(0.01, 10.0) as f32)),
                };
                let m = material(au as f32, av as f32, eta, k);
                let max_theta = std::f64::consts::FRAC_PI_2 - 1e-6;
                // Half of the directions uniform in θ, half crowded near grazing.
                let theta = |r: &mut Rng| if r.f() < 0.5 { r.range(0.0, max_theta) } else { max_theta - r.log_uniform(1e-6, 0.3) };
                let wi = dir(theta(&mut rng), rng.range(0.0, std::f64::consts::TAU));
                let wo = dir(theta(&mut rng), rng.range(0.0, std::f64::consts::TAU));
                let key = rng.next_u64();
                let ctx = || format!("model {model} dist {dist} α ({au}, {av}) wi {wi:?} wo {wo:?} key {key}");
                exercise(&h, 4, &m, wi, wo, key, &ctx);
                let (s1, u, v) = (rng.f() as f32, rng.f() as f32, rng.f() as f32);
                let s = no_panic("msx_sample", || msx_sample(h.0, &m, wi, s1, u, v));
                check_sample(&s, 4, &|| format!("{} sample ({s1}, {u}, {v})", ctx()));
                total_samples += 1;
                if s.valid == 1 {
                    valid_samples += 1;
                    // `pdf` must agree with the pdf that `sample` reports
                    // (docs/conventions.md), up to the float rounding of wo; only
                    // checked where that rounding cannot matter.
                    let p = msx_pdf(h.0, &m, wi, s.wo);
                    let smooth = au.min(av) >= 0.05 && wi.z > 0.2 && s.wo.z > 0.2;
                    if smooth && (p - s.pdf).abs() > 1e-3 * s.pdf.max(p) {
                        pdf_mismatch.push(format!("{} sample pdf {} vs msx_pdf {p}", ctx(), s.pdf));
                    }
                }
            }
        }
    }
    println!("random sweep: {valid_samples}/{total_samples} valid samples");
    assert!(valid_samples > total_samples / 2, "too few valid samples: {valid_samples}/{total_samples}");
    assert!(pdf_mismatch.is_empty(), "{} pdf mismatches, e.g.\n{}", pdf_mismatch.len(), pdf_mismatch[..pdf_mismatch.len().min(5)].join("\n"));
    common::assert_no_raw_defects(diag, "random_sweep_all_outputs_finite_and_nonnegative");
}

// ------------------------------------------------------------ determinism

#[test]
fn deterministic_in_inputs_seed_and_key() {
    let m = material(0.6, 0.4, CU_ETA, CU_K);
    let (wi, wo) = (dir(0.7, 0.2), dir(0.9, 2.4));
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            // Two independent handles with the same parameters.
            let a = new(&params(model, dist));
            let b = new(&params(model, dist));
            for key in [0u64, 1, 77, u64::MAX] {
                let ea = msx_eval(a.0, &m, wi, wo, key);
                let eb = msx_eval(b.0, &m, wi, wo, key);
                assert_eq!(ea.v.map(f32::to_bits), eb.v.map(f32::to_bits), "model {model} dist {dist} key {key}");
                let again = msx_eval(a.0, &m, wi, wo, key);
                assert_eq!(ea.v.map(f32::to_bits), again.v.map(f32::to_bits));
                let pa = msx_eval_pdf(a.0, &m, wi, wo, key);
                let pb = msx_eval_pdf(b.0, &m, wi, wo, key);
                assert_eq!((pa.value.v.map(f32::to_bits), pa.pdf.to_bits()), (pb.value.v.map(f32::to_bits), pb.pdf.to_bits()));
                let oa = msx_eval_orders(a.0, &m, wi, wo, key, 2, 5);
                let ob = msx_eval_orders(b.0, &m, wi, wo, key, 2, 5);
                assert_eq!(oa.v.map(f32::to_bits), ob.v.map(f32::to_bits));
            }
            for (s1, u, v) in [(0.1f32, 0.2f32, 0.3f32), (0.9, 0.5, 0.01)] {
                let sa = msx_sample(a.0, &m, wi, s1, u, v);
                let sb = msx_sample(b.0, &m, wi, s1, u, v);
                let bits = |s: &MsxSample| ([s.wo.x, s.wo.y, s.wo.z, s.pdf].map(f32::to_bits), s.weight.v.map(f32::to_bits), s.valid);
                assert_eq!(bits(&sa), bits(&sb), "model {model} dist {dist} sample");
            }

            // Different keys: the stochastic models give different estimates;
            // the single-scattering model is the same closed form for every key.
            let estimates: Vec<u32> = (0..64u64).map(|key| msx_eval(a.0, &m, wi, wo, key).v[0].to_bits()).collect();
            let distinct: HashSet<u32> = estimates.iter().copied().collect();
            if std::env::var_os("MSX_DEBUG_KEYS").is_some() {
                println!("model {model} dist {dist}: {:?}", estimates.iter().map(|&b| f32::from_bits(b)).collect::<Vec<_>>());
            }
            if model == MSX_MODEL_SINGLE {
                assert_eq!(distinct.len(), 1, "single scattering must not depend on the key");
            } else {
                // Most walks add nothing beyond the deterministic order-1 term
                // at α = 0.6, so only a minority of keys change the estimate.
                assert!(distinct.len() >= 4, "model {model} dist {dist}: only {} distinct estimates over 64 keys", distinct.len());
                // A different seed changes the estimate too.
                let c = new(&MsxParams { seed: 999, ..params(model, dist) });
                let differs = (0..16u64).any(|key| msx_eval(c.0, &m, wi, wo, key).v[0] != msx_eval(a.0, &m, wi, wo, key).v[0]);
                assert!(differs, "model {model} dist {dist}: the seed has no effect");
            }
        }
    }
}

// ------------------------------------------------------------ batches

/// A batch of n lanes whose every array is empty (the defaults).
fn empty_batch(n: usize, key: u64) -> MsxBatchIn {
    MsxBatchIn { n, key, ..Default::default() }
}

fn empty_out() -> MsxBatchOut {
    MsxBatchOut { value: [ptr::null_mut(); 4], pdf: ptr::null_mut(), wo: [ptr::null_mut(); 3] }
}

fn arr(v: &[f32]) -> MsxF32Array {
    MsxF32Array { ptr: v.as_ptr(), len: v.len() }
}

/// Per-lane inputs of a batch (structure of arrays).
struct Lanes {
    wi: [Vec<f32>; 3],
    wo: [Vec<f32>; 3],
    s1: Vec<f32>,
    s2: [Vec<f32>; 2],
    alpha_u: Vec<f32>,
    alpha_v: Vec<f32>,
}

impl Lanes {
    fn random(n: usize, rng: &mut Rng, with_bad: bool) -> Lanes {
        let mut l = Lanes { wi: Default::default(), wo: Default::default(), s1: vec![], s2: Default::default(), alpha_u: vec![], alpha_v: vec![] };
        for i in 0..n {
            let mut wi = dir(rng.range(0.0, 1.5707), rng.range(0.0, 6.28));
            let wo = dir(rng.range(0.0, 1.5707), rng.range(0.0, 6.28));
            if with_bad && i % 97 == 5 {
                wi.x = f32::NAN;
            }
            if with_bad && i % 89 == 3 {
                wi.z = -wi.z;
            }
            for (c, (a, b)) in [(wi.x, wo.x), (wi.y, wo.y), (wi.z, wo.z)].into_iter().enumerate() {
                l.wi[c].push(a);
                l.wo[c].push(b);
            }
            l.s1.push(rng.f() as f32);
            l.s2[0].push(rng.f() as f32);
            l.s2[1].push(rng.f() as f32);
            let a = rng.log_uniform(1e-3, 3.0) as f32;
            l.alpha_u.push(if with_bad && i % 101 == 7 { f32::NAN } else { a });
            l.alpha_v.push(a * rng.range(0.2, 1.0) as f32);
        }
        l
    }

    fn input(&self, n: usize, key: u64, eta: &[f32; 4], k: &[f32; 4]) -> MsxBatchIn {
        let mut b = empty_batch(n, key);
        for c in 0..3 {
            b.wi[c] = arr(&self.wi[c]);
            b.wo[c] = arr(&self.wo[c]);
        }
        b.sample1 = arr(&self.s1);
        b.sample2 = [arr(&self.s2[0]), arr(&self.s2[1])];
        b.alpha_u = arr(&self.alpha_u);
        b.alpha_v = arr(&self.alpha_v);
        // Broadcast (len 1) IOR; channel 3 left at its default.
        for c in 0..3 {
            b.eta[c] = MsxF32Array { ptr: &eta[c], len: 1 };
            b.k[c] = MsxF32Array { ptr: &k[c], len: 1 };
        }
        b
    }

    /// The material lane i sees (defaults for arrays not given).
    fn material(&self, i: usize, eta: &[f32; 4], k: &[f32; 4]) -> MsxMaterial {
        MsxMaterial {
            alpha_u: self.alpha_u[i],
            alpha_v: self.alpha_v[i],
            eta: [eta[0], eta[1], eta[2], 0.0],
            k: [k[0], k[1], k[2], 1.0],
            specular_reflectance: [1.0; 4],
            ..Default::default()
        }
    }

    fn wi(&self, i: usize) -> MsxVec3 {
        MsxVec3 { x: self.wi[0][i], y: self.wi[1][i], z: self.wi[2][i] }
    }
    fn wo(&self, i: usize) -> MsxVec3 {
        MsxVec3 { x: self.wo[0][i], y: self.wo[1][i], z: self.wo[2][i] }
    }
}

struct Outs {
    value: [Vec<f32>; 4],
    pdf: Vec<f32>,
    wo: [Vec<f32>; 3],
}

impl Outs {
    fn new(n: usize) -> Outs {
        // Poisoned with a negative value: every lane must be overwritten.
        Outs { value: std::array::from_fn(|_| vec![-1.0; n]), pdf: vec![-1.0; n], wo: std::array::from_fn(|_| vec![-1.0; n]) }
    }
    fn ptrs(&mut self) -> MsxBatchOut {
        MsxBatchOut {
            value: [0, 1, 2, 3].map(|c| self.value[c].as_mut_ptr()),
            pdf: self.pdf.as_mut_ptr(),
            wo: [0, 1, 2].map(|c| self.wo[c].as_mut_ptr()),
        }
    }
}

fn batch_equals_per_call(model: u32, dist: u32, n: usize, key: u64) {
    let h = new(&params(model, dist));
    let mut rng = Rng(n as u64 ^ key ^ (model as u64) << 8);
    let lanes = Lanes::random(n, &mut rng, true);
    let input = lanes.input(n, key, &CU_ETA, &CU_K);
    let mut err = [0 as c_char; 256];
    let ctx = format!("model {model} dist {dist} n {n}");

    // eval
    let mut o = Outs::new(n);
    assert_eq!(no_panic(&ctx, || msx_eval_batch(h.0, &input, &o.ptrs(), err.as_mut_ptr(), err.len())), MSX_OK, "{}", message(&err));
    for i in 0..n {
        let m = lanes.material(i, &CU_ETA, &CU_K);
        let e = msx_eval(h.0, &m, lanes.wi(i), lanes.wo(i), key.wrapping_add(i as u64));
        for c in 0..4 {
            assert_eq!(o.value[c][i].to_bits(), e.v[c].to_bits(), "{ctx} eval lane {i} channel {c}");
        }
        // "Each non-null pointer receives n floats": eval_batch writes pdf = 0.
        assert_eq!(o.pdf[i], 0.0, "{ctx}: eval_batch lane {i} pdf");
    }

    // pdf
    let mut o = Outs::new(n);
    assert_eq!(msx_pdf_batch(h.0, &input, &o.ptrs(), err.as_mut_ptr(), err.len()), MSX_OK);
    for i in 0..n {
        let m = lanes.material(i, &CU_ETA, &CU_K);
        assert_eq!(o.pdf[i].to_bits(), msx_pdf(h.0, &m, lanes.wi(i), lanes.wo(i)).to_bits(), "{ctx} pdf lane {i}");
    }

    // eval_pdf
    let mut o = Outs::new(n);
    assert_eq!(msx_eval_pdf_batch(h.0, &input, &o.ptrs(), err.as_mut_ptr(), err.len()), MSX_OK);
    for i in 0..n {
        let m = lanes.material(i, &CU_ETA, &CU_K);
        let e = msx_eval_pdf(h.0, &m, lanes.wi(i), lanes.wo(i), key.wrapping_add(i as u64));
        for c in 0..4 {
            assert_eq!(o.value[c][i].to_bits(), e.value.v[c].to_bits(), "{ctx} eval_pdf lane {i} channel {c}");
        }
        assert_eq!(o.pdf[i].to_bits(), e.pdf.to_bits(), "{ctx} eval_pdf lane {i} pdf");
    }

    // sample
    let mut o = Outs::new(n);
    assert_eq!(msx_sample_batch(h.0, &input, &o.ptrs(), err.as_mut_ptr(), err.len()), MSX_OK);
    for i in 0..n {
        let m = lanes.material(i, &CU_ETA, &CU_K);
        let s = msx_sample(h.0, &m, lanes.wi(i), lanes.s1[i], lanes.s2[0][i], lanes.s2[1][i]);
        let got = [o.wo[0][i], o.wo[1][i], o.wo[2][i], o.pdf[i]].map(f32::to_bits);
        assert_eq!(got, [s.wo.x, s.wo.y, s.wo.z, s.pdf].map(f32::to_bits), "{ctx} sample lane {i}");
        for c in 0..4 {
            assert_eq!(o.value[c][i].to_bits(), s.weight.v[c].to_bits(), "{ctx} sample lane {i} weight {c}");
        }
        for x in [o.pdf[i], o.value[0][i], o.value[1][i], o.value[2][i], o.value[3][i]] {
            assert!(ok_f(x), "{ctx} sample lane {i}: {x}");
        }
    }
}

#[test]
fn batches_equal_per_call_small() {
    let diag = msx_diagnostics();
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            batch_equals_per_call(model, dist, 1, 5);
            batch_equals_per_call(model, dist, 333, u64::MAX - 100); // key + i wraps
        }
    }
    common::assert_no_raw_defects(diag, "batches_equal_per_call_small");
}

#[test]
fn batches_equal_per_call_threaded() {
    let diag = msx_diagnostics();
    // Above 2 × 2048 lanes the batch is split over worker threads (when the
    // machine has more than one core); lane i must still use key + i.
    for model in MODELS {
        batch_equals_per_call(model, MSX_DISTRIBUTION_GGX, 4096 * 2 + 123, 42);
    }
    batch_equals_per_call(MSX_MODEL_CORRELATED, MSX_DISTRIBUTION_BECKMANN, 5000, 7);
    common::assert_no_raw_defects(diag, "batches_equal_per_call_threaded");
}

#[test]
fn batch_length_mismatch_is_an_error() {
    let h = new(&params(MSX_MODEL_UNCORRELATED, MSX_DISTRIBUTION_GGX));
    let n = 10;
    let mut rng = Rng(3);
    let lanes = Lanes::random(n, &mut rng, false);
    let good = lanes.input(n, 0, &CU_ETA, &CU_K);
    let short = vec![0.5f32; n - 1];
    let long = vec![0.5f32; n + 1];
    let two = [0.5f32; 2];
    type BatchFn = extern "C" fn(*const MsxBsdf, *const MsxBatchIn, *const MsxBatchOut, *mut c_char, usize) -> i32;
    let fns: [(&str, BatchFn); 4] =
        [("eval", msx_eval_batch), ("pdf", msx_pdf_batch), ("eval_pdf", msx_eval_pdf_batch), ("sample", msx_sample_batch)];
    let cases: Vec<(&str, Box<dyn Fn(&mut MsxBatchIn, MsxF32Array)>)> = vec![
        ("wi.x", Box::new(|b, a| b.wi[0] = a)),
        ("wi.z", Box::new(|b, a| b.wi[2] = a)),
        ("wo.y", Box::new(|b, a| b.wo[1] = a)),
        ("sample1", Box::new(|b, a| b.sample1 = a)),
        ("sample2.y", Box::new(|b, a| b.sample2[1] = a)),
        ("alpha_u", Box::new(|b, a| b.alpha_u = a)),
        ("alpha_v", Box::new(|b, a| b.alpha_v = a)),
        ("eta", Box::new(|b, a| b.eta[3] = a)),
        ("k", Box::new(|b, a| b.k[1] = a)),
        ("specular_reflectance", Box::new(|b, a| b.specular_reflectance[0] = a)),
    ];
    for (fname, f) in fns {
        for (name, set) in &cases {
            for bad in [arr(&short), arr(&long), arr(&two)] {
                let mut input = good;
                set(&mut input, bad);
                let mut o = Outs::new(n);
                let mut err = [0 as c_char; 256];
                let rc = no_panic(fname, || f(h.0, &input, &o.ptrs(), err.as_mut_ptr(), err.len()));
                let msg = message(&err);
                assert_eq!(rc, MSX_ERR_INVALID_PARAMETER, "{fname} {name} len {}: {msg}", bad.len);
                assert!(msg.contains(&format!("'{name}'")), "{fname}: message must name '{name}': {msg}");
                assert!(o.value[0].iter().all(|&x| x == -1.0), "{fname} {name}: nothing may be written on error");
            }
        }
        // The unmodified input is fine.
        let mut o = Outs::new(n);
        assert_eq!(f(h.0, &good, &o.ptrs(), ptr::null_mut(), 0), MSX_OK, "{fname}");
    }
}

// ------------------------------------------------------------ eval_pdf

/// `msx_eval_pdf` is `msx_eval` and `msx_pdf` in one call: the same values
/// (bit for bit, same key), whatever shortcut it takes.
#[test]
fn eval_pdf_equals_eval_and_pdf() {
    let diag = msx_diagnostics();
    let mut rng = Rng(0x5eed_0002);
    for model in MODELS {
        for dist in DISTRIBUTIONS {
            let h = new(&params(model, dist));
            for i in 0..400 {
                let a = rng.log_uniform(0.01, 2.0) as f32;
                let m = material(a, a * rng.range(0.5, 1.0) as f32, CU_ETA, CU_K);
                let wi = dir(rng.range(0.0, 1.5), rng.range(0.0, 6.28));
                let wo = dir(rng.range(0.0, 1.5), rng.range(0.0, 6.28));
                let key = i as u64;
                let both = msx_eval_pdf(h.0, &m, wi, wo, key);
                let (v, p) = (msx_eval(h.0, &m, wi, wo, key), msx_pdf(h.0, &m, wi, wo));
                assert_eq!((both.value.v, both.pdf), (v.v, p), "model {model} dist {dist} wi {wi:?} wo {wo:?}");
            }
        }
    }
    common::assert_no_raw_defects(diag, "eval_pdf_equals_eval_and_pdf");
}
