"""Cost of a glass walk's derivative through directions, per call (docs/gradients.md, "Heitz's walk through glass
along moving directions"): ``eval`` through ``mi.BSDFPtr`` on 2¹⁶ lanes under a shading frame tilting with one
parameter t (ω_i outside, ω_o transmitted, Beckmann α 0.5, IOR 1.5), then ``dr.backward`` of the mean to t — the
walk runs once for its value and once per moving direction coordinate (four forward passes). Each msx walk has
``differentiate_directions``; ``roughdielectric`` is the reference. One process, one untimed step per BSDF (it
compiles or loads the kernels), then the BSDFs interleaved over the repeats, median kept; only the ratios mean
anything (shared machine). The step includes the Python-side recording of the symbolic call and its loops.

    python3 benches/glass_direction_bench.py [model ...]    (default: correlated heitz invariance)
"""

import gc
import os
import statistics
import sys
import time

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

mi.set_variant("llvm_ad_rgb")

import msx  # noqa: E402

msx.register(backend="jit")

LANES = 1 << 16
REPEATS = 5


def step(bsdf, ctx):
    """One eval + backward through the tilting frame; returns the derivative (to keep the work alive)."""
    ptr = dr.gather(mi.BSDFPtr, mi.BSDFPtr(bsdf), dr.zeros(mi.UInt32, LANES))
    t = mi.Float(0.1)
    dr.enable_grad(t)
    si = dr.zeros(mi.SurfaceInteraction3f, LANES)
    si.p = mi.Point3f(dr.arange(mi.Float, LANES), 0.0, 0.0)
    frame = mi.Frame3f(mi.Vector3f(dr.sin(t), 0.0 * t, dr.cos(t)))
    si.sh_frame = frame
    si.wi = frame.to_local(dr.normalize(mi.Vector3f(0.5, 0.1, 0.86)) + dr.zeros(mi.Vector3f, LANES))
    f = ptr.eval(ctx, si, frame.to_local(dr.normalize(mi.Vector3f(-0.3, 0.2, -0.9)) + dr.zeros(mi.Vector3f, LANES)))
    dr.backward(dr.sum(f[0]) / LANES)
    return float(dr.grad(t)[0])


def main():
    models = sys.argv[1:] or ["correlated", "heitz", "invariance"]
    bsdfs = {m: mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "int_ior": 1.5, "model": m,
                              "alpha": 0.5, "distribution": "beckmann", "differentiate_directions": True})
             for m in models}
    bsdfs["roughdielectric"] = mi.load_dict({"type": "roughdielectric", "int_ior": 1.5, "alpha": 0.5,
                                             "distribution": "beckmann"})
    ctx = mi.BSDFContext()
    for b in bsdfs.values():
        step(b, ctx)
    times = {k: [] for k in bsdfs}
    for _ in range(REPEATS):
        for k, b in bsdfs.items():
            gc.collect()
            t0 = time.perf_counter()
            step(b, ctx)
            times[k].append(time.perf_counter() - t0)
    base = statistics.median(times["roughdielectric"])
    print("load average (1, 5, 15 min): %.2f %.2f %.2f" % os.getloadavg())
    for k, v in times.items():
        print("%-16s median %.3f s  %.1f x roughdielectric" % (k, statistics.median(v), statistics.median(v) / base))


if __name__ == "__main__":
    main()
