"""Build-time errors come early and say what is missing: without a C compiler
(or without cargo) the build stops before the long cargo build, with one line
naming the tool."""

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def build_ext(env_changes, tmp_path):
    env = dict(os.environ, **env_changes)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--build-temp", str(tmp_path / "t"),
                        "--build-lib", str(tmp_path / "l")], cwd=ROOT, env=env, capture_output=True, text=True,
                       timeout=600)
    return r, time.perf_counter() - t0


def test_missing_c_compiler_is_named_before_cargo_runs(tmp_path):
    r, took = build_ext({"CC": "/nonexistent/cc"}, tmp_path)
    assert r.returncode != 0
    assert "needs a C compiler" in r.stderr and "/nonexistent/cc" in r.stderr, r.stderr[-2000:]
    assert "Compiling" not in r.stderr  # cargo never started
    print(f"\n[missing compiler] stopped after {took:.1f} s: {r.stderr.strip().splitlines()[-1]}")


def test_missing_cargo_is_named(tmp_path):
    r, _ = build_ext({"CARGO": "", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}, tmp_path)
    assert r.returncode != 0
    assert "needs Rust's `cargo`" in r.stderr, r.stderr[-2000:]
