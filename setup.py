"""Build script: compiles the Rust core (staticlib) with cargo and links it
into a cffi API-mode extension, ``msx._native``.

The cffi declarations are generated from ``include/msx.h`` (the cbindgen
header), so the Python side always matches the C ABI that was compiled.
"""

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

# Small C helpers compiled into the extension: they take and return plain
# scalars/structs so that each Python-side call crosses cffi exactly once
# with cheap argument conversion (floats instead of struct construction).
C_HELPERS = r"""
/* Per-instance state: the BSDF handle and the cached material (used when no
   texture varies). */
typedef struct MsxpyInst {
    const MsxBsdf *bsdf;
    MsxMaterial mat;
} MsxpyInst;

/* Flat result structs: one cdata attribute access per value. */
typedef struct MsxpyEvalPdf { float v0, v1, v2, v3, pdf; } MsxpyEvalPdf;
typedef struct MsxpySample { float x, y, z, pdf, w0, w1, w2, w3; uint32_t valid; } MsxpySample;

static MsxpyEvalPdf msxpy_pack_eval_pdf(MsxEvalPdf r) {
    MsxpyEvalPdf o = { r.value.v[0], r.value.v[1], r.value.v[2], r.value.v[3], r.pdf };
    return o;
}
static MsxpyEvalPdf msxpy_pack_eval(MsxSpectrum r) {
    MsxpyEvalPdf o = { r.v[0], r.v[1], r.v[2], r.v[3], 0.0f };
    return o;
}
static MsxpySample msxpy_pack_sample(MsxSample r) {
    MsxpySample o = { r.wo.x, r.wo.y, r.wo.z, r.pdf,
                      r.weight.v[0], r.weight.v[1], r.weight.v[2], r.weight.v[3], r.valid };
    return o;
}

/* `m` is the material evaluated at the hit, or NULL for the cached one. The
   key of an evaluation comes from where it happens (hit position p and uv,
   see msx_call_key), so estimates never depend on the order of the calls. */
static MsxpyEvalPdf msxpy_eval_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
        float wox, float woy, float woz, float px, float py, float pz, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return msxpy_pack_eval_pdf(msx_eval_pdf(s->bsdf, m ? m : &s->mat, wi, wo, msx_call_key(px, py, pz, u, v)));
}
static MsxpyEvalPdf msxpy_eval(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
        float wox, float woy, float woz, float px, float py, float pz, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return msxpy_pack_eval(msx_eval(s->bsdf, m ? m : &s->mat, wi, wo, msx_call_key(px, py, pz, u, v)));
}
static float msxpy_pdf(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
        float wox, float woy, float woz) {
    MsxVec3 wi = { wix, wiy, wiz }, wo = { wox, woy, woz };
    return msx_pdf(s->bsdf, m ? m : &s->mat, wi, wo);
}
static MsxpySample msxpy_sample(MsxpyInst *s, const MsxMaterial *m, float wix, float wiy, float wiz,
        float s1, float u, float v) {
    MsxVec3 wi = { wix, wiy, wiz };
    return msxpy_pack_sample(msx_sample(s->bsdf, m ? m : &s->mat, wi, s1, u, v));
}
"""

C_HELPERS_CDEF = """
typedef struct MsxpyInst { const MsxBsdf *bsdf; MsxMaterial mat; } MsxpyInst;
typedef struct MsxpyEvalPdf { float v0, v1, v2, v3, pdf; } MsxpyEvalPdf;
typedef struct MsxpySample { float x, y, z, pdf, w0, w1, w2, w3; uint32_t valid; } MsxpySample;
MsxpyEvalPdf msxpy_eval_pdf(MsxpyInst *, const MsxMaterial *, float, float, float, float, float, float,
                            float, float, float, float, float);
MsxpyEvalPdf msxpy_eval(MsxpyInst *, const MsxMaterial *, float, float, float, float, float, float,
                        float, float, float, float, float);
float msxpy_pdf(MsxpyInst *, const MsxMaterial *, float, float, float, float, float, float);
MsxpySample msxpy_sample(MsxpyInst *, const MsxMaterial *, float, float, float, float, float, float);
"""

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
    import cffi

    with open(HEADER, encoding="utf-8") as f:
        header = f.read()
    ffi = cffi.FFI()
    ffi.cdef(cdef_from_header(header) + C_HELPERS_CDEF)
    return ffi


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
        ffi.set_source(NATIVE, '#include "msx.h"\n' + C_HELPERS)
        ffi.emit_c_code(c_file)
        for ext in self.extensions:
            if ext.name == NATIVE:
                ext.sources = [c_file]
                ext.include_dirs = [os.path.join(ROOT, "include")]
                ext.extra_objects = [lib]
                ext.libraries = ["pthread", "dl", "m"]
                ext.depends = [lib, HEADER]
        super().run()


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
        with open(path, encoding="utf-8") as f:
            return f.read()
    return "Multiple-scattering microfacet BSDFs for Mitsuba 3."


setup(
    long_description=long_description(),
    long_description_content_type="text/markdown",
    # Sources are filled in by BuildRustThenCffi (generated by cffi).
    ext_modules=[Extension(NATIVE, sources=[])],
    cmdclass={"build_ext": BuildRustThenCffi, "build_py": BuildPyWithData},
)
