//! Speed **and** variance of every model and estimator, so that the efficiency
//! 1 / (variance per call × time per call) of the stochastic estimators can be
//! compared. See benches/README.md.
//!
//! Part 1 (criterion): ns per `eval` and per `sample` of every
//! surface × model × estimator (`msx::bsdf::models_for`, `bdpt_models`) at GGX
//! α = 0.5 and α = 1.0, on a fixed set of 256 random (ωi, ωo) pairs; one
//! criterion iteration walks the whole set (Throughput::Elements(256)).
//! `sample` ignores the estimator (the walk is the sampler), so `bdpt` has no
//! `sample` benchmark; `sample` runs at α = 0.5 only unless
//! MSX_BENCH_SAMPLE_ALL=1 (time budget: 46 benchmarks ≈ 2.7 min).
//!
//! Part 2 (plain `Instant` timing, after criterion): ns per call of `eval` and
//! `sample` over the same set at both α (interleaved rounds); then mean, variance per call,
//! ns per call and relative efficiency of `eval` at three fixed direction pairs
//! (mirror, off-specular, grazing), N = 100 000 calls per cell with distinct
//! keys, all models of a cell interleaved in chunks of 1 000 calls so that
//! machine drift hits them alike.

// Lints relaxed for this test file: lanes indexed in lockstep across several arrays.
#![allow(clippy::needless_range_loop)]

#[path = "common.rs"]
mod common;

use common::{copper, estimate_ns, Rng};
use criterion::{black_box, BenchmarkId, Criterion, Throughput};
use glam::DVec3;
use msx::bsdf::{bdpt_models, models_for};
use msx::{Bsdf, Config, Distribution, Estimator, Material, Model, Spectrum, Surface};
use std::time::{Duration, Instant, SystemTime};

/// Pairs per criterion iteration.
const N_SET: usize = 256;
const SEED: u64 = 0x5e_ed0f_0de1_5a11;

/// Calls per cell of the variance table, and the interleaving chunk.
const N_VAR: usize = 100_000;
const CHUNK: usize = 1_000;

const DIELECTRIC_IOR: f64 = 1.5;
const DIFFUSE_ALBEDO: f64 = 0.8;

const ALPHAS: [f64; 2] = [0.5, 1.0];
const SURFACES: [Surface; 3] = [Surface::Conductor, Surface::Dielectric, Surface::Diffuse];

// ------------------------------------------------------------------ variants

#[derive(Clone, Copy)]
struct Variant {
    surface: Surface,
    model: Model,
    estimator: Estimator,
}

impl Variant {
    /// "single", "correlated", "correlated-bdpt", ...
    fn label(&self) -> String {
        match self.estimator {
            Estimator::Pt => self.model.name().to_string(),
            Estimator::Bdpt => format!("{}-bdpt", self.model.name()),
        }
    }

    fn bsdf(&self) -> Bsdf {
        Bsdf::new(Config {
            surface: self.surface,
            distribution: Distribution::Ggx,
            model: self.model,
            estimator: self.estimator,
            channels: 3,
            ..Config::default()
        })
        .expect("valid config")
    }
}

/// Every model of a surface, followed by its bdpt variant where there is one.
fn variants(surface: Surface) -> Vec<Variant> {
    let mut out = Vec::new();
    for &model in models_for(surface) {
        out.push(Variant { surface, model, estimator: Estimator::Pt });
        if bdpt_models(surface).contains(&model) {
            out.push(Variant { surface, model, estimator: Estimator::Bdpt });
        }
    }
    out
}

fn material(surface: Surface, alpha: f64) -> Material {
    let mut m = Material::mirror(alpha);
    match surface {
        Surface::Conductor => m = copper(alpha),
        Surface::Dielectric => m.ior = DIELECTRIC_IOR,
        Surface::Diffuse => m.reflectance = Spectrum::splat(DIFFUSE_ALBEDO),
    }
    m
}

fn group_name(op: &str, surface: Surface, alpha: f64) -> String {
    format!("{op}-{}-ggx-a{alpha:.1}", surface.name())
}

// ----------------------------------------------------------- fixed direction set

struct Set {
    wi: Vec<DVec3>,
    /// Upper hemisphere (conductor, diffuse).
    wo: Vec<DVec3>,
    /// Dielectric: the same directions, every second one mirrored to the
    /// lower hemisphere (transmission).
    wo_dielectric: Vec<DVec3>,
    u: Vec<(f64, f64, f64)>,
}

fn fixed_set() -> Set {
    let mut rng = Rng(SEED);
    let wi: Vec<DVec3> = (0..N_SET).map(|_| rng.hemisphere()).collect();
    let wo: Vec<DVec3> = (0..N_SET).map(|_| rng.hemisphere()).collect();
    let u = (0..N_SET).map(|_| (rng.f(), rng.f(), rng.f())).collect();
    let wo_dielectric = wo.iter().enumerate().map(|(i, &w)| if i % 2 == 1 { DVec3::new(w.x, w.y, -w.z) } else { w }).collect();
    Set { wi, wo, wo_dielectric, u }
}

// ------------------------------------------------------------ part 1: criterion

fn bench_eval(c: &mut Criterion, set: &Set) {
    for surface in SURFACES {
        let wo = if surface == Surface::Dielectric { &set.wo_dielectric } else { &set.wo };
        for alpha in ALPHAS {
            let mat = material(surface, alpha);
            let mut g = c.benchmark_group(group_name("eval", surface, alpha));
            g.throughput(Throughput::Elements(N_SET as u64));
            for v in variants(surface) {
                let b = v.bsdf();
                let mut key = 0u64;
                g.bench_function(BenchmarkId::from_parameter(v.label()), |bencher| {
                    bencher.iter(|| {
                        let mut acc = 0.0;
                        for i in 0..N_SET {
                            key = key.wrapping_add(1);
                            acc += b.eval(black_box(&mat), black_box(set.wi[i]), black_box(wo[i]), key).0[0];
                        }
                        acc
                    })
                });
            }
            g.finish();
        }
    }
}

/// α values of the criterion `sample` groups: 0.5 only by default, so that the
/// whole bench fits in 3 minutes (criterion spends ≈ 3.5 s per benchmark at
/// `--warm-up-time 1 --measurement-time 2`); MSX_BENCH_SAMPLE_ALL=1 adds α = 1.0.
/// The plain-timing table after criterion covers `sample` at both α anyway.
fn sample_alphas() -> &'static [f64] {
    if std::env::var_os("MSX_BENCH_SAMPLE_ALL").is_some() {
        &ALPHAS
    } else {
        &ALPHAS[..1]
    }
}

fn bench_sample(c: &mut Criterion, set: &Set) {
    for surface in SURFACES {
        for &alpha in sample_alphas() {
            let mat = material(surface, alpha);
            let mut g = c.benchmark_group(group_name("sample", surface, alpha));
            g.throughput(Throughput::Elements(N_SET as u64));
            for v in variants(surface).into_iter().filter(|v| v.estimator == Estimator::Pt) {
                let b = v.bsdf();
                g.bench_function(BenchmarkId::from_parameter(v.label()), |bencher| {
                    bencher.iter(|| {
                        let mut acc = 0.0;
                        for i in 0..N_SET {
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
}

/// ns per call that criterion estimated in this run (per iteration / N_SET).
fn ns_per_call(group: &str, function: &str, since: SystemTime) -> Option<f64> {
    estimate_ns(group, function, since).map(|ns| ns / N_SET as f64)
}

fn print_speed_table(since: SystemTime) {
    let fmt = |x: Option<f64>| x.map_or(format!("{:>8}", "-"), |v| format!("{v:8.1}"));
    let ratio = |a: Option<f64>, b: Option<f64>| match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:>8}", format!("{:.2}x", a / b)),
        _ => format!("{:>8}", "-"),
    };
    println!("\n== speed: ns per call (GGX, {N_SET} fixed pairs; criterion slope / {N_SET}) ==");
    println!("eval/sgl = eval time / eval time of the same surface's `single` (diffuse has none: / conductor single, marked *)");
    println!(
        "{:<11} {:<18} {:>8} {:>8} {:>8} {:>8} {:>8} {:>8}",
        "surface", "model", "eval.5", "eval1.0", "smpl.5", "smpl1.0", "e/sgl.5", "e/sgl1.0"
    );
    let mut any = false;
    for surface in SURFACES {
        let reference = if models_for(surface).contains(&Model::Single) { surface } else { Surface::Conductor };
        let star = if reference == surface { "" } else { "*" };
        for v in variants(surface) {
            let label = v.label();
            let e = ALPHAS.map(|a| ns_per_call(&group_name("eval", surface, a), &label, since));
            let s = ALPHAS.map(|a| ns_per_call(&group_name("sample", surface, a), &label, since));
            let sgl = ALPHAS.map(|a| ns_per_call(&group_name("eval", reference, a), "single", since));
            if e.iter().chain(s.iter()).all(Option::is_none) {
                continue;
            }
            any = true;
            println!(
                "{:<11} {:<18} {} {} {} {} {} {}",
                surface.name(),
                label,
                fmt(e[0]),
                fmt(e[1]),
                fmt(s[0]),
                fmt(s[1]),
                ratio(e[0], sgl[0]) + star,
                ratio(e[1], sgl[1]) + star
            );
        }
    }
    if !any {
        println!("(no criterion estimates from this run)");
    }
}

// ---------------------------------------------------- part 2: variance table

/// The three fixed (ωi, ωo) pairs: (name, θi, θo, Δφ).
const PAIRS: [(&str, f64, f64, f64); 3] = [("mirror", 0.6, 0.6, std::f64::consts::PI), ("off-spec", 0.6, 1.1, 2.1), ("grazing", 1.45, 1.4, 3.0)];

fn dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

/// Running mean / variance (Welford) and time of one cell.
#[derive(Clone, Copy, Default)]
struct Acc {
    n: u64,
    mean: f64,
    m2: f64,
    ns: f64,
}

impl Acc {
    fn push(&mut self, x: f64) {
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
    }
    fn var(&self) -> f64 {
        if self.n > 1 {
            self.m2 / (self.n - 1) as f64
        } else {
            0.0
        }
    }
    fn ns_per_call(&self) -> f64 {
        self.ns / self.n as f64
    }
    /// var × time; 0 for a deterministic (analytic) model.
    fn cost(&self) -> f64 {
        self.var() * self.ns_per_call()
    }
}

/// Efficiency of `a` relative to `r`: (var_r·t_r) / (var_a·t_a).
fn rel_eff(a: &Acc, r: Option<&Acc>) -> String {
    let s = match r {
        None => "-".to_string(),
        Some(r) if a.cost() == 0.0 => {
            if r.cost() == 0.0 {
                "-".into()
            } else {
                "exact".into()
            }
        }
        Some(r) => format!("{:.2}x", r.cost() / a.cost()),
    };
    format!("{s:>9}")
}

fn variance_table(surface: Surface) {
    let vs = variants(surface);
    let bsdfs: Vec<Bsdf> = vs.iter().map(Variant::bsdf).collect();
    let heitz = vs.iter().position(|v| v.model == Model::Heitz && v.estimator == Estimator::Pt);
    let corr = vs.iter().position(|v| v.model == Model::Correlated && v.estimator == Estimator::Pt);
    let extra = match surface {
        Surface::Conductor => "Cu η≈(0.20,0.92,1.10) k≈(3.91,2.45,2.14)".to_string(),
        Surface::Dielectric => format!("ior {DIELECTRIC_IOR}, reflection"),
        Surface::Diffuse => format!("albedo {DIFFUSE_ALBEDO}"),
    };
    println!("\n== variance: {} ({extra}), GGX; value = f·cos θo averaged over the 3 channels ==", surface.name());
    println!(
        "{:<5} {:<9} {:<18} {:>11} {:>9} {:>10} {:>7} {:>9} {:>9} {:>9}",
        "alpha", "pair", "model", "mean", "±se", "var/call", "ns", "rel.std", "eff/heitz", "eff/corr"
    );
    for alpha in ALPHAS {
        let mat = material(surface, alpha);
        for (pname, ti, to, dphi) in PAIRS {
            let (wi, wo) = (dir(ti, 0.0), dir(to, dphi));
            let mut acc = vec![Acc::default(); vs.len()];
            // Interleaved: chunk c of every model, then chunk c + 1 of every model.
            for chunk in 0..N_VAR / CHUNK {
                for (b, a) in bsdfs.iter().zip(acc.iter_mut()) {
                    let mut vals = [0.0f64; CHUNK];
                    let t0 = Instant::now();
                    for (j, val) in vals.iter_mut().enumerate() {
                        let key = (chunk * CHUNK + j) as u64;
                        let s = b.eval(black_box(&mat), black_box(wi), black_box(wo), key);
                        *val = (s.0[0] + s.0[1] + s.0[2]) / 3.0;
                    }
                    a.ns += t0.elapsed().as_nanos() as f64;
                    for &x in &vals {
                        a.push(x);
                    }
                }
            }
            for (v, a) in vs.iter().zip(acc.iter()) {
                let se = (a.var() / a.n as f64).sqrt();
                let rel = if a.mean != 0.0 { format!("{:.3}", a.var().sqrt() / a.mean) } else { "-".into() };
                println!(
                    "{:<5} {:<9} {:<18} {:>11.5e} {:>9.2e} {:>10.3e} {:>7.0} {:>9} {} {}",
                    format!("{alpha:.1}"),
                    pname,
                    v.label(),
                    a.mean,
                    se,
                    a.var(),
                    a.ns_per_call(),
                    rel,
                    rel_eff(a, heitz.map(|i| &acc[i])),
                    rel_eff(a, corr.map(|i| &acc[i]))
                );
            }
        }
    }
}

// ------------------------------------------- part 2a: plain timing, fixed set

/// ns per call of `eval` and `sample` over the fixed set at both α, with
/// `Instant`: every (variant, α, op) is timed for one pass over the 256 pairs,
/// then the next, for `ROUNDS` interleaved rounds. A cross-check of the
/// criterion numbers, and the only `sample` timing at α = 1.0 by default.
fn plain_speed_table(set: &Set) {
    const ROUNDS: usize = 150;
    struct Cell {
        surface: Surface,
        label: String,
        bsdf: Bsdf,
        ns: [[f64; 2]; 2], // [op: eval, sample][alpha]
    }
    let mut cells: Vec<Cell> = SURFACES
        .iter()
        .flat_map(|&s| variants(s).into_iter().map(move |v| (s, v)))
        .map(|(surface, v)| Cell { surface, label: v.label(), bsdf: v.bsdf(), ns: [[0.0; 2]; 2] })
        .collect();
    let mut key = 0u64;
    // Round 0 is a warm-up (tables that models build on first use, caches),
    // not counted.
    for round in 0..=ROUNDS {
        if round == 1 {
            for cell in cells.iter_mut() {
                cell.ns = [[0.0; 2]; 2];
            }
        }
        for cell in cells.iter_mut() {
            let wo = if cell.surface == Surface::Dielectric { &set.wo_dielectric } else { &set.wo };
            let bdpt = cell.label.ends_with("-bdpt");
            for (ai, &alpha) in ALPHAS.iter().enumerate() {
                let mat = material(cell.surface, alpha);
                let t0 = Instant::now();
                let mut acc = 0.0;
                for i in 0..N_SET {
                    key = key.wrapping_add(1);
                    acc += cell.bsdf.eval(black_box(&mat), black_box(set.wi[i]), black_box(wo[i]), key).0[0];
                }
                black_box(acc);
                cell.ns[0][ai] += t0.elapsed().as_nanos() as f64;
                if bdpt {
                    continue; // sample ignores the estimator
                }
                let t0 = Instant::now();
                let mut acc = 0.0;
                for i in 0..N_SET {
                    let (s1, u1, u2) = set.u[i];
                    if let Some(s) = cell.bsdf.sample(black_box(&mat), black_box(set.wi[i]), s1, (u1, u2)) {
                        acc += s.weight.0[0];
                    }
                }
                black_box(acc);
                cell.ns[1][ai] += t0.elapsed().as_nanos() as f64;
            }
        }
    }
    let calls = (ROUNDS * N_SET) as f64;
    println!("\n== speed, plain Instant timing: ns per call over the same {N_SET} pairs, {ROUNDS} interleaved rounds ==");
    println!("{:<11} {:<18} {:>8} {:>8} {:>8} {:>8}", "surface", "model", "eval.5", "eval1.0", "smpl.5", "smpl1.0");
    for c in &cells {
        let f = |x: f64| if x > 0.0 { format!("{:8.1}", x / calls) } else { format!("{:>8}", "-") };
        println!("{:<11} {:<18} {} {} {} {}", c.surface.name(), c.label, f(c.ns[0][0]), f(c.ns[0][1]), f(c.ns[1][0]), f(c.ns[1][1]));
    }
}

/// `auto` against the model it approximates (`correlated`) across roughness:
/// ns per eval over the fixed set, interleaved rounds after a warm-up round.
fn auto_speed_table(set: &Set) {
    const ROUNDS: usize = 100;
    const AUTO_ALPHAS: [f64; 5] = [0.02, 0.05, 0.1, 0.3, 1.0];
    println!("\n== auto vs correlated: ns per eval over the same {N_SET} pairs, {ROUNDS} interleaved rounds ==");
    println!("{:<11} {:>6} {:>11} {:>9} {:>11}", "surface", "alpha", "correlated", "auto", "auto/corr");
    for surface in SURFACES {
        let wo = if surface == Surface::Dielectric { &set.wo_dielectric } else { &set.wo };
        let models = [Model::Correlated, Model::Auto].map(|model| Variant { surface, model, estimator: Estimator::Pt }.bsdf());
        for alpha in AUTO_ALPHAS {
            let mat = material(surface, alpha);
            let mut ns = [0.0f64; 2];
            let mut key = 0u64;
            for round in 0..=ROUNDS {
                for (m, bsdf) in models.iter().enumerate() {
                    let t0 = Instant::now();
                    let mut acc = 0.0;
                    for i in 0..N_SET {
                        key = key.wrapping_add(1);
                        acc += bsdf.eval(black_box(&mat), black_box(set.wi[i]), black_box(wo[i]), key).0[0];
                    }
                    black_box(acc);
                    if round > 0 {
                        ns[m] += t0.elapsed().as_nanos() as f64;
                    }
                }
            }
            let calls = (ROUNDS * N_SET) as f64;
            println!("{:<11} {:>6} {:>11.1} {:>9.1} {:>10.2}x", surface.name(), alpha, ns[0] / calls, ns[1] / calls, ns[1] / ns[0]);
        }
    }
}

/// The plain tables run only under `cargo bench` (which passes `--bench`):
/// not for `--list`, not in criterion's test mode (`cargo test --benches`),
/// not with MSX_BENCH_NO_TABLES set.
fn skip_tables() -> bool {
    let args: Vec<String> = std::env::args().collect();
    !args.iter().any(|a| a == "--bench") || args.iter().any(|a| a == "--list" || a == "--test") || std::env::var_os("MSX_BENCH_NO_TABLES").is_some()
}

fn main() {
    let start = SystemTime::now();
    let set = fixed_set();
    // Short defaults (1 s warm-up, 2 s measurement, 30 samples); command-line
    // options override them.
    let mut c = Criterion::default()
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(2))
        .sample_size(30)
        .nresamples(20_000)
        .configure_from_args();
    bench_eval(&mut c, &set);
    bench_sample(&mut c, &set);
    c.final_summary();
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    print_speed_table(start);
    if skip_tables() {
        return;
    }
    let t0 = Instant::now();
    plain_speed_table(&set);
    auto_speed_table(&set);
    println!(
        "\n{N_VAR} eval calls per cell, distinct keys, models of a cell interleaved in chunks of {CHUNK}; one run.\n\
         eff = 1/(var·ns); eff/heitz, eff/corr: relative to Heitz's random walk and to posfree correlated PT of the\n\
         same cell (\"exact\": analytic model, variance 0). Means differ between models by design (correlated,\n\
         uncorrelated and Heitz split multiple-scattered energy differently); heitz and invariance should agree."
    );
    for surface in SURFACES {
        variance_table(surface);
    }
    println!("\n(plain tables: {:.1} s)", t0.elapsed().as_secs_f64());
}
