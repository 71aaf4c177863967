//! Robustness sweep through the C ABI (issue: every model × surface ×
//! distribution): α log-uniform in [1e-4, 4], anisotropy ratio up to 100,
//! θ_i up to π/2 − 1e-6 (and below the horizon for dielectrics), η from
//! 1.0001 to 3 and below 1, Radiance and Importance mode. Nothing may come
//! out NaN, infinite or negative; valid samples have unit ω_o and pdf > 0.
//! Fixed seed.

// Lints relaxed for this test file: angles near π/2 and 2π on purpose (grazing, not exactly horizontal).
#![allow(clippy::approx_constant)]

mod common;

use msx::ffi::*;
use msx::rng::Sampler;
use std::ptr;

/// The models run with the PT estimator on conductors and dielectrics alike.
const CONDUCTOR_AND_DIELECTRIC_PT: [u32; 7] =
    [MSX_MODEL_SINGLE, MSX_MODEL_UNCORRELATED, MSX_MODEL_CORRELATED, MSX_MODEL_HEITZ, MSX_MODEL_INVARIANCE, MSX_MODEL_COMPENSATED, MSX_MODEL_AUTO];

fn combos() -> Vec<(u32, u32, u32, u32)> {
    let mut v = Vec::new();
    for dist in [MSX_DISTRIBUTION_BECKMANN, MSX_DISTRIBUTION_GGX] {
        for model in CONDUCTOR_AND_DIELECTRIC_PT {
            v.push((MSX_SURFACE_CONDUCTOR, dist, model, MSX_ESTIMATOR_PT));
        }
        v.push((MSX_SURFACE_CONDUCTOR, dist, MSX_MODEL_UNCORRELATED, MSX_ESTIMATOR_BDPT));
        v.push((MSX_SURFACE_CONDUCTOR, dist, MSX_MODEL_CORRELATED, MSX_ESTIMATOR_BDPT));
        for model in CONDUCTOR_AND_DIELECTRIC_PT {
            v.push((MSX_SURFACE_DIELECTRIC, dist, model, MSX_ESTIMATOR_PT));
        }
        v.push((MSX_SURFACE_CONDUCTOR, dist, MSX_MODEL_AUTO, MSX_ESTIMATOR_BDPT));
        for surface in [MSX_SURFACE_DIELECTRIC, MSX_SURFACE_DIFFUSE] {
            v.push((surface, dist, MSX_MODEL_AUTO, MSX_ESTIMATOR_BDPT));
            v.push((surface, dist, MSX_MODEL_UNCORRELATED, MSX_ESTIMATOR_BDPT));
            v.push((surface, dist, MSX_MODEL_CORRELATED, MSX_ESTIMATOR_BDPT));
        }
        for model in [MSX_MODEL_UNCORRELATED, MSX_MODEL_CORRELATED, MSX_MODEL_HEITZ, MSX_MODEL_INVARIANCE, MSX_MODEL_AUTO] {
            v.push((MSX_SURFACE_DIFFUSE, dist, model, MSX_ESTIMATOR_PT));
        }
    }
    v.push((MSX_SURFACE_CONDUCTOR, MSX_DISTRIBUTION_GGX, MSX_MODEL_FASTMSX, MSX_ESTIMATOR_PT));
    v
}

fn ok(x: f32) -> bool {
    x.is_finite() && x >= 0.0
}

#[test]
fn every_model_surface_distribution_is_total() {
    let diag = msx_diagnostics();
    let mut rng = Sampler::new(2024);
    let mut calls = 0usize;
    for (surface, distribution, model, estimator) in combos() {
        let params = MsxParams {
            surface,
            distribution,
            model,
            estimator,
            max_bounces: 0,
            channels: 3,
            seed: 7,
            auto_tolerance: 0.0,
            mis_density: 0,
            sample_all_normals: 0,
        };
        let mut h: *mut MsxBsdf = ptr::null_mut();
        let mut err = [0 as std::os::raw::c_char; 256];
        let rc = msx_bsdf_new(&params, &mut h, err.as_mut_ptr(), err.len());
        let msg = unsafe { std::ffi::CStr::from_ptr(err.as_ptr()) }.to_string_lossy().into_owned();
        assert_eq!(rc, MSX_OK, "{params:?}: {msg}");
        let label = format!("surface {surface} dist {distribution} model {model} estimator {estimator}");
        let n = if distribution == MSX_DISTRIBUTION_BECKMANN { 250 } else { 400 };
        for i in 0..n {
            let a = (rng.gen_range((1e-4f64).ln(), (4.0f64).ln())).exp();
            let ratio = if rng.next() < 0.5 { 1.0 } else { (rng.gen_range(0.0, (100.0f64).ln())).exp() };
            let eta = if rng.next() < 0.5 { rng.gen_range(1.0001, 3.0) } else { rng.gen_range(0.33, 0.9999) };
            let mut theta =
                if rng.next() < 0.3 { std::f64::consts::FRAC_PI_2 - (rng.gen_range((1e-6f64).ln(), 0.0)).exp() } else { rng.gen_range(0.0, 1.5707) };
            if surface == MSX_SURFACE_DIELECTRIC && rng.next() < 0.5 {
                theta = std::f64::consts::PI - theta; // from inside
            }
            let phi = rng.gen_range(0.0, 6.283);
            let wi = MsxVec3 { x: (theta.sin() * phi.cos()) as f32, y: (theta.sin() * phi.sin()) as f32, z: theta.cos() as f32 };
            let (z, p2) = (rng.gen_range(-1.0, 1.0), rng.gen_range(0.0, 6.283));
            let r = (1.0f64 - z * z).max(0.0).sqrt();
            let wo = MsxVec3 { x: (r * p2.cos()) as f32, y: (r * p2.sin()) as f32, z: z as f32 };
            let mat = MsxMaterial {
                alpha_u: a as f32,
                alpha_v: (a * ratio) as f32,
                eta: [0.2, 0.92, 1.1, 0.0],
                k: [3.9, 2.45, 2.14, 1.0],
                specular_reflectance: [1.0, 0.9, 0.8, 1.0],
                ior: eta as f32,
                specular_transmittance: [1.0, 0.95, 0.9, 1.0],
                reflectance: [0.8, 0.5, 0.2, 1.0],
                mode: if i % 2 == 0 { MSX_MODE_RADIANCE } else { MSX_MODE_IMPORTANCE },
            };
            let v = msx_eval(h, &mat, wi, wo, i as u64);
            assert!(v.v.iter().all(|&x| ok(x)), "{label}: eval {v:?} α={a} ratio={ratio} η={eta} wi={wi:?} wo={wo:?}");
            let p = msx_pdf(h, &mat, wi, wo);
            assert!(ok(p), "{label}: pdf {p}");
            let ep = msx_eval_pdf(h, &mat, wi, wo, i as u64);
            assert!(ep.value.v.iter().all(|&x| ok(x)) && ok(ep.pdf), "{label}: eval_pdf {ep:?}");
            let s = msx_sample(h, &mat, wi, rng.next() as f32, rng.next() as f32, rng.next() as f32);
            assert!(s.weight.v.iter().all(|&x| ok(x)) && ok(s.pdf), "{label}: sample {s:?}");
            if s.valid == 1 {
                let len = (s.wo.x * s.wo.x + s.wo.y * s.wo.y + s.wo.z * s.wo.z).sqrt();
                assert!((len - 1.0).abs() < 1e-4 && s.pdf > 0.0, "{label}: sample {s:?}");
            }
            calls += 4;
        }
        msx_bsdf_free(h);
    }
    println!("{calls} ABI calls, all finite and non-negative");
    common::assert_no_raw_defects(diag, "every_model_surface_distribution_is_total");
}
