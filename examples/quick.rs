use glam::DVec3;
use msx::rng::Sampler;
use msx::*;
fn main() {
    for dist in [Distribution::Ggx, Distribution::Beckmann] {
        for model in [Model::Single, Model::Uncorrelated, Model::Correlated] {
            for &alpha in &[0.05, 0.3, 1.0, 1.5] {
                for &th in &[0.0f64, 1.0, 1.45] {
                    let b = Bsdf::new(Config { model, distribution: dist, ..Default::default() }).unwrap();
                    let mat = Material::mirror(alpha);
                    let wi = DVec3::new(th.sin(), 0.0, th.cos());
                    let mut rng = Sampler::new(7);
                    let n = 200000;
                    let (mut s_eval, mut s_w) = (0.0, 0.0);
                    for i in 0..n {
                        // cosine-weighted wo
                        let (u1, u2) = rng.next2();
                        let r = u1.sqrt();
                        let phi = 2.0 * std::f64::consts::PI * u2;
                        let wo = DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
                        let v = b.eval(&mat, wi, wo, i as u64).0[0];
                        s_eval += v / (wo.z / std::f64::consts::PI);
                        let (a, bb, c) = (rng.next(), rng.next(), rng.next());
                        if let Some(s) = b.sample(&mat, wi, a, (bb, c)) {
                            s_w += s.weight.0[0];
                        }
                    }
                    println!("{:?} {:?} a={alpha} th={th}: eval-albedo {:.4} sample-albedo {:.4}", dist, model, s_eval / n as f64, s_w / n as f64);
                }
            }
        }
    }
}
