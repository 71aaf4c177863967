"""Per-call cost of the scalar route's crossing into the Rust core: cffi API mode (what msx builds: the
extension ``msx._native`` with the C helpers of csrc/) against cffi ABI mode (what maturin's
``bindings = "cffi"`` builds: ``ffi.dlopen`` of the crate's cdylib with declarations from cffi's
``recompiler.make_py_source``, and no C of our own, so the helpers cannot exist there).

One ``eval_pdf`` of the Fig. 9 conductor (GGX α = 1, ``correlated``), written as each route's Python code
would call it per BSDF call, results read back as floats:

- api: ``lib.msxpy_eval_pdf(inst, NULL, 13 floats)`` -> ``r.v0, r.v1, r.v2, r.pdf`` (msx/plugin/scalar.py today);
- abi: ``key = lib.msx_call_key(p, uv)`` then ``lib.msx_eval_pdf(bsdf, mat, (wi), (wo), key)`` with the two
  MsxVec3 passed by value from tuples -> ``r.value.v[0..2], r.pdf``;
- abi_core_only: the same ABI call with the key computed once outside the loop (a lower bound for ABI mode
  if the key moved into the core's signature);
- scalar_route (context): the whole call as Mitsuba's Python API makes it, ``bsdf.eval_pdf(ctx, si, wo)`` on
  ``msx_posfree`` in ``scalar_rgb`` with the Python back end (material Cu: not compared with the others).

Each variant runs ``--calls`` calls per repeat; the variants are interleaved over ``--repeats`` repeats and
the per-call medians (and the ratios against ``api`` in the same repeat) are printed. It needs the crate's
cdylib: ``cargo build --release --lib`` (target/release/libmsx.so) or ``--cdylib PATH``.

``--render RES``: also renders the Fig. 9 scene (``model=correlated``) in ``scalar_rgb`` with the Python back
end on one thread at RES×RES and ``--spp``, counts the crossings a render makes (eval and eval_pdf, which
take the key, and pdf and sample, which do not) and prints what ABI mode would add to it, estimated as
crossings × the measured per-call differences (abi - api for the first, abi_core_only - api for the others).

    python3 benches/cffi_mode_bench.py [--calls 200000] [--repeats 9] [--cdylib target/release/libmsx.so]
                                       [--render 32 --spp 4]
"""

import argparse
import os
import re
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def abi_cdef(header_text):
    """The core's header as ABI-mode declarations: comments, the C++ guard and preprocessor lines removed;
    integer MSX_* defines kept; float ones dropped (ABI mode cannot read a constant's value from the compiler,
    which is how setup.py's API mode gets them)."""
    text = re.sub(r"/\*.*?\*/", "", header_text, flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r"^\s*#ifdef\s+__cplusplus\s*$.*?^\s*#endif\s*$", "", text, flags=re.S | re.M)
    out = []
    for line in text.splitlines():
        m = re.match(r"^#define\s+(MSX_\w+)\s+(-?(?:0x[0-9a-fA-F]+|\d+))[uUlL]*\s*$", line.strip())
        if m:
            out.append("#define %s %s" % m.groups())
        elif line.strip() and not line.strip().startswith("#"):
            out.append(line)
    return "\n".join(out) + "\n"


def load_abi(cdylib):
    """maturin's cffi route: make_py_source from the header, then ffi.dlopen of the cdylib."""
    import importlib.util

    import cffi
    from cffi import recompiler

    ffi = cffi.FFI()
    with open(os.path.join(ROOT, "include", "msx.h"), encoding="utf-8") as f:
        ffi.cdef(abi_cdef(f.read()))
    d = tempfile.mkdtemp(prefix="msx_abi_")
    recompiler.make_py_source(ffi, "msx_abi_ffi", os.path.join(d, "msx_abi_ffi.py"))
    spec = importlib.util.spec_from_file_location("msx_abi_ffi", os.path.join(d, "msx_abi_ffi.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.ffi, mod.ffi.dlopen(cdylib)


def make_bsdf(ffi, lib):
    params = ffi.new("MsxParams *", dict(surface=lib.MSX_SURFACE_CONDUCTOR, distribution=lib.MSX_DISTRIBUTION_GGX,
                                         model=lib.MSX_MODEL_CORRELATED, estimator=lib.MSX_ESTIMATOR_PT,
                                         max_bounces=0, channels=3, seed=0))
    out = ffi.new("MsxBsdf **")
    err = ffi.new("char[]", 256)
    if lib.msx_bsdf_new(params, out, err, 256) != lib.MSX_OK:
        sys.exit(ffi.string(err).decode())
    mat = ffi.new("MsxMaterial *", dict(alpha_u=1.0, alpha_v=1.0, eta=[0.2, 0.92, 1.1, 1.1], k=[3.9, 2.45, 2.14, 2.14],
                                        specular_reflectance=[1.0] * 4, ior=1.5, specular_transmittance=[1.0] * 4,
                                        reflectance=[1.0] * 4, mode=lib.MSX_MODE_RADIANCE))
    return ffi.gc(out[0], lib.msx_bsdf_free), mat


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=200000)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--cdylib", default=os.path.join(ROOT, "target", "release", "libmsx.so"))
    ap.add_argument("--render", type=int, default=0, metavar="RES")
    ap.add_argument("--spp", type=int, default=4)
    a = ap.parse_args()
    if not os.path.exists(a.cdylib):
        sys.exit(f"no cdylib at {a.cdylib}: run `cargo build --release --lib` or pass --cdylib")

    from msx._native import ffi as api_ffi
    from msx._native import lib as api_lib

    abi_ffi, abi_lib = load_abi(a.cdylib)
    api_bsdf, api_mat = make_bsdf(api_ffi, api_lib)
    abi_bsdf, abi_mat = make_bsdf(abi_ffi, abi_lib)
    inst = api_ffi.new("MsxpyInst *")
    inst.bsdf, inst.mat = api_bsdf, api_mat[0]

    wi, wo, p, uv = (0.3, 0.1, 0.948683), (-0.2, 0.15, 0.968246), (0.25, -0.5, 1.0), (0.3, 0.6)
    n = a.calls

    def api():
        f, NULL = api_lib.msxpy_eval_pdf, api_ffi.NULL
        t0 = time.perf_counter()
        for _ in range(n):
            r = f(inst, NULL, wi[0], wi[1], wi[2], wo[0], wo[1], wo[2], p[0], p[1], p[2], uv[0], uv[1])
            out = (r.v0, r.v1, r.v2, r.pdf)
        return (time.perf_counter() - t0) / n, out

    def abi():
        f, key_of = abi_lib.msx_eval_pdf, abi_lib.msx_call_key
        t0 = time.perf_counter()
        for _ in range(n):
            key = key_of(p[0], p[1], p[2], uv[0], uv[1])
            r = f(abi_bsdf, abi_mat, (wi[0], wi[1], wi[2]), (wo[0], wo[1], wo[2]), key)
            v = r.value.v
            out = (v[0], v[1], v[2], r.pdf)
        return (time.perf_counter() - t0) / n, out

    def abi_core_only():
        f = abi_lib.msx_eval_pdf
        key = abi_lib.msx_call_key(p[0], p[1], p[2], uv[0], uv[1])
        t0 = time.perf_counter()
        for _ in range(n):
            r = f(abi_bsdf, abi_mat, (wi[0], wi[1], wi[2]), (wo[0], wo[1], wo[2]), key)
            v = r.value.v
            out = (v[0], v[1], v[2], r.pdf)
        return (time.perf_counter() - t0) / n, out

    import mitsuba as mi

    import msx

    mi.set_variant("scalar_rgb")
    msx.register(backend="python")
    bsdf = mi.load_dict(dict(type="msx_posfree", material="Cu", distribution="ggx", alpha=1.0, model="correlated"))
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.wi, si.p, si.uv = mi.Vector3f(wi), mi.Point3f(p), mi.Point2f(uv)
    mwo = mi.Vector3f(wo)

    def scalar_route():
        f = bsdf.eval_pdf
        t0 = time.perf_counter()
        for _ in range(n):
            out = f(ctx, si, mwo)
        return (time.perf_counter() - t0) / n, out

    variants = dict(api=api, abi=abi, abi_core_only=abi_core_only, scalar_route=scalar_route)
    results = {k: f()[1] for k, f in variants.items()}
    results.pop("scalar_route")  # warm-up; same inputs must give the same values
    ref = results["api"]
    for k, out in results.items():
        if any(abs(x - y) > 1e-6 * max(1.0, abs(y)) for x, y in zip(out, ref)):
            sys.exit(f"{k} gives {out}, api gives {ref}: not the same computation")
    times = {k: [] for k in variants}
    for _ in range(a.repeats):
        for k, f in variants.items():
            times[k].append(f()[0])
    print(f"{n} calls x {a.repeats} repeats, interleaved; per call (median [min, max]) and ratio to api (median of "
          f"per-repeat ratios)")
    for k, ts in times.items():
        ratios = [t / b for t, b in zip(ts, times["api"])]
        print(f"  {k:14s} {statistics.median(ts) * 1e6:7.3f} us  [{min(ts) * 1e6:.3f}, {max(ts) * 1e6:.3f}]  "
              f"x{statistics.median(ratios):.2f}")
    if a.render:
        keyed = statistics.median([x - y for x, y in zip(times["abi"], times["api"])])
        unkeyed = statistics.median([x - y for x, y in zip(times["abi_core_only"], times["api"])])
        render_estimate(mi, a.render, a.spp, a.repeats, keyed, unkeyed)


def render_estimate(mi, res, spp, repeats, keyed, unkeyed):
    """The Fig. 9 render on the scalar route, its crossings counted, and what ABI mode would add to it."""
    import collections

    import drjit as dr

    from msx._render import scenes_dir

    dr.set_thread_count(1)
    scene = mi.load_file(str(scenes_dir() / "fig09_copper_sphere.xml"), bsdf="msx_posfree", model="correlated",
                         width=str(res), height=str(res))
    mi.render(scene, spp=1)  # warm-up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        mi.render(scene, spp=spp)
        ts.append(time.perf_counter() - t0)
    t = statistics.median(ts)
    [cls] = {type(s.bsdf()) for s in scene.shapes() if type(s.bsdf()).__module__.startswith("msx")}
    counts = collections.Counter()
    originals = {m: cls.__dict__[m] for m in ("eval", "pdf", "eval_pdf", "sample") if m in cls.__dict__}

    def counted(name, f):
        def g(self, *args, **kwargs):
            counts[name] += 1
            return f(self, *args, **kwargs)
        return g

    for name, f in originals.items():
        setattr(cls, name, counted(name, f))
    try:
        mi.render(scene, spp=spp)  # counted, not timed
    finally:
        for name, f in originals.items():
            setattr(cls, name, f)
    n_keyed, n_unkeyed = counts["eval"] + counts["eval_pdf"], counts["pdf"] + counts["sample"]
    extra = n_keyed * keyed + n_unkeyed * unkeyed
    print(f"render {res}x{res}, {spp} spp, scalar_rgb, Python back end, 1 thread: {t:.3f} s (median of {repeats}); "
          f"crossings {dict(counts)}, {t / max(1, n_keyed + n_unkeyed) * 1e6:.2f} us of render per crossing; "
          f"ABI mode would add ~{extra:.3f} s (+{100 * extra / t:.0f} %)")


if __name__ == "__main__":
    main()
