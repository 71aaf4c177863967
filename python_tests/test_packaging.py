"""Packaging: build-time errors come early and say what is missing (without a C
compiler, or without cargo, the build stops before the long cargo build, with
one line naming the tool); the scalar route's C helpers (csrc/) agree with the
extension that was built from them. docs/building.md describes the build."""

import os
import re
import subprocess
import sys
import sysconfig
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


HELPERS_H = ROOT / "csrc" / "msxpy_helpers.h"
HELPERS_C = ROOT / "csrc" / "msxpy_helpers.c"


def _without_comments(text):
    return re.sub(r"//[^\n]*", "", re.sub(r"/\*.*?\*/", "", text, flags=re.S))


def _c_type(decl):
    """The C type of one parameter's declaration (``const MsxMaterial *m`` -> ``const MsxMaterial *``)."""
    return re.sub(r"\s*\b\w+$", "", decl.strip())


def _helper_functions(text):
    """{name: (result type, [parameter types])} of the msxpy_* prototypes (or definitions) in C text."""
    out = {}
    for result, name, params in re.findall(r"^(\w[\w ]*?)\s+(msxpy_\w+)\s*\(([^)]*)\)", _without_comments(text),
                                           flags=re.M):
        out[name] = (result.strip(), [_c_type(p) for p in params.split(",")])
    return out


def test_c_helpers_header_source_and_extension_agree():
    """csrc/msxpy_helpers.h declares what msxpy_helpers.c defines, and the installed extension's cffi
    declarations (derived from the header by setup.py) expose exactly those functions and structs."""
    from msx._native import ffi, lib

    header, source = HELPERS_H.read_text(), HELPERS_C.read_text()
    declared, defined = _helper_functions(header), _helper_functions(source)
    assert declared, "no msxpy_* prototype found in csrc/msxpy_helpers.h"
    assert declared == defined, (declared, defined)
    assert sorted(n for n in dir(lib) if n.startswith("msxpy_")) == sorted(declared)
    for name, (result, params) in declared.items():
        t = ffi.typeof(getattr(lib, name))
        assert t.result is ffi.typeof(result) and list(t.args) == [ffi.typeof(p) for p in params], (name, t.cname)
    structs = re.findall(r"typedef struct (\w+) \{(.*?)\} \1;", _without_comments(header), flags=re.S)
    assert {s for s, _ in structs} == {"MsxpyInst", "MsxpyEvalPdf", "MsxpySample"}
    for struct, body in structs:
        fields = [n.strip().lstrip("*") for decl in body.split(";") if decl.strip()
                  for n in re.sub(r"^\s*(const\s+)?\w+\s*\**", "", decl).split(",")]
        assert [f for f, _ in ffi.typeof(struct).fields] == fields, struct


def test_sdist_carries_the_sources_and_its_wheel_the_scenes(tmp_path):
    """`python -m build --sdist`, then a wheel built from that sdist (as pip builds it on a user's machine):
    the sdist holds what the build reads (the crate, the headers, the C helpers, the native plugin's source,
    the scenes); the wheel holds the package, one extension file (abi3), the scenes and the native plugin's
    sources (docs/building.md)."""
    import tarfile
    import zipfile

    r = subprocess.run([sys.executable, "-m", "build", "--sdist", "-o", str(tmp_path), str(ROOT)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    [sdist] = tmp_path.glob("msx-*.tar.gz")
    with tarfile.open(sdist) as t:
        names = {n.split("/", 1)[1] for n in t.getnames() if "/" in n}
    for need in ("setup.py", "pyproject.toml", "Cargo.toml", "Cargo.lock", "src/lib.rs", "include/msx.h",
                 "csrc/msxpy_helpers.h", "csrc/msxpy_helpers.c", "native/msx_mitsuba.cpp",
                 "scenes/fig09_copper_sphere.xml", "mitsuba_plugin/msx/__init__.py"):
        assert need in names, f"{need} is not in the sdist"
    env = {k: v for k, v in os.environ.items() if k != "CARGO_TARGET_DIR"}  # cargo builds inside the unpacked sdist
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--disable-pip-version-check",
                        "--progress-bar", "off", "-w", str(tmp_path / "wheel"), str(sdist)],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, (r.stdout + r.stderr)[-2000:]
    [wheel] = (tmp_path / "wheel").glob("msx-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
    natives = [n for n in names if n.startswith("msx/_native.")]
    assert len(natives) == 1, natives
    if not (hasattr(sys, "gettotalrefcount") or sysconfig.get_config_var("Py_GIL_DISABLED")):  # setup.py's rule
        assert natives == ["msx/_native.abi3.so"] and "-cp39-abi3-" in wheel.name, (natives, wheel.name)
    for need in ("msx/__init__.py", "msx/jit/__init__.py", "msx/plugin/__init__.py", "msx/microgeometry/__init__.py",
                 "msx/scenes/fig09_copper_sphere.xml",
                 "msx/native/msx_mitsuba.cpp", "msx/native/msx.h"):
        assert need in names, f"{need} is not in the wheel"
    assert not any(n.startswith(("csrc/", "src/", "msx/scenes/assets/")) for n in names)
