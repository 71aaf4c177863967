//! Prints what every model returns at fixed inputs: eval (whole and per order
//! range), pdf, eval_pdf and sample_with_order, for every surface × model ×
//! estimator × distribution that `Bsdf::new` accepts, over a few roughnesses,
//! materials and direction pairs. Values are printed with `{:e}` (the shortest
//! decimal that reads back to the same f64), so two dumps are equal exactly
//! when the numbers are bit-identical.
//!
//! A refactoring that must not change numbers is checked by diffing the dump
//! before and after:
//!
//! ```sh
//! cargo run --release --example behaviour_dump > before.txt
//! # … change the code …
//! cargo run --release --example behaviour_dump > after.txt && cmp before.txt after.txt
//! ```

use glam::DVec3;
use msx::{Bsdf, Config, Distribution, Estimator, Material, Model, Spectrum, Surface};
use std::fmt::Write as _;
use std::io::Write as _;

/// Every model of the table (src/config.rs), in its order.
const MODELS: [Model; msx::config::ALL_MODELS.len()] = msx::config::ALL_MODELS;

fn spectrum(s: Spectrum, channels: usize) -> String {
    s.0[..channels].iter().map(|v| format!("{v:e}")).collect::<Vec<_>>().join(",")
}

fn dir(theta: f64, phi: f64) -> DVec3 {
    DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

/// The materials of a surface: a coloured conductor, a dielectric seen from
/// both sides in both transport modes, a diffuse albedo.
fn materials(surface: Surface, alpha: (f64, f64)) -> Vec<(&'static str, Material)> {
    let mut m = Material::mirror(alpha.0);
    m.alpha_v = alpha.1;
    match surface {
        Surface::Conductor => {
            m.eta = Spectrum([0.2, 0.9, 1.1, 0.0]);
            m.k = Spectrum([3.9, 2.4, 2.2, 0.0]);
            vec![("cu", m)]
        }
        Surface::Dielectric => {
            let mut out = Vec::new();
            for (name, ior, radiance) in [("glass", 1.5, true), ("glass-importance", 1.5, false), ("inside", 1.0 / 1.33, true)] {
                out.push((name, Material { ior, radiance, ..m }));
            }
            out
        }
        Surface::Diffuse => vec![("albedo", Material { reflectance: Spectrum([0.8, 0.5, 0.95, 0.0]), ..m })],
    }
}

fn main() {
    let channels = 3;
    let alphas = [(0.1, 0.1), (0.6, 0.6), (1.5, 1.5), (0.3, 0.9)];
    let wis = [dir(0.0, 0.0), dir(0.9, 0.3), dir(1.45, 2.0), dir(2.4, 0.7)];
    let wos = [dir(0.2, 1.0), dir(1.2, 3.5), dir(2.0, 0.1), dir(2.9, 4.0)];
    let samples = [(0.1, (0.2, 0.3)), (0.5, (0.5, 0.5)), (0.93, (0.71, 0.04)), (0.37, (0.99, 0.61))];
    let mut out = String::new();
    for surface in [Surface::Conductor, Surface::Dielectric, Surface::Diffuse] {
        for model in MODELS {
            for estimator in [Estimator::Pt, Estimator::Bdpt] {
                for distribution in [Distribution::Ggx, Distribution::Beckmann] {
                    let cfg = Config { surface, model, estimator, distribution, channels, seed: 11, ..Config::default() };
                    let Ok(bsdf) = Bsdf::new(cfg) else { continue };
                    writeln!(out, "# {surface:?} {model:?} {estimator:?} {distribution:?}").unwrap();
                    for alpha in alphas {
                        for (name, mat) in materials(surface, alpha) {
                            for (i, wi) in wis.iter().enumerate() {
                                let head = format!("a={:e},{:e} {name} wi{i}", alpha.0, alpha.1);
                                for (o, wo) in wos.iter().enumerate() {
                                    for key in [0u64, 1, 99] {
                                        let v = bsdf.eval(&mat, *wi, *wo, key);
                                        writeln!(out, "{head} wo{o} eval k{key} {}", spectrum(v, channels)).unwrap();
                                    }
                                    for orders in [(1, 1), (2, 3), (2, u32::MAX)] {
                                        let v = bsdf.eval_orders(&mat, *wi, *wo, 5, orders);
                                        writeln!(out, "{head} wo{o} orders {orders:?} {}", spectrum(v, channels)).unwrap();
                                    }
                                    writeln!(out, "{head} wo{o} pdf {:e}", bsdf.pdf(&mat, *wi, *wo)).unwrap();
                                    let (v, p) = bsdf.eval_pdf(&mat, *wi, *wo, 7);
                                    writeln!(out, "{head} wo{o} eval_pdf {} {p:e}", spectrum(v, channels)).unwrap();
                                }
                                for (s, (s1, s2)) in samples.iter().enumerate() {
                                    match bsdf.sample_with_order(&mat, *wi, *s1, *s2) {
                                        Some((smp, order)) => writeln!(
                                            out,
                                            "{head} sample{s} wo={:e},{:e},{:e} pdf={:e} w={} order={order}",
                                            smp.wo.x,
                                            smp.wo.y,
                                            smp.wo.z,
                                            smp.pdf,
                                            spectrum(smp.weight, channels)
                                        )
                                        .unwrap(),
                                        None => writeln!(out, "{head} sample{s} none").unwrap(),
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    std::io::stdout().write_all(out.as_bytes()).unwrap();
}
