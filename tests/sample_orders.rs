//! `Bsdf::sample_with_order` (C ABI `msx_sample_orders_batch`): the same
//! samples as `sample`, tagged with the scattering order of the sampled path;
//! weights binned by order estimate each order's energy.

mod common;

use common::Checker;
use glam::DVec3;
use msx::bsdf::models_for;
use msx::rng::Sampler;
use msx::{Bsdf, Config, Distribution, Material, Microfacet, Model, Surface};

fn bsdf(surface: Surface, model: Model, distribution: Distribution) -> Option<Bsdf> {
    Bsdf::new(Config { surface, model, distribution, channels: 1, ..Config::default() }).ok()
}

#[test]
fn samples_are_those_of_sample_and_analytic_models_are_order_one() {
    let mut rng = Sampler::new(4);
    for surface in [Surface::Conductor, Surface::Dielectric, Surface::Diffuse] {
        for &model in models_for(surface) {
            for distribution in [Distribution::Beckmann, Distribution::Ggx] {
                let Some(b) = bsdf(surface, model, distribution) else { continue };
                let mut mat = Material::mirror(0.6);
                mat.ior = 1.5;
                mat.reflectance = msx::Spectrum::ONE * 0.8;
                for _ in 0..300 {
                    let (u, v) = rng.next2();
                    let z = if surface == Surface::Dielectric { 2.0 * u - 1.0 } else { u };
                    let r = (1.0 - z * z).max(0.0).sqrt();
                    let wi = DVec3::new(r * (6.3 * v).cos(), r * (6.3 * v).sin(), z);
                    let (s1, u1, u2) = (rng.next(), rng.next(), rng.next());
                    let a = b.sample(&mat, wi, s1, (u1, u2));
                    let c = b.sample_with_order(&mat, wi, s1, (u1, u2));
                    match (a, c) {
                        (None, None) => {}
                        (Some(a), Some((c, k))) => {
                            let tag = format!("{surface:?} {model:?} {distribution:?}");
                            assert!(a.wo == c.wo && a.pdf.to_bits() == c.pdf.to_bits() && a.weight.0 == c.weight.0, "{tag}");
                            assert!(k >= 1, "{tag}: order {k}");
                            if matches!(model, Model::Single | Model::Compensated | Model::FastMsx) {
                                assert_eq!(k, 1, "{tag}");
                            }
                        }
                        _ => panic!("{surface:?} {model:?}: sample and sample_with_order disagree on validity"),
                    }
                }
            }
        }
    }
}

#[test]
fn sampled_order_one_energy_is_single_scattering() {
    // For a perfect mirror, the order-1 energy of every random walk is the
    // single-scattering albedo: E_{m ~ D_ωi}[P(leave | ω_o)], with the exit
    // probability (1 + Λ_i)/(1 + Λ_i + Λ_o) (height-correlated: heitz,
    // invariance, correlated) or 1/(1 + Λ_o) (uncorrelated), computed here by
    // visible-normal sampling. The orders sum to the total energy (1).
    let (alpha, theta) = (0.7f64, 0.9f64);
    let mf = Microfacet::new(Distribution::Beckmann, alpha, alpha);
    let wi = DVec3::new(theta.sin(), 0.0, theta.cos());
    let (mut corr, mut unc) = (common::Stat::default(), common::Stat::default());
    let mut rng = Sampler::new(11);
    for _ in 0..400_000 {
        let (u1, u2) = rng.next2();
        let m = mf.sample_visible(wi, u1, u2).unwrap();
        let wo = msx::microfacet::reflect(wi, m);
        let (li, lo) = (mf.lambda(wi), if wo.z > 0.0 { mf.lambda(wo) } else { f64::INFINITY });
        corr.push(if wo.z > 0.0 { (1.0 + li) / (1.0 + li + lo) } else { 0.0 });
        unc.push(if wo.z > 0.0 { 1.0 / (1.0 + lo) } else { 0.0 });
    }
    let mut ck = Checker::new("sampled order-1 energy");
    let mat = Material::mirror(alpha);
    for model in [Model::Heitz, Model::Invariance, Model::Correlated, Model::Uncorrelated] {
        let b = bsdf(Surface::Conductor, model, Distribution::Beckmann).unwrap();
        let (mut e1, mut all) = (common::Stat::default(), common::Stat::default());
        for _ in 0..200_000 {
            let (s1, u1, u2) = (rng.next(), rng.next(), rng.next());
            let (w, k) = b.sample_with_order(&mat, wi, s1, (u1, u2)).map_or((0.0, 0), |(s, k)| (s.weight.0[0], k));
            e1.push(if k == 1 { w } else { 0.0 });
            all.push(w);
        }
        let expect = if model == Model::Uncorrelated { unc.est() } else { corr.est() };
        ck.close(&format!("{model:?} order 1"), e1.est(), expect, 0.0, 0.0);
        ck.close(&format!("{model:?} all orders"), all.est(), (1.0, 0.0), 0.0, 1e-3);
    }
    ck.finish();
}
