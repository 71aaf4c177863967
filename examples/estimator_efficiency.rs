//! Variance and time per call of the position-free estimators (PT and BDPT,
//! `correlated` and `uncorrelated`) on Cu, a dielectric (IOR 1.5) and a diffuse
//! microsurface (reflectance 0.8): fixed pairs, among them ω_o at the normal,
//! and 256 random pairs. Used for docs/estimators.md: build it at two commits,
//! run both binaries alternately a few times and compare var·ns per row
//! (efficiency = 1/(variance × time)); `var` and `mean` are deterministic.
//!
//! cargo run --release --example estimator_efficiency -- [N] [ggx|beckmann] [α,α,…]
//!
//! Columns: surface, α, pair, estimator, model, mean, variance per call (of
//! the 3-channel average of f·cos θ_o; for `random256` the mean over the pairs
//! of the per-pair variance), ns per call. Time is the thread's CPU time on
//! Linux (robust to preemption on a shared machine), wall time elsewhere.
use glam::DVec3;
use msx::rng::Sampler;
use msx::*;
use std::f64::consts::PI;

#[cfg(target_os = "linux")]
fn now_ns() -> f64 {
    #[repr(C)]
    struct Timespec {
        sec: i64,
        nsec: i64,
    }
    extern "C" {
        fn clock_gettime(clk: i32, ts: *mut Timespec) -> i32;
    }
    const CLOCK_THREAD_CPUTIME_ID: i32 = 3;
    let mut t = Timespec { sec: 0, nsec: 0 };
    // SAFETY: clock_gettime writes one timespec to the pointer it is given.
    unsafe { clock_gettime(CLOCK_THREAD_CPUTIME_ID, &mut t) };
    t.sec as f64 * 1e9 + t.nsec as f64
}

#[cfg(not(target_os = "linux"))]
fn now_ns() -> f64 {
    use std::sync::OnceLock;
    use std::time::Instant;
    static START: OnceLock<Instant> = OnceLock::new();
    START.get_or_init(Instant::now).elapsed().as_nanos() as f64
}

fn dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: u64 = args.get(1).map(|s| s.parse().expect("N")).unwrap_or(100_000);
    let dist = if args.get(2).map(|s| s.as_str()) == Some("beckmann") { Distribution::Beckmann } else { Distribution::Ggx };
    let alphas: Vec<f64> = args.get(3).map(|s| s.split(',').map(|a| a.parse().expect("alpha")).collect()).unwrap_or(vec![0.5, 1.0]);

    let mut rng = Sampler::new(12345);
    let random_pairs: Vec<(DVec3, DVec3)> = (0..256)
        .map(|i| {
            let wi = dir(rng.next().acos(), 2.0 * PI * rng.next());
            let mut wo = dir(rng.next().acos(), 2.0 * PI * rng.next());
            if i % 2 == 1 {
                wo.z = -wo.z; // transmission for the dielectric (0 for the others)
            }
            (wi, wo)
        })
        .collect();
    let cu = Material { eta: Spectrum([0.200, 0.924, 1.102, 1.0]), k: Spectrum([3.912, 2.452, 2.142, 1.0]), ..Material::mirror(0.5) };
    let surfaces = [
        ("Cu", Surface::Conductor, cu),
        ("dielectric", Surface::Dielectric, Material { ior: 1.5, ..Material::mirror(0.5) }),
        ("diffuse", Surface::Diffuse, Material { reflectance: Spectrum([0.8; 4]), ..Material::mirror(0.5) }),
    ];
    let wi_m = dir(0.6, 0.0);
    let fixed = [
        ("mirror", wi_m, DVec3::new(-wi_m.x, -wi_m.y, wi_m.z)),
        ("off-spec", wi_m, dir(1.1, 2.1)),
        ("grazing", dir(1.45, 0.0), dir(1.4, 3.0)),
        ("normal", wi_m, dir(0.0, 0.0)),
        ("wi-normal", dir(0.02, 0.0), dir(0.8, 1.0)),
    ];
    println!("{:<10} {:>4} {:<9} {:<5} {:<13} {:>11} {:>10} {:>8}", "surface", "α", "pair", "est", "model", "mean", "var", "ns");
    for &alpha in &alphas {
        for (name, surface, mat0) in surfaces {
            let mat = Material { alpha_u: alpha, alpha_v: alpha, ..mat0 };
            for est in [Estimator::Pt, Estimator::Bdpt] {
                for model in [Model::Correlated, Model::Uncorrelated] {
                    let b = Bsdf::new(Config { surface, distribution: dist, model, estimator: est, seed: 1, ..Config::default() }).unwrap();
                    let val = |wi, wo, key| {
                        let v = b.eval(&mat, wi, wo, key);
                        (v.0[0] + v.0[1] + v.0[2]) / 3.0
                    };
                    let row = |pair: &str, mean: f64, var: f64, ns: f64| {
                        println!(
                            "{:<10} {:>4} {:<9} {:<5} {:<13} {:>11.5e} {:>10.3e} {:>8.1}",
                            name,
                            alpha,
                            pair,
                            format!("{est:?}"),
                            model.name(),
                            mean,
                            var,
                            ns
                        );
                    };
                    for (pair, wi, wo) in fixed {
                        let (mut s, mut s2) = (0.0, 0.0);
                        let t0 = now_ns();
                        for key in 0..n {
                            let v = val(wi, wo, key);
                            s += v;
                            s2 += v * v;
                        }
                        let ns = (now_ns() - t0) / n as f64;
                        let m = s / n as f64;
                        row(pair, m, (s2 / n as f64 - m * m).max(0.0), ns);
                    }
                    let per = (n / 256).max(2);
                    let (mut var_sum, mut mean_sum) = (0.0, 0.0);
                    let t0 = now_ns();
                    for (p, &(wi, wo)) in random_pairs.iter().enumerate() {
                        let (mut s, mut s2) = (0.0, 0.0);
                        for key in 0..per {
                            let v = val(wi, wo, key * 1000 + p as u64);
                            s += v;
                            s2 += v * v;
                        }
                        let m = s / per as f64;
                        var_sum += (s2 / per as f64 - m * m).max(0.0);
                        mean_sum += m;
                    }
                    let ns = (now_ns() - t0) / (per * 256) as f64;
                    row("random256", mean_sum / 256.0, var_sum / 256.0, ns);
                }
            }
        }
    }
}
