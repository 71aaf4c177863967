//! Fuzz test of the C ABI: random and adversarial configurations, materials
//! (NaN/Inf/negative/huge values standing for broken textures, α from 0 to
//! 1e5, IORs around 1 and far from it), directions (NaN, Inf, zero, not unit
//! length, exactly vertical or horizontal, below the horizon, grazing) and
//! sample values, through every entry point (per call and batched).
//!
//! What is asserted is the raw count: `msx_diagnostics` counts every output
//! value the ABI had to clean (non-finite or negative) and every panic it
//! caught, so a defect in the core cannot hide behind the ABI's sanitising.
//! It must stay 0. Outputs are also checked to be finite and non-negative.
//!
//! Calls: `MSX_FUZZ_CALLS` (default 1 000 000, the CI run); the long run of
//! docs/testing.md sets 100 000 000. Fixed seeds: the run is reproducible.

mod common;

use common::Rng;
use msx::ffi::*;
use std::ptr;

const SPECIAL: [f32; 14] =
    [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 0.0, -0.0, -1.0, 1.0, f32::MAX, f32::MIN_POSITIVE, 1e-45, 1e30, 1e-30, 0.999_999_94, 1.000_000_1];

/// A value that is usually plausible (log-uniform in [lo, hi]) and sometimes adversarial.
fn value(rng: &mut Rng, lo: f64, hi: f64) -> f32 {
    if rng.f() < 0.12 {
        rng.pick(&SPECIAL)
    } else {
        rng.log_uniform(lo, hi) as f32
    }
}

fn direction(rng: &mut Rng) -> MsxVec3 {
    let r = rng.f();
    if r < 0.06 {
        let s = rng.pick(&SPECIAL);
        let (a, b) = (rng.pick(&[0.0f32, 0.5, -0.3, 1.0]), rng.pick(&[1.0f32, -1.0, 0.0, 0.2]));
        return match rng.below(3) {
            0 => MsxVec3 { x: s, y: a, z: b },
            1 => MsxVec3 { x: a, y: s, z: b },
            _ => MsxVec3 { x: a, y: b, z: s },
        };
    }
    if r < 0.12 {
        return rng.pick(&[
            MsxVec3 { x: 0.0, y: 0.0, z: 1.0 },
            MsxVec3 { x: 0.0, y: 0.0, z: -1.0 },
            MsxVec3 { x: 1.0, y: 0.0, z: 0.0 },
            MsxVec3 { x: 0.0, y: -1.0, z: 0.0 },
            MsxVec3 { x: 0.0, y: 0.0, z: 0.0 },
            MsxVec3 { x: 1e-30, y: 0.0, z: 1e-30 },
            MsxVec3 { x: 1e30, y: 1e30, z: 1e30 },
            MsxVec3 { x: 0.6, y: 0.8, z: 1e-7 },
            MsxVec3 { x: 0.6, y: 0.8, z: -1e-7 },
            MsxVec3 { x: 1e-7, y: 0.0, z: 1.0 },
        ]);
    }
    // Uniform on the sphere, half of them crowded towards the horizon.
    let z = if rng.f() < 0.5 { rng.f() * 2.0 - 1.0 } else { rng.log_uniform(1e-7, 0.2) * if rng.f() < 0.5 { 1.0 } else { -1.0 } };
    let phi = rng.f() * std::f64::consts::TAU;
    let s = (1.0 - z * z).max(0.0).sqrt();
    let scale = if rng.f() < 0.05 { rng.log_uniform(1e-3, 1e3) } else { 1.0 };
    MsxVec3 { x: (scale * s * phi.cos()) as f32, y: (scale * s * phi.sin()) as f32, z: (scale * z) as f32 }
}

fn material(rng: &mut Rng) -> MsxMaterial {
    let alpha = value(rng, 1e-6, 1e5);
    let alpha_v = if rng.f() < 0.5 { alpha } else { value(rng, 1e-6, 1e5) };
    let ch = |rng: &mut Rng, lo: f64, hi: f64| -> [f32; 4] { std::array::from_fn(|_| value(rng, lo, hi)) };
    let ior = if rng.f() < 0.1 { rng.pick(&[1.0f32, 1.000_000_1, 0.999_999_94, 1e-6, 1e6]) } else { value(rng, 0.2, 5.0) };
    MsxMaterial {
        alpha_u: alpha,
        alpha_v,
        eta: ch(rng, 0.01, 20.0),
        k: ch(rng, 0.001, 20.0),
        specular_reflectance: ch(rng, 0.01, 2.0),
        ior,
        specular_transmittance: ch(rng, 0.01, 2.0),
        reflectance: ch(rng, 0.01, 1.0),
        mode: if rng.f() < 0.5 { MSX_MODE_RADIANCE } else { MSX_MODE_IMPORTANCE },
    }
}

struct Handle(*mut MsxBsdf, u32, MsxParams);

impl Drop for Handle {
    fn drop(&mut self) {
        msx_bsdf_free(self.0);
    }
}

/// Random configurations (every surface × distribution × model × estimator
/// the library accepts, random channels, bounce caps, seeds and tolerances).
/// Invalid combinations must be refused with an error code, never crash.
fn handles(rng: &mut Rng, n: usize) -> Vec<Handle> {
    let models = [
        MSX_MODEL_SINGLE,
        MSX_MODEL_UNCORRELATED,
        MSX_MODEL_CORRELATED,
        MSX_MODEL_HEITZ,
        MSX_MODEL_INVARIANCE,
        MSX_MODEL_FASTMSX,
        MSX_MODEL_COMPENSATED,
        MSX_MODEL_AUTO,
    ];
    let mut out = Vec::new();
    let mut err = [0 as std::os::raw::c_char; 256];
    while out.len() < n {
        let p = MsxParams {
            surface: rng.pick(&[MSX_SURFACE_CONDUCTOR, MSX_SURFACE_DIELECTRIC, MSX_SURFACE_DIFFUSE]),
            distribution: rng.pick(&[MSX_DISTRIBUTION_BECKMANN, MSX_DISTRIBUTION_GGX]),
            model: rng.pick(&models),
            estimator: rng.pick(&[MSX_ESTIMATOR_PT, MSX_ESTIMATOR_BDPT]),
            max_bounces: if rng.f() < 0.7 { 0 } else { 1 + rng.below(64) as u32 },
            channels: 1 + rng.below(4) as u32,
            seed: rng.next_u64(),
            auto_tolerance: if rng.f() < 0.5 { 0.0 } else { rng.log_uniform(1e-4, 0.9) },
            mis_density: if rng.f() < 0.5 { 0 } else { rng.below(5) as u32 },
            sample_all_normals: if rng.f() < 0.7 { 0 } else { rng.below(3) as u32 },
        };
        let mut h: *mut MsxBsdf = ptr::null_mut();
        if msx_bsdf_new(&p, &mut h, err.as_mut_ptr(), err.len()) == MSX_OK {
            out.push(Handle(h, p.channels, p));
        } else {
            assert!(h.is_null(), "a refused configuration returned a handle: {p:?}");
        }
    }
    out
}

fn ok(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

fn check(what: &str, values: &[f32]) {
    assert!(values.iter().all(|&x| ok(x)), "{what}: output {values:?} is not finite and non-negative");
}

/// `calls` random ABI calls with the generator seeded by `seed`; returns the
/// calls after which the diagnostic counters grew (suspects, for the report).
fn fuzz(seed: u64, calls: usize) -> Vec<String> {
    let mut defects = Vec::new();
    let mut rng = Rng(seed);
    let pool = handles(&mut rng, 64);
    let mut done = 0usize;
    let lanes = 256;
    while done < calls {
        let h = &pool[rng.below(pool.len())];
        let m = material(&mut rng);
        let wi = direction(&mut rng);
        let wo = direction(&mut rng);
        let key = rng.next_u64();
        let before = msx_diagnostics();
        let op = rng.below(6);
        match op {
            0 => check("msx_eval", &msx_eval(h.0, &m, wi, wo, key).v),
            1 => check("msx_pdf", &[msx_pdf(h.0, &m, wi, wo)]),
            2 => {
                let r = msx_eval_pdf(h.0, &m, wi, wo, key);
                check("msx_eval_pdf", &[r.value.v[0], r.value.v[1], r.value.v[2], r.value.v[3], r.pdf]);
            }
            3 => {
                let (first, last) = (rng.below(5) as u32, rng.below(70) as u32);
                check("msx_eval_orders", &msx_eval_orders(h.0, &m, wi, wo, key, first, last).v);
            }
            4 => {
                let s = msx_sample(h.0, &m, wi, value(&mut rng, 1e-9, 1.0), value(&mut rng, 1e-9, 1.0), value(&mut rng, 1e-9, 1.0));
                check("msx_sample", &[s.pdf, s.weight.v[0], s.weight.v[1], s.weight.v[2], s.weight.v[3]]);
                if s.valid == 1 {
                    assert!(s.pdf > 0.0 && [s.wo.x, s.wo.y, s.wo.z].iter().all(|v| v.is_finite()), "valid sample {s:?}");
                }
            }
            _ => {
                batch(&mut rng, h, lanes);
                done += lanes - 1;
            }
        }
        done += 1;
        let after = msx_diagnostics();
        if after.nonfinite + after.negative + after.panics > before.nonfinite + before.negative + before.panics && defects.len() < 20 {
            // Other threads may have counted too: a listed call is a suspect, re-run it alone to confirm.
            defects.push(format!("op {op} {:?} material {m:?} wi {wi:?} wo {wo:?} key {key}", h.2));
        }
    }
    defects
}

/// One batched call (eval, pdf, eval_pdf or sample) over `n` lanes with per-lane random inputs.
fn batch(rng: &mut Rng, h: &Handle, n: usize) {
    let before = msx_diagnostics();
    let dirs: Vec<(MsxVec3, MsxVec3)> = (0..n).map(|_| (direction(rng), direction(rng))).collect();
    let mats: Vec<MsxMaterial> = (0..n).map(|_| material(rng)).collect();
    let samples: Vec<[f32; 3]> = (0..n).map(|_| std::array::from_fn(|_| value(rng, 1e-9, 1.0))).collect();
    // Structure of arrays: one column per input, referenced by index.
    let mut cols: Vec<Vec<f32>> = Vec::new();
    let mut push = |v: Vec<f32>| {
        cols.push(v);
        cols.len() - 1
    };
    let xyz = |v: &MsxVec3, c: usize| [v.x, v.y, v.z][c];
    let wi: [usize; 3] = std::array::from_fn(|c| push(dirs.iter().map(|d| xyz(&d.0, c)).collect()));
    let wo: [usize; 3] = std::array::from_fn(|c| push(dirs.iter().map(|d| xyz(&d.1, c)).collect()));
    let s1 = push(samples.iter().map(|s| s[0]).collect());
    let s2: [usize; 2] = std::array::from_fn(|c| push(samples.iter().map(|s| s[1 + c]).collect()));
    let au = push(mats.iter().map(|m| m.alpha_u).collect());
    let av = push(mats.iter().map(|m| m.alpha_v).collect());
    let eta: [usize; 4] = std::array::from_fn(|c| push(mats.iter().map(|m| m.eta[c]).collect()));
    let kk: [usize; 4] = std::array::from_fn(|c| push(mats.iter().map(|m| m.k[c]).collect()));
    let sr: [usize; 4] = std::array::from_fn(|c| push(mats.iter().map(|m| m.specular_reflectance[c]).collect()));
    let ior = push(mats.iter().map(|m| m.ior).collect());
    let st: [usize; 4] = std::array::from_fn(|c| push(mats.iter().map(|m| m.specular_transmittance[c]).collect()));
    let refl: [usize; 4] = std::array::from_fn(|c| push(mats.iter().map(|m| m.reflectance[c]).collect()));
    let with_position = rng.f() < 0.5;
    let pos: [usize; 3] = std::array::from_fn(|_| push((0..n).map(|_| value(rng, 1e-3, 1e3)).collect()));
    let uv: [usize; 2] = std::array::from_fn(|_| push((0..n).map(|_| value(rng, 1e-6, 1.0)).collect()));
    let arr = |i: usize| MsxF32Array { ptr: cols[i].as_ptr(), len: n };
    let input = MsxBatchIn {
        n,
        wi: wi.map(arr),
        wo: wo.map(arr),
        sample1: arr(s1),
        sample2: s2.map(arr),
        alpha_u: arr(au),
        alpha_v: arr(av),
        eta: eta.map(arr),
        k: kk.map(arr),
        specular_reflectance: sr.map(arr),
        ior: arr(ior),
        specular_transmittance: st.map(arr),
        reflectance: refl.map(arr),
        mode: if rng.f() < 0.5 { MSX_MODE_RADIANCE } else { MSX_MODE_IMPORTANCE },
        key: rng.next_u64(),
        // Half of the batches derive their lane keys from (adversarial) hit positions.
        p: if with_position { pos.map(arr) } else { Default::default() },
        uv: if with_position { uv.map(arr) } else { Default::default() },
    };
    let mut out: Vec<Vec<f32>> = (0..8).map(|_| vec![f32::NAN; n]).collect();
    let p = |v: &mut Vec<f32>| v.as_mut_ptr();
    let (value_cols, rest) = out.split_at_mut(4);
    let (pdf_col, wo_cols) = rest.split_at_mut(1);
    let output = MsxBatchOut {
        value: [p(&mut value_cols[0]), p(&mut value_cols[1]), p(&mut value_cols[2]), p(&mut value_cols[3])],
        pdf: p(&mut pdf_col[0]),
        wo: [p(&mut wo_cols[0]), p(&mut wo_cols[1]), p(&mut wo_cols[2])],
    };
    let mut err = [0 as std::os::raw::c_char; 256];
    let op = rng.below(4);
    let rc = match op {
        0 => msx_eval_batch(h.0, &input, &output, err.as_mut_ptr(), err.len()),
        1 => msx_pdf_batch(h.0, &input, &output, err.as_mut_ptr(), err.len()),
        2 => msx_eval_pdf_batch(h.0, &input, &output, err.as_mut_ptr(), err.len()),
        _ => msx_sample_batch(h.0, &input, &output, err.as_mut_ptr(), err.len()),
    };
    assert_eq!(rc, MSX_OK, "batched call {op} failed");
    let after = msx_diagnostics();
    if after.nonfinite + after.negative > before.nonfinite + before.negative {
        // Find the lanes: re-run each one alone through the per-call entry point.
        for i in 0..n {
            let b0 = msx_diagnostics();
            let mut m = mats[i];
            m.mode = input.mode;
            let (wi, wo) = dirs[i];
            match op {
                0 | 2 => {
                    msx_eval_pdf(h.0, &m, wi, wo, input.key.wrapping_add(i as u64));
                }
                1 => {
                    msx_pdf(h.0, &m, wi, wo);
                }
                _ => {
                    msx_sample(h.0, &m, wi, samples[i][0], samples[i][1], samples[i][2]);
                }
            }
            let b1 = msx_diagnostics();
            if b1.nonfinite + b1.negative > b0.nonfinite + b0.negative {
                println!("batch op {op} lane {i}: {:?} material {m:?} wi {wi:?} wo {wo:?} samples {:?}", h.2, samples[i]);
            }
        }
    }
    let written: Vec<usize> = match op {
        0 => (0..h.1 as usize).collect(),
        1 => vec![4],
        2 => (0..h.1 as usize).chain([4]).collect(),
        _ => (0..h.1 as usize).chain([4]).collect(),
    };
    for c in written {
        check("batched call", &out[c]);
    }
}

#[test]
fn fuzz_the_c_abi() {
    let calls: usize = std::env::var("MSX_FUZZ_CALLS").ok().and_then(|v| v.parse().ok()).unwrap_or(1_000_000);
    let threads = std::thread::available_parallelism().map(|t| t.get()).unwrap_or(1).clamp(1, 8);
    let before = msx_diagnostics();
    let t0 = std::time::Instant::now();
    let suspects: Vec<String> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads).map(|t| s.spawn(move || fuzz(0xf022_0000 + t as u64, calls / threads))).collect();
        workers.into_iter().flat_map(|w| w.join().expect("fuzz thread")).collect()
    });
    println!("fuzz: {calls} ABI calls on {threads} threads in {:.1} s", t0.elapsed().as_secs_f64());
    for line in &suspects {
        println!("suspect: {line}");
    }
    common::assert_no_raw_defects(before, "fuzz");
}
