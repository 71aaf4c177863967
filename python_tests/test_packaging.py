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
    """Builds the wheel as a user does (`pip wheel .`, so setuptools comes from the build requirements in
    pyproject.toml, not from the environment) with `env_changes` applied."""
    env = dict(os.environ, **env_changes)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--disable-pip-version-check",
                        "--progress-bar", "off", "-v", "-w", str(tmp_path / "wheel"), str(ROOT)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    # pip reports the build's own output on stdout (-v) and its failure on stderr: read both.
    r.stderr = r.stdout + r.stderr
    return r, time.perf_counter() - t0


def test_missing_c_compiler_is_named_before_cargo_runs(tmp_path):
    r, took = build_ext({"CC": "/nonexistent/cc"}, tmp_path)
    assert r.returncode != 0
    assert "needs a C compiler" in r.stderr and "/nonexistent/cc" in r.stderr, r.stderr[-2000:]
    assert "Compiling" not in r.stderr  # cargo never started
    named = next(ln for ln in r.stderr.splitlines() if "needs a C compiler" in ln)
    print(f"\n[missing compiler] stopped after {took:.1f} s: {named.strip()}")


def test_missing_cargo_is_named(tmp_path):
    r, _ = build_ext({"CARGO": "", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}, tmp_path)
    assert r.returncode != 0
    assert "needs Rust's `cargo`" in r.stderr, r.stderr[-2000:]
