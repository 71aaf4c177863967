//! The batched calls: structure-of-arrays inputs and outputs, lanes run over
//! threads, each lane as the single call would compute it.

use super::handles::{msx_call_key, MsxBsdf};
use super::output::{out_f32, out_sample, out_spectrum};
use super::params::*;
use super::{report_panic, write_error, MSX_ERR_INVALID_PARAMETER, MSX_ERR_NULL_POINTER, MSX_OK};
use crate::bsdf::{Bsdf, Material};
use crate::spectrum::Spectrum;
use glam::DVec3;
use std::os::raw::c_char;
use std::panic::{catch_unwind, AssertUnwindSafe};

/// A read-only float array of length `len`: either the batch size n (one value
/// per lane) or 1 (broadcast). `len = 0` or a null pointer selects the default.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxF32Array {
    pub ptr: *const f32,
    pub len: usize,
}

/// Inputs of the batched calls (structure of arrays).
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxBatchIn {
    pub n: usize,
    pub wi: [MsxF32Array; 3],
    /// Unused by `msx_sample_batch`
    pub wo: [MsxF32Array; 3],
    /// Used by `msx_sample_batch` only
    pub sample1: MsxF32Array,
    /// Used by `msx_sample_batch` only
    pub sample2: [MsxF32Array; 2],
    pub alpha_u: MsxF32Array,
    pub alpha_v: MsxF32Array,
    pub eta: [MsxF32Array; 4],
    pub k: [MsxF32Array; 4],
    pub specular_reflectance: [MsxF32Array; 4],
    pub ior: MsxF32Array,
    pub specular_transmittance: [MsxF32Array; 4],
    pub reflectance: [MsxF32Array; 4],
    /// MSX_MODE_RADIANCE or MSX_MODE_IMPORTANCE, for every lane
    pub mode: u32,
    /// Lane i uses key + i (see `msx_eval`), or, when `p` is given,
    /// msx_call_key(p_i, uv_i) + key
    pub key: u64,
    /// Optional hit position per lane (with `uv`): derives each lane's key from
    /// where the call happens, so that a render does not depend on the order
    /// of the lanes
    pub p: [MsxF32Array; 3],
    /// Optional hit uv per lane (see `p`)
    pub uv: [MsxF32Array; 2],
}

impl Default for MsxF32Array {
    fn default() -> Self {
        MsxF32Array { ptr: std::ptr::null(), len: 0 }
    }
}

impl Default for MsxBatchIn {
    /// n = 0 and every array empty (defaults).
    fn default() -> Self {
        let e = MsxF32Array::default();
        MsxBatchIn {
            n: 0,
            wi: [e; 3],
            wo: [e; 3],
            sample1: e,
            sample2: [e; 2],
            alpha_u: e,
            alpha_v: e,
            eta: [e; 4],
            k: [e; 4],
            specular_reflectance: [e; 4],
            ior: e,
            specular_transmittance: [e; 4],
            reflectance: [e; 4],
            mode: MSX_MODE_RADIANCE,
            key: 0,
            p: [e; 3],
            uv: [e; 2],
        }
    }
}

/// Outputs of the batched calls; each non-null pointer receives n floats.
/// Null pointers are skipped.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct MsxBatchOut {
    /// eval / eval_pdf: f·|cos θ_o|; sample: weight. One array per channel.
    pub value: [*mut f32; 4],
    pub pdf: *mut f32,
    /// sample only
    pub wo: [*mut f32; 3],
}

#[derive(Clone, Copy)]
enum Op {
    /// `eval` restricted to the scattering orders first..=last (all: 1..=u32::MAX).
    Eval(u32, u32),
    Pdf,
    EvalPdf,
    Sample,
    /// `sample`, also writing each lane's scattering order (u32) at this address.
    SampleOrders(usize),
}

/// One input array (or its default), read lane by lane.
struct Reader {
    ptr: *const f32,
    len: usize,
    default: f32,
}

impl Reader {
    #[inline]
    fn get(&self, i: usize) -> f32 {
        // SAFETY: `reader` checked that len is 1 or n and the caller promises
        // `len` readable floats at `ptr`; i < n.
        match self.len {
            0 => self.default,
            1 => unsafe { *self.ptr },
            _ => unsafe { *self.ptr.add(i) },
        }
    }
}

// SAFETY: a Reader only reads caller-owned memory that outlives the batch call.
unsafe impl Sync for Reader {}

fn reader(a: &MsxF32Array, n: usize, default: f32, name: &'static str) -> Result<Reader, String> {
    if a.ptr.is_null() || a.len == 0 {
        return Ok(Reader { ptr: std::ptr::null(), len: 0, default });
    }
    if a.len != 1 && a.len != n {
        return Err(format!("array '{name}' has length {} (expected 1 or n = {n})", a.len));
    }
    Ok(Reader { ptr: a.ptr, len: a.len, default })
}

struct Inputs {
    /// Hit position and uv per lane, if given.
    at: Option<([Reader; 3], [Reader; 2])>,
    wi: [Reader; 3],
    wo: [Reader; 3],
    s1: Reader,
    s2: [Reader; 2],
    alpha_u: Reader,
    alpha_v: Reader,
    eta: [Reader; 4],
    k: [Reader; 4],
    spec: [Reader; 4],
    ior: Reader,
    spec_t: [Reader; 4],
    refl: [Reader; 4],
    radiance: bool,
}

fn inputs(b: &MsxBatchIn) -> Result<Inputs, String> {
    let n = b.n;
    let r = |a: &MsxF32Array, d: f32, name| reader(a, n, d, name);
    // The four channels of a per-channel input, one name for all of them.
    let r4 = |a: &[MsxF32Array; 4], d: f32, name: &'static str| -> Result<[Reader; 4], String> {
        Ok([r(&a[0], d, name)?, r(&a[1], d, name)?, r(&a[2], d, name)?, r(&a[3], d, name)?])
    };
    let alpha_u = r(&b.alpha_u, 0.1, "alpha_u")?;
    let alpha_v = if b.alpha_v.ptr.is_null() || b.alpha_v.len == 0 { r(&b.alpha_u, 0.1, "alpha_u")? } else { r(&b.alpha_v, 0.1, "alpha_v")? };
    let given = |a: &MsxF32Array| !a.ptr.is_null() && a.len > 0;
    let at = if given(&b.p[0]) {
        Some(([r(&b.p[0], 0.0, "p.x")?, r(&b.p[1], 0.0, "p.y")?, r(&b.p[2], 0.0, "p.z")?], [r(&b.uv[0], 0.0, "uv.x")?, r(&b.uv[1], 0.0, "uv.y")?]))
    } else {
        None
    };
    Ok(Inputs {
        at,
        wi: [r(&b.wi[0], 0.0, "wi.x")?, r(&b.wi[1], 0.0, "wi.y")?, r(&b.wi[2], 1.0, "wi.z")?],
        wo: [r(&b.wo[0], 0.0, "wo.x")?, r(&b.wo[1], 0.0, "wo.y")?, r(&b.wo[2], 1.0, "wo.z")?],
        s1: r(&b.sample1, 0.5, "sample1")?,
        s2: [r(&b.sample2[0], 0.5, "sample2.x")?, r(&b.sample2[1], 0.5, "sample2.y")?],
        alpha_u,
        alpha_v,
        eta: r4(&b.eta, 0.0, "eta")?,
        k: r4(&b.k, 1.0, "k")?,
        spec: r4(&b.specular_reflectance, 1.0, "specular_reflectance")?,
        ior: r(&b.ior, MSX_DEFAULT_IOR as f32, "ior")?,
        spec_t: r4(&b.specular_transmittance, 1.0, "specular_transmittance")?,
        refl: r4(&b.reflectance, 0.5, "reflectance")?,
        radiance: b.mode != MSX_MODE_IMPORTANCE,
    })
}

impl Inputs {
    fn material(&self, i: usize) -> Material {
        let ch = |r: &[Reader; 4]| Spectrum(std::array::from_fn(|c| r[c].get(i) as f64));
        Material {
            alpha_u: self.alpha_u.get(i) as f64,
            alpha_v: self.alpha_v.get(i) as f64,
            eta: ch(&self.eta),
            k: ch(&self.k),
            specular_reflectance: ch(&self.spec),
            ior: self.ior.get(i) as f64,
            specular_transmittance: ch(&self.spec_t),
            reflectance: ch(&self.refl),
            radiance: self.radiance,
        }
    }

    /// `sample1` and `sample2` of lane i.
    fn sample_numbers(&self, i: usize) -> (f64, (f64, f64)) {
        (self.s1.get(i) as f64, (self.s2[0].get(i) as f64, self.s2[1].get(i) as f64))
    }

    fn dir(r: &[Reader; 3], i: usize) -> DVec3 {
        DVec3::new(r[0].get(i) as f64, r[1].get(i) as f64, r[2].get(i) as f64)
    }
}

/// Output pointers as addresses, so that lanes can be written from worker threads.
#[derive(Clone, Copy)]
struct OutPtrs {
    value: [usize; 4],
    pdf: usize,
    wo: [usize; 3],
}

impl OutPtrs {
    /// SAFETY: `i` < n and each non-null pointer holds n floats; lanes are
    /// written by exactly one thread.
    unsafe fn put(p: usize, i: usize, v: f32) {
        if p != 0 {
            *(p as *mut f32).add(i) = v;
        }
    }
}

fn run_lane(b: &Bsdf, inp: &Inputs, out: OutPtrs, key: u64, op: Op, i: usize) {
    let channels = b.config().channels;
    let mat = inp.material(i);
    let wi = Inputs::dir(&inp.wi, i);
    let lane_key = match &inp.at {
        Some((p, uv)) => msx_call_key(p[0].get(i), p[1].get(i), p[2].get(i), uv[0].get(i), uv[1].get(i)).wrapping_add(key),
        None => key.wrapping_add(i as u64),
    };
    let (value, pdf, wo) = match op {
        Op::Eval(first, last) => (out_spectrum(b.eval_orders(&mat, wi, Inputs::dir(&inp.wo, i), lane_key, (first, last)), channels), 0.0, [0.0; 3]),
        Op::Pdf => (MsxSpectrum::default(), out_f32(b.pdf(&mat, wi, Inputs::dir(&inp.wo, i))), [0.0; 3]),
        Op::EvalPdf => {
            let (v, p) = b.eval_pdf(&mat, wi, Inputs::dir(&inp.wo, i), lane_key);
            (out_spectrum(v, channels), out_f32(p), [0.0; 3])
        }
        Op::Sample => {
            let (s1, s2) = inp.sample_numbers(i);
            let s = out_sample(b.sample(&mat, wi, s1, s2), channels);
            (s.weight, s.pdf, [s.wo.x, s.wo.y, s.wo.z])
        }
        Op::SampleOrders(orders) => {
            let (s1, s2) = inp.sample_numbers(i);
            let r = b.sample_with_order(&mat, wi, s1, s2);
            let order = r.as_ref().map_or(0, |&(_, k)| k);
            let s = out_sample(r.map(|(s, _)| s), channels);
            // SAFETY: msx_sample_orders_batch checked `orders` non-null; the
            // caller promises n u32 there; lane i is written by one thread.
            unsafe { *(orders as *mut u32).add(i) = if s.valid == 1 { order } else { 0 } };
            (s.weight, s.pdf, [s.wo.x, s.wo.y, s.wo.z])
        }
    };
    // SAFETY: see OutPtrs::put.
    unsafe {
        for (&p, &x) in out.value.iter().zip(value.v.iter()) {
            OutPtrs::put(p, i, x);
        }
        OutPtrs::put(out.pdf, i, pdf);
        for (&p, &x) in out.wo.iter().zip(wo.iter()) {
            OutPtrs::put(p, i, x);
        }
    }
}

/// Lanes per worker thread below which a batch runs on the calling thread.
const LANES_PER_THREAD: usize = 2048;

fn run_batch(bsdf: *const MsxBsdf, input: *const MsxBatchIn, output: *const MsxBatchOut, op: Op, err: *mut c_char, err_len: usize) -> i32 {
    let result = catch_unwind(AssertUnwindSafe(|| {
        if bsdf.is_null() || input.is_null() || output.is_null() {
            write_error(err, err_len, "null pointer passed to a batched call");
            return MSX_ERR_NULL_POINTER;
        }
        // SAFETY: checked non-null; the caller owns the structs for the call.
        let (b, bin, bout) = unsafe { (&(*bsdf).bsdf, &*input, &*output) };
        let inp = match inputs(bin) {
            Ok(i) => i,
            Err(msg) => {
                write_error(err, err_len, &msg);
                return MSX_ERR_INVALID_PARAMETER;
            }
        };
        let out = OutPtrs { value: bout.value.map(|p| p as usize), pdf: bout.pdf as usize, wo: bout.wo.map(|p| p as usize) };
        let (n, key) = (bin.n, bin.key);
        let threads = std::thread::available_parallelism().map(|t| t.get()).unwrap_or(1).min(n / LANES_PER_THREAD).max(1);
        if threads == 1 {
            for i in 0..n {
                run_lane(b, &inp, out, key, op, i);
            }
        } else {
            let chunk = n.div_ceil(threads);
            std::thread::scope(|s| {
                for t in 0..threads {
                    let inp = &inp;
                    s.spawn(move || {
                        for i in (t * chunk)..((t + 1) * chunk).min(n) {
                            run_lane(b, inp, out, key, op, i);
                        }
                    });
                }
            });
        }
        MSX_OK
    }));
    result.unwrap_or_else(|_| report_panic(err, err_len, "a batched call"))
}

/// Batched `msx_eval`: writes `value` (per channel) for n lanes.
#[no_mangle]
pub extern "C" fn msx_eval_batch(
    bsdf: *const MsxBsdf,
    input: *const MsxBatchIn,
    output: *const MsxBatchOut,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    run_batch(bsdf, input, output, Op::Eval(1, u32::MAX), err, err_len)
}

/// Batched `msx_eval_orders`: writes `value` (per channel) for n lanes,
/// restricted to the scattering orders first..=last (1 = single scattering).
#[no_mangle]
pub extern "C" fn msx_eval_orders_batch(
    bsdf: *const MsxBsdf,
    input: *const MsxBatchIn,
    first: u32,
    last: u32,
    output: *const MsxBatchOut,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    run_batch(bsdf, input, output, Op::Eval(first, last), err, err_len)
}

/// Batched `msx_pdf`: writes `pdf` for n lanes.
#[no_mangle]
pub extern "C" fn msx_pdf_batch(bsdf: *const MsxBsdf, input: *const MsxBatchIn, output: *const MsxBatchOut, err: *mut c_char, err_len: usize) -> i32 {
    run_batch(bsdf, input, output, Op::Pdf, err, err_len)
}

/// Batched `msx_eval_pdf`: writes `value` and `pdf` for n lanes.
#[no_mangle]
pub extern "C" fn msx_eval_pdf_batch(
    bsdf: *const MsxBsdf,
    input: *const MsxBatchIn,
    output: *const MsxBatchOut,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    run_batch(bsdf, input, output, Op::EvalPdf, err, err_len)
}

/// Batched `msx_sample`: writes `wo`, `pdf` and `value` (= weight) for n
/// lanes; an invalid sample has pdf 0 and zero weight.
#[no_mangle]
pub extern "C" fn msx_sample_batch(
    bsdf: *const MsxBsdf,
    input: *const MsxBatchIn,
    output: *const MsxBatchOut,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    run_batch(bsdf, input, output, Op::Sample, err, err_len)
}

/// Batched `msx_sample` that also writes each lane's scattering order into
/// `orders` (n values): the number of microfacet events of the sampled path,
/// 1 for the analytic models (their whole lobe is order 1, as in
/// `msx_eval_orders`), 0 for an invalid sample. Weights binned by order
/// estimate each order's lobe and energy.
#[no_mangle]
pub extern "C" fn msx_sample_orders_batch(
    bsdf: *const MsxBsdf,
    input: *const MsxBatchIn,
    output: *const MsxBatchOut,
    orders: *mut u32,
    err: *mut c_char,
    err_len: usize,
) -> i32 {
    if orders.is_null() {
        write_error(err, err_len, "null pointer passed to msx_sample_orders_batch (orders)");
        return MSX_ERR_NULL_POINTER;
    }
    run_batch(bsdf, input, output, Op::SampleOrders(orders as usize), err, err_len)
}
