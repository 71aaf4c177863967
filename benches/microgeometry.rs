//! Throughput of the microgeometry simulation (src/microgeometry/): rays per
//! second on all cores and on one, for the configurations of the comparison
//! (docs/microgeometry.md), plus the time to generate the surfaces. Plain
//! wall-clock timing of one run per configuration: run on an idle machine and
//! read the ratios.
//!
//! `cargo bench --bench microgeometry` (≈ 1 min).

use msx::microgeometry::{Facet, SimConfig, Simulation, SurfaceParams};
use std::time::Instant;

fn main() {
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let rays_per_surface = 125_000u64; // 2M rays on 16 surfaces
    println!(
        "{:<11} {:>10} {:>5} {:>8} {:>12} {:>12} {:>8} {:>9}",
        "surface",
        "alpha",
        "θi",
        "gen s",
        format!("rays/s ({cores}t)"),
        "rays/s (1t)",
        "speedup",
        "bounces"
    );
    for facet in [Facet::Conductor { eta: 0.0, k: 1.0 }, Facet::Dielectric { ior: 1.5 }, Facet::Diffuse { albedo: 1.0 }] {
        for alpha in [(0.25, 0.25), (1.0, 1.0), (1.0, 0.1)] {
            for theta in [0.0, 1.5] {
                let cfg = SimConfig {
                    surface: SurfaceParams { alpha_x: alpha.0, alpha_y: alpha.1, grid: 1024, corr_cells: 16.0 },
                    facet,
                    theta_i: theta,
                    phi_i: 0.0,
                    surfaces: 16,
                    seed: 1,
                    theta_bins: 36,
                    phi_bins: 36,
                    max_bounces: 100_000,
                };
                let t0 = Instant::now();
                let mut sim = Simulation::new(cfg).unwrap();
                let gen = t0.elapsed().as_secs_f64();
                let t0 = Instant::now();
                sim.run(rays_per_surface, cores);
                let multi = t0.elapsed().as_secs_f64();
                let mut one = Simulation::new(cfg).unwrap();
                let t0 = Instant::now();
                one.run(rays_per_surface / 4, 1);
                let single = t0.elapsed().as_secs_f64();
                let t = sim.tally();
                let rays: u64 = t.rays.iter().sum();
                let bounces = t.bounces.iter().sum::<u64>() as f64 / rays as f64;
                let name = match facet {
                    Facet::Conductor { .. } => "conductor",
                    Facet::Dielectric { .. } => "dielectric",
                    Facet::Diffuse { .. } => "diffuse",
                };
                let r_multi = rays as f64 / multi;
                let r_one = (rays / 4) as f64 / single;
                println!(
                    "{name:<11} {:>10} {theta:>5} {gen:>8.2} {r_multi:>12.0} {r_one:>12.0} {:>7.2}x {bounces:>9.3}",
                    format!("{alpha:?}"),
                    r_multi / r_one
                );
            }
        }
    }
}
