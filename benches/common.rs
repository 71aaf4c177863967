//! Shared by the benches: the fixed directions' generator, the copper
//! material, reading the estimates criterion wrote in this run.

use glam::DVec3;
use msx::{Material, Spectrum};
use std::path::PathBuf;
use std::time::SystemTime;

/// Copper's complex IOR (RGB).
const CU_ETA: [f64; 3] = [0.200438, 0.924033, 1.10221];
const CU_K: [f64; 3] = [3.91295, 2.45285, 2.14219];

/// The conductor of the benches: copper at roughness `alpha`.
pub fn copper(alpha: f64) -> Material {
    let mut cu = Material::mirror(alpha);
    cu.eta = Spectrum([CU_ETA[0], CU_ETA[1], CU_ETA[2], 0.0]);
    cu.k = Spectrum([CU_K[0], CU_K[1], CU_K[2], 1.0]);
    cu
}

/// SplitMix64: the set of directions is identical in every run.
pub struct Rng(pub u64);

impl Rng {
    pub fn f(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in cos θ on the upper hemisphere (cos θ in (0, 1]).
    pub fn hemisphere(&mut self) -> DVec3 {
        let z = 1.0 - self.f();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = std::f64::consts::TAU * self.f();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

fn criterion_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("CRITERION_HOME") {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("CARGO_TARGET_DIR") {
        return PathBuf::from(d).join("criterion");
    }
    // <target>/<profile>/deps/<bench>-<hash>
    std::env::current_exe()
        .ok()
        .and_then(|e| e.parent()?.parent()?.parent().map(|t| t.join("criterion")))
        .unwrap_or_else(|| PathBuf::from("target/criterion"))
}

/// Time per criterion iteration (ns) estimated in this run: the slope estimate
/// if present, else the mean; None if the benchmark was filtered out (no
/// estimates written since `since`).
pub fn estimate_ns(group: &str, function: &str, since: SystemTime) -> Option<f64> {
    let path = criterion_dir().join(group).join(function).join("new/estimates.json");
    if std::fs::metadata(&path).ok()?.modified().ok()? < since {
        return None;
    }
    let json = std::fs::read_to_string(&path).ok()?;
    let point = |key: &str| -> Option<f64> {
        let rest = &json[json.find(&format!("\"{key}\":{{"))?..];
        let rest = &rest[rest.find("\"point_estimate\":")? + "\"point_estimate\":".len()..];
        let end = rest.find([',', '}'])?;
        rest[..end].trim().parse().ok()
    };
    point("slope").or_else(|| point("mean"))
}
