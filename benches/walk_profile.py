"""Where a position-free conductor walk's time goes on Fig. 9 (issue 31; benches/README.md, "The GGX conductor
walks on Fig. 9"), in `llvm_ad_rgb`:

    python3 benches/walk_profile.py [frame] [iterations] [parts] [roulette] [--model correlated] [--res 256]
                                    [--spp 32] [--repeats 7] [--lanes 20] [--gains 30,10,3,100]

* ``frame``: Fig. 9 (scenes/fig09_copper_sphere.xml) rendered by the built-in, ``single`` and ``--model`` with
  parts of its calls replaced by order 1's closed forms (jit/auto.py), to attribute the frame's extra time (not
  shippable: the replaced images are wrong): ``no eval walk`` (the value towards the light is order 1's),
  ``no MIS density`` (order 1's density), ``no sample walk`` (``single``'s visible-normal sample, the walks'
  MIS density), ``no walks`` (both walks replaced). One process, one scene alive at a time, interleaved;
  wall and CPU time × the built-in's.
* ``iterations``: the walks' loop iterations per lane and what a packet of 8 or 16 lanes pays (the mean of its
  longest walk: the LLVM backend runs a packet until all its lanes have ended), on 2^lanes directions like
  Fig. 9's (ω_i and ω_o cosine-distributed), GGX α 1, copper.
* ``parts``: the kernel time of the eval and sample walks alone (same lanes) with one part computed twice
  (a second result, from a perturbed argument, merged in at 1e-30 of the first so that the compiler keeps it
  and the walk does not change): the increase is what that part costs.
* ``roulette``: Fig. 9 rendered with the walk's roulette gain (``posfree.RR_NEE_GAIN``, the weight of the
  next-event value in the roulette's importance) at each of ``--gains``: time × the built-in's, and the image
  variance at equal spp (per pixel over 4 seeds, averaged over the image) × the first gain's, so that
  variance × time compares the estimators' efficiency per frame.

Only ratios from one run mean anything (shared machines).
"""

import argparse
import gc
import os
import statistics
import sys
import time

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

# Copper's η and k in RGB as Mitsuba 3.9 gives them (roughconductor, material "Cu", scalar_rgb).
CU_ETA, CU_K = (0.201005, 0.92375, 1.10222), (3.91326, 2.45305, 2.14209)


def load():
    return " ".join(open("/proc/loadavg").read().split()[:3])


def frame(mi, dr, args):
    """The frame's extra time split by replacing parts of the model's calls with order 1's closed forms."""
    from msx._render import scenes_dir
    from msx.jit import auto, mis, single
    from msx.jit import bsdf as engine

    from render_bench import _render

    mode = {"now": "full"}
    eval_pdf, sample = engine.ConductorModel.eval_pdf, engine.ConductorModel.sample

    def eval_pdf_parts(self, call, wi, wo, key, want_value=True, want_pdf=True):
        walk_value = mode["now"] not in ("no eval walk", "no walks")
        walk_pdf = mode["now"] != "no MIS density"
        value, pdf = eval_pdf(self, call, wi, wo, key, want_value and walk_value, want_pdf and walk_pdf)
        if want_value and not walk_value:
            value = auto.order_one_eval(call.mf, call.fresnel, wi, wo) * call.tint_r
        if want_pdf and not walk_pdf:
            pdf = auto.order_one_pdf(call.mf, wi, wo)
        return value, pdf

    def sample_parts(self, call, wi, s1, u1, u2, key):
        if mode["now"] not in ("no sample walk", "no walks"):
            return sample(self, call, wi, s1, u1, u2, key)
        wo, _, weight, valid = single.sample(call.mf, call.fresnel, wi, u1, u2)
        pdf = mis.conductor_pdf(self.walk.exit, self.walk.below, call.mf, wi, wo, self.mis_density)
        return wo, pdf, weight * call.tint_r, valid

    engine.ConductorModel.eval_pdf, engine.ConductorModel.sample = eval_pdf_parts, sample_parts
    path = str(scenes_dir() / "fig09_copper_sphere.xml")
    size = dict(width=str(args.res), height=str(args.res))
    configs = [("built-in", dict(bsdf="roughconductor"), "full"),
               ("single", dict(bsdf="msx_posfree", model="single"), "full")]
    configs += [("%s, %s" % (args.model, m), dict(bsdf="msx_posfree", model=args.model), m)
                for m in ("full", "no eval walk", "no MIS density", "no sample walk", "no walks")]
    wall, cpu = {c[0]: [] for c in configs}, {c[0]: [] for c in configs}
    for rep in range(args.repeats):
        for label, extra, m in configs:
            mode["now"] = m
            scene = mi.load_file(path, **extra, **size)
            _render(mi, dr, scene, 1)  # compiles on the first repeat, a kernel-cache hit after
            t0, c0 = time.perf_counter(), time.process_time()
            _render(mi, dr, scene, args.spp)
            wall[label].append(time.perf_counter() - t0)
            cpu[label].append(time.process_time() - c0)
            del scene
            gc.collect()
    engine.ConductorModel.eval_pdf, engine.ConductorModel.sample = eval_pdf, sample
    print("frame: Fig. 9, %d², %d spp, %d repeats, load %s" % (args.res, args.spp, args.repeats, load()))
    ref_w, ref_c = statistics.median(wall["built-in"]), statistics.median(cpu["built-in"])
    for label, _, _ in configs:
        w, c = statistics.median(wall[label]), statistics.median(cpu[label])
        print("  %-34s wall %7.3f s  × %.2f   CPU %7.3f s  × %.2f" % (label, w, w / ref_w, c, ref_c and c / ref_c))


def roulette(mi, dr, np, args):
    """Time and image variance of Fig. 9 against the roulette's gain (an estimator change: same expectation)."""
    from msx._render import scenes_dir
    from msx.jit import posfree

    from render_bench import _render

    gains = [float(g) for g in args.gains.split(",")]
    shipped, seeds = posfree.RR_NEE_GAIN, 4
    path = str(scenes_dir() / "fig09_copper_sphere.xml")
    size = dict(width=str(args.res), height=str(args.res))
    configs = [("built-in", dict(bsdf="roughconductor"), None)]
    configs += [("gain %g" % g, dict(bsdf="msx_posfree", model=args.model), g) for g in gains]
    wall, var, mean = {c[0]: [] for c in configs}, {}, {}
    try:
        for rep in range(args.repeats + 1):
            for label, extra, gain in configs:
                posfree.RR_NEE_GAIN = shipped if gain is None else gain  # read when the kernel is traced
                scene = mi.load_file(path, **extra, **size)
                if rep == 0:  # the variance, from independent renders (and the kernels compiled)
                    images = np.stack([np.array(mi.render(scene, spp=args.spp, seed=100 + s)) for s in range(seeds)])
                    var[label], mean[label] = images.var(axis=0, ddof=1).mean(), images.mean()
                else:
                    _render(mi, dr, scene, 1)
                    t0 = time.perf_counter()
                    _render(mi, dr, scene, args.spp)
                    wall[label].append(time.perf_counter() - t0)
                del scene
                gc.collect()
    finally:
        posfree.RR_NEE_GAIN = shipped
    print("roulette: %s on Fig. 9, %d², %d spp, %d repeats, variance over %d seeds, load %s"
          % (args.model, args.res, args.spp, args.repeats, seeds, load()))
    ref, first = statistics.median(wall["built-in"]), configs[1][0]
    for label, _, _ in configs:
        w = statistics.median(wall[label])
        print("  %-10s time × %.2f  image mean %.5f  variance %.3e (× %.2f)  variance × time × %.2f" % (
            label, w / ref, mean[label], var[label], var[label] / var[first],
            var[label] * w / (var[first] * statistics.median(wall[first]))))


def lanes(mi, dr, np, n):
    """Fig.-9-like inputs: cosine-distributed ω_i and ω_o, uniform numbers for the sampler, lane keys."""
    rng = np.random.default_rng(3)

    def cosine():
        u, phi = rng.random(n), rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(u)
        xyz = (s * np.cos(phi), s * np.sin(phi), np.sqrt(1 - u))
        return mi.Vector3f(*[mi.Float(x.astype(np.float32)) for x in xyz])

    wi, wo = cosine(), cosine()
    u = [mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)]
    key = mi.UInt32(rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32))
    alpha = mi.Float(1.0)
    eta, k = mi.Spectrum(*CU_ETA), mi.Spectrum(*CU_K)
    dr.make_opaque(wi, wo, key, alpha, eta, k, *u)
    return wi, wo, u, key, alpha, eta, k


def walks(args, mi, dr, np):
    """(the model's walks as callables returning what to evaluate, the msx.jit.walk module)."""
    from msx.jit import posfree, walk
    from msx.jit.microfacet import ConductorFresnel, Microfacet

    wi, wo, u, key, alpha, eta, k = lanes(mi, dr, np, 1 << args.lanes)
    mf, fresnel = Microfacet("ggx", alpha, alpha), ConductorFresnel(eta, k)
    return {"eval": lambda: [posfree.eval_pt(args.model, mf, fresnel, wi, wo, 64, key)],
            "sample": lambda: list(posfree.sample_walk(args.model, mf, fresnel, wi, *u, 64, key)[:2])}, walk


def iterations(mi, dr, np, args):
    """Loop iterations per lane and the longest of each packet, from the walks' vertex index ``j``."""
    fns, walk = walks(args, mi, dr, np)
    loop, last = walk.while_loop, {}

    def keep_state(state, body, label, cond="active"):
        last["state"] = loop(state, body, label, cond)
        return last["state"]

    walk.while_loop = keep_state
    print("iterations: %s, GGX α 1, Cu, 2^%d lanes (ω_i, ω_o cosine-distributed), load %s"
          % (args.model, args.lanes, load()))
    try:
        for call, fn in fns.items():
            dr.eval(fn())
            j = last["state"]["j"].numpy().astype(np.float64)
            packets = "  ".join("packet of %d: %.2f (× %.2f)" % (p, j.reshape(-1, p).max(axis=1).mean(),
                                                                  j.reshape(-1, p).max(axis=1).mean() / j.mean())
                                for p in (8, 16))
            share = np.bincount(j.astype(int), minlength=9)[:9] / j.size
            print("  %-6s per lane %.2f  %s  lanes by iterations 0..8: %s" % (call, j.mean(), packets,
                                                                             " ".join("%.3f" % s for s in share)))
    finally:
        walk.while_loop = loop


def parts(mi, dr, np, args):
    """The walks' kernel time with one part computed twice, × the plain walk's (median of paired ratios)."""
    from msx.jit import microfacet, rng

    fns, _ = walks(args, mi, dr, np)
    mf_cls, fr_cls, stream = microfacet.Microfacet, microfacet.ConductorFresnel, rng.Stream
    plain = {"Fresnel": (fr_cls, "eval"), "D": (mf_cls, "d"), "visible normal": (mf_cls, "sample_visible"),
             "|Λ|": (mf_cls, "abs_lambda"), "stream": (stream, "next2")}
    plain = {name: (cls, attr, getattr(cls, attr)) for name, (cls, attr) in plain.items()}
    nudge = 0.9999999  # a second argument the trace cannot share with the first

    def merged(a, b):
        """a with b merged in at 1e-30 of its size: the compiler must compute b, a does not change in float32."""
        return a + 1e-30 * b

    def twice(name):
        cls, attr, f = plain[name]
        if name == "visible normal":
            def g(self, w, u1, u2):
                (m, ok), (m2, _) = f(self, w, u1, u2), f(self, w, u1 * nudge, u2)
                return merged(m, m2), ok
        elif name == "stream":
            def g(self):
                other = stream(self.key ^ 1, self.counter)
                (a, b), (a2, b2) = f(self), f(other)
                return merged(a, a2), merged(b, b2)
        else:
            def g(self, x):
                return merged(f(self, x), f(self, x * nudge))
        return cls, attr, g

    def timed(fn, variant):
        cls, attr, g = twice(variant) if variant else (None, None, None)
        if cls is not None:
            setattr(cls, attr, g)
        try:
            dr.kernel_history()
            dr.eval(fn())
            dr.sync_thread()
            return sum(k.get("execution_time", 0.0) for k in dr.kernel_history())
        finally:
            if cls is not None:
                setattr(cls, attr, plain[variant][2])

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    print("parts: %s, GGX α 1, Cu, 2^%d lanes, %d repeats, load %s" % (args.model, args.lanes, args.repeats, load()))
    for call, fn in fns.items():
        variants = [None] + list(plain)
        for v in variants:
            timed(fn, v)  # compiles
        times = {v: [] for v in variants}
        for rep in range(args.repeats):
            for v in (variants if rep % 2 == 0 else variants[::-1]):
                times[v].append(timed(fn, v))
        base = statistics.median(times[None])
        print("  %-6s %.1f ms;  %s twice: %s" % (call, base, "/".join(plain), "  ".join(
            "+%.0f %%" % (100 * (statistics.median(a / b for a, b in zip(times[v], times[None])) - 1))
            for v in plain)))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", nargs="*", default=["frame", "iterations", "parts", "roulette"])
    ap.add_argument("--model", default="correlated", choices=("correlated", "uncorrelated"))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--lanes", type=int, default=20)
    ap.add_argument("--gains", default="30,10,3,100")
    args = ap.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register(backend="jit")
    for what in args.what:
        {"frame": lambda: frame(mi, dr, args), "iterations": lambda: iterations(mi, dr, np, args),
         "parts": lambda: parts(mi, dr, np, args), "roulette": lambda: roulette(mi, dr, np, args)}[what]()
        sys.stdout.flush()


if __name__ == "__main__":
    main()
