//! Proof that `include/msx.h` is consumable from C (docs/testing.md): compiles
//! `tests/c/consumer.c` with the `cc` crate (outside a build script, so the
//! target, host, optimisation level and output directory are set by hand),
//! links it against the staticlib `libmsx.a`, runs it and checks that it
//! printed "ok" and exited with status 0.
//!
//! The staticlib comes from a nested `cargo build --lib` into the same target
//! directory and profile as this test (a no-op when it is up to date; cargo
//! does not hold its build lock while tests run). Building it every time,
//! rather than only when `libmsx.a` is missing, guarantees that the C program
//! never links a stale library from an earlier version of `src/`.
//!
//! A test executable under `<target dir>/debug` was built with the `test`
//! profile, as was the library `cargo test` linked it with: the nested build
//! asks for that profile (`--profile test`) and finds the library up to date.
//! The `dev` profile, whose output shares that folder, would compile the
//! library and its dependencies once more, unoptimised, and overwrite the
//! test profile's `libmsx.rlib` (a library with a `staticlib` or `cdylib`
//! crate type has no profile hash in its file names), so that the next
//! `cargo test` rebuilt the library and relinked every test.

// Lints relaxed for this test file: tuple types of test tables.
#![allow(clippy::type_complexity)]

use std::path::{Path, PathBuf};
use std::process::Command;

const MANIFEST_DIR: &str = env!("CARGO_MANIFEST_DIR");

/// The target triple this test was compiled for (integration tests get no
/// `TARGET` variable, so it is assembled from cfg values).
fn target_triple() -> String {
    if let Ok(t) = std::env::var("TARGET") {
        return t;
    }
    let arch = std::env::consts::ARCH;
    let env = if cfg!(target_env = "gnu") {
        "gnu"
    } else if cfg!(target_env = "musl") {
        "musl"
    } else {
        ""
    };
    if cfg!(target_os = "linux") {
        format!("{arch}-unknown-linux-{env}")
    } else if cfg!(target_os = "macos") {
        format!("{arch}-apple-darwin")
    } else {
        // Good enough for cc's compiler detection on other Unix systems.
        format!("{arch}-unknown-{}", std::env::consts::OS)
    }
}

/// `<target dir>/<profile>` of this very test executable
/// (`<target dir>/<profile>/deps/c_abi-<hash>`).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current_exe");
    exe.parent().and_then(Path::parent).expect("test executable lives in <profile>/deps").to_path_buf()
}

fn target_dir() -> PathBuf {
    match std::env::var_os("CARGO_TARGET_DIR") {
        Some(d) => {
            let d = PathBuf::from(d);
            if d.is_absolute() {
                d
            } else {
                Path::new(MANIFEST_DIR).join(d)
            }
        }
        None => Path::new(MANIFEST_DIR).join("target"),
    }
}

/// Builds the staticlib with a nested cargo and returns its path.
fn staticlib() -> PathBuf {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| option_env!("CARGO").unwrap_or("cargo").to_string());
    let profile_dir = profile_dir();
    let profile = profile_dir.file_name().and_then(|s| s.to_str()).unwrap_or("debug").to_string();
    let mut cmd = Command::new(&cargo);
    cmd.current_dir(MANIFEST_DIR)
        .args(["build", "--lib", "--message-format=json-render-diagnostics"])
        .arg("--manifest-path")
        .arg(Path::new(MANIFEST_DIR).join("Cargo.toml"))
        .arg("--target-dir")
        .arg(target_dir());
    match profile.as_str() {
        "debug" => {
            cmd.args(["--profile", "test"]);
        }
        "release" => {
            cmd.arg("--release");
        }
        other => {
            cmd.args(["--profile", other]);
        }
    }
    // `cargo test --target X` puts the executable under <target dir>/X/<profile>.
    let triple_dir = profile_dir.parent().and_then(Path::file_name).and_then(|s| s.to_str()).map(str::to_string);
    if let Some(t) = triple_dir.filter(|t| t.contains('-') && target_dir().join(t).is_dir()) {
        cmd.args(["--target", &t]);
    }
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run {cargo}: {e}"));
    assert!(out.status.success(), "`cargo build --lib` failed:\n{}", String::from_utf8_lossy(&out.stderr));
    // Find the artifact in cargo's JSON messages ("filenames":[..., ".../libmsx.a", ...]).
    let stdout = String::from_utf8_lossy(&out.stdout);
    let from_json = stdout
        .lines()
        .filter(|l| l.contains("\"reason\":\"compiler-artifact\""))
        .flat_map(|l| l.split('"'))
        .filter(|s| s.ends_with("/libmsx.a"))
        .map(PathBuf::from)
        .next_back();
    let lib = from_json.unwrap_or_else(|| profile_dir.join("libmsx.a"));
    assert!(lib.is_file(), "staticlib not found at {}", lib.display());
    lib
}

#[test]
fn c_program_links_the_staticlib_and_passes() {
    let root = Path::new(MANIFEST_DIR);
    let lib = staticlib();
    let work = profile_dir().join("c_abi");
    std::fs::create_dir_all(&work).unwrap();
    let exe = work.join("consumer");

    let triple = target_triple();
    let compiler = cc::Build::new()
        .target(&triple)
        .host(&triple)
        .opt_level(1)
        .debug(false)
        .cargo_metadata(false)
        .cargo_warnings(false)
        .out_dir(&work)
        .try_get_compiler()
        .expect("no C compiler found by the cc crate");

    let mut cmd = compiler.to_command();
    cmd.args(["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror"])
        .arg("-I")
        .arg(root.join("include"))
        .arg(root.join("tests/c/consumer.c"))
        .arg("-o")
        .arg(&exe)
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm"]);
    let out = cmd.output().unwrap_or_else(|e| panic!("cannot run the C compiler {cmd:?}: {e}"));
    assert!(
        out.status.success(),
        "compiling/linking the C consumer failed ({cmd:?}):\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );

    let run = Command::new(&exe).output().expect("run the C consumer");
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    println!("{stdout}");
    assert!(run.status.success(), "C consumer exited with {}:\n{stdout}\n{stderr}", run.status);
    assert_eq!(run.status.code(), Some(0));
    assert_eq!(stdout.lines().next_back(), Some("ok"), "C consumer output:\n{stdout}\n{stderr}");
    assert!(!stdout.contains("FAIL"), "C consumer reported failures:\n{stdout}");
    assert!(stdout.contains("invalid parameter 'model'"), "error message not printed as expected:\n{stdout}");
}
