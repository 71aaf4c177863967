//! Shared by the benches: reading the estimates criterion wrote in this run.

use std::path::PathBuf;
use std::time::SystemTime;

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
