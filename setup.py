"""Build script: compiles the Rust core (staticlib) with cargo and links it
into a cffi API-mode extension, ``msx._native``.

The cffi declarations are generated from ``include/msx.h`` (the cbindgen
header) and ``csrc/msxpy_helpers.h`` (the scalar route's C helpers, compiled
into the extension from ``csrc/msxpy_helpers.c``), so the Python side always
matches the C that was compiled. Why setuptools with this script and not
maturin or setuptools-rust, and how a release builds its wheels:
docs/building.md.
"""

import glob
import os
import re
import shutil
import subprocess
import sys
import sysconfig

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = os.path.dirname(os.path.abspath(__file__))
HEADER = os.path.join(ROOT, "include", "msx.h")
NATIVE = "msx._native"

# The scalar route's C helpers (csrc/): compiled into the extension; their cffi
# declarations are derived from the header, like the core's.
CSRC = os.path.join(ROOT, "csrc")
HELPERS_HEADER = os.path.join(CSRC, "msxpy_helpers.h")
HELPERS_SOURCE = os.path.join(CSRC, "msxpy_helpers.c")

_INT_DEFINE = re.compile(r"^#define\s+(MSX_\w+)\s+(-?(?:0x[0-9a-fA-F]+|\d+))[uUlL]*\s*$")
_FLOAT_DEFINE = re.compile(r"^#define\s+(MSX_\w+)\s+([-+0-9.eE]+)[fF]?\s*$")


def cdef_from_header(text):
    """cffi declarations from the cbindgen header.

    Comments and preprocessor lines that cffi cannot parse are removed.
    Integer ``#define MSX_*`` constants are kept (cffi supports them); float
    ones become ``static const double`` (their values are read from the C
    compiler when the API-mode extension is built).
    """
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    # `#ifdef __cplusplus` blocks only hold `extern "C" {` and its `}`.
    text = re.sub(r"^\s*#ifdef\s+__cplusplus\s*$.*?^\s*#endif\s*$", "", text, flags=re.S | re.M)
    out = []
    for line in text.splitlines():
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            m = _INT_DEFINE.match(s)
            if m:
                out.append("#define %s %s" % (m.group(1), m.group(2)))
                continue
            m = _FLOAT_DEFINE.match(s)
            if m:
                out.append("static const double %s;" % m.group(1))
            continue  # #ifndef / #define MSX_H / #include / #endif
        out.append(line)
    return "\n".join(out) + "\n"


def make_ffi():
    """The cffi declarations: the core's header, then the helpers' (which use the core's types)."""
    import cffi

    ffi = cffi.FFI()
    ffi.cdef("".join(cdef_from_header(read(path)) for path in (HEADER, HELPERS_HEADER)))
    return ffi


def read(path):
    with open(path, encoding="utf-8") as f:
        return f.read()


def find_cargo():
    cargo = os.environ.get("CARGO") or shutil.which("cargo")
    if cargo is None:
        home_cargo = os.path.expanduser("~/.cargo/bin/cargo")
        cargo = home_cargo if os.path.exists(home_cargo) else None
    if cargo is None:
        sys.exit("error: building msx needs Rust's `cargo` on PATH (install it from https://rustup.rs)")
    return cargo


def check_c_toolchain(compiler):
    """Fails early (before the long cargo build) without a C compiler or Python's headers."""
    exe = (getattr(compiler, "compiler_so", None) or getattr(compiler, "compiler", None) or ["cc"])[0]
    if shutil.which(exe) is None:
        sys.exit(
            "error: building msx needs a C compiler (looked for %r, from the CC variable or Python's build "
            "configuration); on Debian/Ubuntu: apt-get install gcc" % exe
        )
    include = sysconfig.get_paths().get("include") or ""
    if not os.path.exists(os.path.join(include, "Python.h")):
        sys.exit(
            "error: building msx needs Python's C headers (Python.h not found in %r); on Debian/Ubuntu: "
            "apt-get install python3-dev" % include
        )


class BuildRustThenCffi(build_ext):
    """Runs ``cargo build --release --lib`` and generates the cffi C source
    before the normal extension build."""

    def cargo_target_dir(self):
        d = os.environ.get("CARGO_TARGET_DIR")
        if d:
            return d if os.path.isabs(d) else os.path.join(ROOT, d)
        # Beside setuptools' own intermediate files (build/), reused by later builds.
        return os.path.join(os.path.abspath(self.build_temp), "..", "cargo")

    def run(self):
        cargo = find_cargo()
        from setuptools._distutils.ccompiler import new_compiler
        from setuptools._distutils.sysconfig import customize_compiler

        compiler = new_compiler(compiler=self.compiler)
        customize_compiler(compiler)
        check_c_toolchain(compiler)
        target = os.path.normpath(self.cargo_target_dir())
        cmd = [cargo, "build", "--release", "--lib", "--manifest-path", os.path.join(ROOT, "Cargo.toml"),
               "--target-dir", target]
        self.announce("running " + " ".join(cmd), level=2)
        subprocess.check_call(cmd, cwd=ROOT)
        lib = os.path.join(target, "release", "libmsx.a")
        if not os.path.exists(lib):
            sys.exit("error: cargo did not produce %s" % lib)

        ffi = make_ffi()
        src_dir = os.path.join(self.build_temp, "msx_cffi")
        os.makedirs(src_dir, exist_ok=True)
        c_file = os.path.join(src_dir, "_native.c")
        ffi.set_source(NATIVE, '#include "msx.h"\n#include "msxpy_helpers.h"\n')
        ffi.emit_c_code(c_file)
        for ext in self.extensions:
            if ext.name == NATIVE:
                ext.sources = [c_file, os.path.relpath(HELPERS_SOURCE)]
                ext.include_dirs = [os.path.join(ROOT, "include"), CSRC]
                ext.extra_objects = [lib]
                ext.libraries = ["pthread", "dl", "m"]
                ext.depends = [lib, HEADER, HELPERS_HEADER]
        super().run()
        self.remove_stale_builds()

    def remove_stale_builds(self):
        """Removes the extension built under another file name by an earlier build in the same folder (e.g.
        ``_native.cpython-311-x86_64-linux-gnu.so`` beside ``_native.abi3.so``): it would be shipped with the
        new one, and Python, which tries the version-specific suffix first, would import the stale one."""
        current = self.get_ext_fullpath(NATIVE)
        for path in glob.glob(os.path.join(os.path.dirname(current), "_native.*")):
            if path.endswith((".so", ".pyd", ".dylib")) and os.path.basename(path) != os.path.basename(current):
                self.announce("removing the stale build %s" % path, level=2)
                os.remove(path)


class BuildPyWithData(build_py):
    """Ships, inside the package: the scene files (``msx/scenes``), so that
    ``msx compare`` works from an installed wheel, not only from a checkout;
    and the native plugin's C++ source with the C header (``msx/native``),
    which msx compiles on first use against the installed Mitsuba."""

    def run(self):
        super().run()
        src = os.path.join(ROOT, "scenes")
        if os.path.isdir(src):
            dst = os.path.join(self.build_lib, "msx", "scenes")
            shutil.rmtree(dst, ignore_errors=True)
            shutil.copytree(src, dst, ignore=shutil.ignore_patterns("assets"))  # generated on demand
        native = os.path.join(self.build_lib, "msx", "native")
        os.makedirs(native, exist_ok=True)
        shutil.copy2(os.path.join(ROOT, "native", "msx_mitsuba.cpp"), native)
        shutil.copy2(HEADER, native)


def long_description():
    path = os.path.join(ROOT, "README.md")
    if os.path.exists(path):
        return read(path)
    return "Multiple-scattering microfacet BSDFs for Mitsuba 3."


# cffi's generated C defines Py_LIMITED_API (CPython's stable ABI) unless the interpreter is a debug or
# free-threaded build: there the extension is tagged abi3, so one wheel serves every CPython from the
# oldest that requires-python allows (docs/building.md).
LIMITED_API = not (hasattr(sys, "gettotalrefcount") or sysconfig.get_config_var("Py_GIL_DISABLED"))

setup(
    long_description=long_description(),
    long_description_content_type="text/markdown",
    # Sources are filled in by BuildRustThenCffi (generated by cffi).
    ext_modules=[Extension(NATIVE, sources=[], py_limited_api=LIMITED_API)],
    options={"bdist_wheel": {"py_limited_api": "cp39"}} if LIMITED_API else {},
    cmdclass={"build_ext": BuildRustThenCffi, "build_py": BuildPyWithData},
)
