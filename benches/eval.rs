//! Cost of `eval` and `sample` per call for the three models, on a fixed set
//! of 1024 random upper-hemisphere (ωi, ωo) pairs, through the core API
//! (`msx::Bsdf`) and through the C ABI (`msx::ffi`). See benches/README.md.
//!
//! Every benchmark iterates over the whole set inside the closure, so one
//! criterion "iteration" is 1024 calls (Throughput::Elements(1024)): the
//! "thrpt" line is calls per second and time / 1024 is the time per call.
//! At the end a table of ns per call and ratios to `single` is printed, read
//! from the estimates criterion just wrote (this run only).

#[path = "common.rs"]
mod common;

use common::{copper, estimate_ns, Rng};
use criterion::{black_box, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use msx::ffi::*;
use msx::{Bsdf, Config, Distribution, Material, Model};
use std::time::{Duration, SystemTime};

const N: usize = 1024;
const SEED: u64 = 0x00be_7c4a_11ce;

const MODELS: [(&str, Model, u32); 3] = [
    ("single", Model::Single, MSX_MODEL_SINGLE),
    ("uncorrelated", Model::Uncorrelated, MSX_MODEL_UNCORRELATED),
    ("correlated", Model::Correlated, MSX_MODEL_CORRELATED),
];

/// (name, distribution, α) of the surfaces measured.
const SURFACES: [(&str, Distribution, f64); 3] =
    [("ggx-a0.5", Distribution::Ggx, 0.5), ("beckmann-a0.5", Distribution::Beckmann, 0.5), ("ggx-a1.0", Distribution::Ggx, 1.0)];

struct Set {
    wi: Vec<DVec3>,
    wo: Vec<DVec3>,
    u: Vec<(f64, f64, f64)>,
}

fn fixed_set() -> Set {
    let mut rng = Rng(SEED);
    let wi = (0..N).map(|_| rng.hemisphere()).collect();
    let wo = (0..N).map(|_| rng.hemisphere()).collect();
    let u = (0..N).map(|_| (rng.f(), rng.f(), rng.f())).collect();
    Set { wi, wo, u }
}

fn materials(alpha: f64) -> [(&'static str, Material); 2] {
    [("none", Material::mirror(alpha)), ("Cu", copper(alpha))]
}

fn bsdf(distribution: Distribution, model: Model) -> Bsdf {
    Bsdf::new(Config { distribution, model, channels: 3, ..Config::default() }).expect("valid config")
}

fn bench_core_eval(c: &mut Criterion, set: &Set) {
    for (sname, dist, alpha) in SURFACES {
        for (mname, mat) in materials(alpha) {
            let mut g = c.benchmark_group(format!("eval-{sname}-{mname}"));
            g.throughput(Throughput::Elements(N as u64));
            for (name, model, _) in MODELS {
                let b = bsdf(dist, model);
                let mut key = 0u64;
                g.bench_function(BenchmarkId::from_parameter(name), |bencher| {
                    bencher.iter(|| {
                        let mut acc = 0.0;
                        for i in 0..N {
                            key = key.wrapping_add(1);
                            acc += b.eval(black_box(&mat), black_box(set.wi[i]), black_box(set.wo[i]), key).0[0];
                        }
                        acc
                    })
                });
            }
            g.finish();
        }
    }
}

fn bench_core_sample(c: &mut Criterion, set: &Set) {
    let (sname, dist, alpha) = SURFACES[0];
    for (mname, mat) in materials(alpha) {
        let mut g = c.benchmark_group(format!("sample-{sname}-{mname}"));
        g.throughput(Throughput::Elements(N as u64));
        for (name, model, _) in MODELS {
            let b = bsdf(dist, model);
            g.bench_function(BenchmarkId::from_parameter(name), |bencher| {
                bencher.iter(|| {
                    let mut acc = 0.0;
                    for i in 0..N {
                        let (s1, u1, u2) = set.u[i];
                        if let Some(s) = b.sample(black_box(&mat), black_box(set.wi[i]), s1, (u1, u2)) {
                            acc += s.weight.0[0];
                        }
                    }
                    acc
                })
            });
        }
        g.finish();
    }
}

fn f3(v: DVec3) -> MsxVec3 {
    MsxVec3 { x: v.x as f32, y: v.y as f32, z: v.z as f32 }
}

/// The same eval through the C ABI: per call, and as one batch of 1024 lanes
/// (below the threading threshold, so it runs on the calling thread).
fn bench_ffi_eval(c: &mut Criterion, set: &Set) {
    let (sname, distribution, alpha) = SURFACES[0];
    let dist = match distribution {
        Distribution::Ggx => MSX_DISTRIBUTION_GGX,
        Distribution::Beckmann => MSX_DISTRIBUTION_BECKMANN,
    };
    let a = alpha as f32;
    let mat = MsxMaterial { alpha_u: a, alpha_v: a, eta: [0.0; 4], k: [1.0; 4], specular_reflectance: [1.0; 4], ..Default::default() };
    let wi: Vec<MsxVec3> = set.wi.iter().map(|&v| f3(v)).collect();
    let wo: Vec<MsxVec3> = set.wo.iter().map(|&v| f3(v)).collect();
    let soa = |v: &[MsxVec3], f: fn(&MsxVec3) -> f32| v.iter().map(f).collect::<Vec<f32>>();
    let (wix, wiy, wiz) = (soa(&wi, |v| v.x), soa(&wi, |v| v.y), soa(&wi, |v| v.z));
    let (wox, woy, woz) = (soa(&wo, |v| v.x), soa(&wo, |v| v.y), soa(&wo, |v| v.z));

    let mut g = c.benchmark_group(format!("ffi-eval-{sname}-none"));
    g.throughput(Throughput::Elements(N as u64));
    for (name, _, model) in MODELS {
        let params = MsxParams {
            surface: MSX_SURFACE_CONDUCTOR,
            distribution: dist,
            model,
            estimator: MSX_ESTIMATOR_PT,
            max_bounces: 0,
            channels: 3,
            seed: 0,
            auto_tolerance: 0.0,
            mis_density: 0,
            sample_all_normals: 0,
        };
        let mut h: *mut MsxBsdf = std::ptr::null_mut();
        assert_eq!(msx_bsdf_new(&params, &mut h, std::ptr::null_mut(), 0), MSX_OK);
        let mut key = 0u64;
        g.bench_function(BenchmarkId::from_parameter(name), |bencher| {
            bencher.iter(|| {
                let mut acc = 0.0f32;
                for i in 0..N {
                    key = key.wrapping_add(1);
                    acc += msx_eval(h, black_box(&mat), black_box(wi[i]), black_box(wo[i]), key).v[0];
                }
                acc
            })
        });

        let arr = |v: &Vec<f32>| MsxF32Array { ptr: v.as_ptr(), len: v.len() };
        let one = |x: &f32| MsxF32Array { ptr: x, len: 1 };
        let none = MsxF32Array { ptr: std::ptr::null(), len: 0 };
        let input = MsxBatchIn {
            n: N,
            wi: [arr(&wix), arr(&wiy), arr(&wiz)],
            wo: [arr(&wox), arr(&woy), arr(&woz)],
            sample1: none,
            sample2: [none; 2],
            alpha_u: one(&mat.alpha_u),
            alpha_v: one(&mat.alpha_v),
            eta: [0, 1, 2, 3].map(|c| one(&mat.eta[c])),
            k: [0, 1, 2, 3].map(|c| one(&mat.k[c])),
            specular_reflectance: [none; 4],
            key: 0,
            ..Default::default()
        };
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; N]);
        g.bench_function(BenchmarkId::from_parameter(format!("{name}-batch")), |bencher| {
            bencher.iter(|| {
                let output = MsxBatchOut {
                    value: [out[0].as_mut_ptr(), out[1].as_mut_ptr(), out[2].as_mut_ptr(), std::ptr::null_mut()],
                    pdf: std::ptr::null_mut(),
                    wo: [std::ptr::null_mut(); 3],
                };
                let rc = msx_eval_batch(h, black_box(&input), &output, std::ptr::null_mut(), 0);
                assert_eq!(rc, MSX_OK);
                out[0][N - 1]
            })
        });
        msx_bsdf_free(h);
    }
    g.finish();
}

// ------------------------------------------------------------ summary table

fn print_summary(since: SystemTime) {
    let per_call = |g: &str, f: &str| estimate_ns(g, f, since).map(|ns| ns / N as f64);
    let fmt = |x: Option<f64>| x.map_or("     -".to_string(), |v| format!("{v:8.1}"));
    let ratio = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) => format!("{:6.2}x", a / b),
        _ => "     -".to_string(),
    };
    let mut groups: Vec<String> = Vec::new();
    for (s, _, _) in SURFACES {
        for m in ["none", "Cu"] {
            groups.push(format!("eval-{s}-{m}"));
        }
    }
    for m in ["none", "Cu"] {
        groups.push(format!("sample-{}-{m}", SURFACES[0].0));
    }
    let ffi_group = format!("ffi-eval-{}-none", SURFACES[0].0);
    groups.push(ffi_group.clone());

    println!("\nns per call (1024 upper-hemisphere pairs; slope estimate / 1024)");
    println!("{:<26} {:>8} {:>8} {:>8} {:>10} {:>10}", "group", "single", "uncorr", "corr", "uncorr/sgl", "corr/sgl");
    for g in &groups {
        let [s, u, c] = ["single", "uncorrelated", "correlated"].map(|m| per_call(g, m));
        if s.is_none() && u.is_none() && c.is_none() {
            continue;
        }
        println!("{g:<26} {} {} {} {:>10} {:>10}", fmt(s), fmt(u), fmt(c), ratio(u, s), ratio(c, s));
    }
    let core_group = format!("eval-{}-none", SURFACES[0].0);
    let mut header = false;
    for m in ["single", "uncorrelated", "correlated"] {
        let (core, ffi, batch) = (per_call(&core_group, m), per_call(&ffi_group, m), per_call(&ffi_group, &format!("{m}-batch")));
        if core.is_none() && ffi.is_none() && batch.is_none() {
            continue;
        }
        if !header {
            println!("\nC ABI cost ({core_group}): ns per call");
            println!("{:<14} {:>8} {:>8} {:>8} {:>10} {:>10}", "model", "core", "ffi", "batch", "ffi/core", "batch/core");
            header = true;
        }
        println!("{m:<14} {} {} {} {:>10} {:>10}", fmt(core), fmt(ffi), fmt(batch), ratio(ffi, core), ratio(batch, core));
    }
}

fn main() {
    let start = SystemTime::now();
    let set = fixed_set();
    // Short defaults so that a plain `cargo bench --bench eval` finishes in
    // about 1.5 minutes; command-line options override them.
    let mut c =
        Criterion::default().warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(2)).sample_size(30).configure_from_args();
    bench_core_eval(&mut c, &set);
    bench_core_sample(&mut c, &set);
    bench_ffi_eval(&mut c, &set);
    c.final_summary();
    print_summary(start);
}
