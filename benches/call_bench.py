"""Per call: `eval`, `pdf`, `sample` and `eval_pdf` of msx models against Mitsuba's built-in, in `llvm_ad_rgb`.

    python3 benches/call_bench.py [--lanes 21] [--repeats 7] [--models single,auto,correlated]
                                  [--distribution beckmann] [--alpha 0.1] [--mu-min 0.5] [--mu-max 1.0]

2^lanes random ω_i (cos θ_i uniform in [mu-min, mu-max], azimuth uniform) and ω_o (cosine-distributed), or
(sample1, sample2) uniform, evaluated in one wavefront per call; copper, the built-in `roughconductor` with the
same distribution and α (``--surface dielectric``: glass of IOR ``--ior`` against `roughdielectric`, ω_i and ω_o
each flipped below the surface with probability 1/2). The calls are interleaved (every model and the built-in once per repeat, in turn)
and each is timed twice: by the kernels it launches (drjit's kernel history: their execution time, wall
clock, no tracing or compilation: the inputs are evaluated before, the kernel is compiled in an untimed first
call) and by the process's CPU time over the call (tracing included; less sensitive to other work on the
cores). Prints the median time per call and the ratio to the built-in's median; for `auto`, the fraction of
lanes whose ω_i the rule does not reduce to order 1 (none for the default μ range at Beckmann α 0.1). Only
ratios from one run mean anything (benches/README.md).
"""

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lanes", type=int, default=21, help="log2 of the number of lanes")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--models", default="single,auto")
    ap.add_argument("--distribution", default="beckmann")
    ap.add_argument("--alpha", type=float, default=0.1)
    ap.add_argument("--mu-min", type=float, default=0.5)
    ap.add_argument("--mu-max", type=float, default=1.0)
    ap.add_argument("--calls", default="eval,pdf,sample,eval_pdf")
    ap.add_argument("--surface", default="conductor", choices=("conductor", "dielectric"),
                    help="dielectric: glass of IOR --ior against roughdielectric, ω_i and ω_o on both sides")
    ap.add_argument("--ior", type=float, default=1.5)
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register(backend="jit")

    n = 1 << args.lanes
    rng = np.random.default_rng(1)
    mu = rng.uniform(args.mu_min, args.mu_max, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(np.maximum(1 - mu * mu, 0))
    wi = np.stack([s * np.cos(phi), s * np.sin(phi), mu]).astype(np.float32)
    u = rng.random(n)
    phi_o = rng.uniform(0, 2 * np.pi, n)
    so = np.sqrt(u)
    wo = np.stack([so * np.cos(phi_o), so * np.sin(phi_o), np.sqrt(1 - u)]).astype(np.float32)
    su = rng.random((3, n)).astype(np.float32)
    if args.surface == "dielectric":  # ω_i and ω_o each on either side with probability 1/2
        wi[2] *= np.where(rng.random(n) < 0.5, 1.0, -1.0).astype(np.float32)
        wo[2] *= np.where(rng.random(n) < 0.5, 1.0, -1.0).astype(np.float32)

    def vec(a):
        v = mi.Vector3f(*[mi.Float(x) for x in a])
        dr.make_opaque(v)
        return v

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = vec(wi)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    dr.make_opaque(si)
    wo_v = vec(wo)
    s1 = mi.Float(su[0])
    s2 = mi.Point2f(mi.Float(su[1]), mi.Float(su[2]))
    dr.make_opaque(s1, s2)
    ctx = mi.BSDFContext()

    if args.surface == "dielectric":
        common = {"distribution": args.distribution, "alpha": args.alpha, "int_ior": args.ior, "ext_ior": 1.0}
        builtin, surface = "roughdielectric", {"surface": "dielectric"}
    else:
        common = {"distribution": args.distribution, "alpha": args.alpha, "material": "Cu"}
        builtin, surface = "roughconductor", {}
    bsdfs = {"built-in": mi.load_dict({"type": builtin, **common})}
    for m in args.models.split(","):
        bsdfs[m] = mi.load_dict({"type": "msx_posfree", "model": m, **surface, **common})

    calls = {
        "eval": lambda b: (b.eval(ctx, si, wo_v),),
        "pdf": lambda b: (b.pdf(ctx, si, wo_v),),
        "sample": lambda b: (lambda bs, w: (bs.wo, bs.pdf, w))(*b.sample(ctx, si, s1, s2)),
        "eval_pdf": lambda b: b.eval_pdf(ctx, si, wo_v),
    }

    def run(b, call):
        """(the kernels' execution time, the process's CPU time of the call: tracing included) in seconds."""
        dr.kernel_history()  # clears it
        t0 = time.process_time()
        out = calls[call](b)
        dr.eval(*out)
        dr.sync_thread()
        cpu = time.process_time() - t0
        return sum(k.get("execution_time", 0.0) for k in dr.kernel_history()) / 1000.0, cpu

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    if "auto" in bsdfs:
        from msx.jit import auto as jit_auto

        counter = jit_auto.count_calls()
        dr.eval(bsdfs["auto"].eval(ctx, si, wo_v))
        print("auto: %.2f %% of the lanes walk (μ_i in [%.2f, %.2f])"
              % (100 * jit_auto.walked_fraction(counter), args.mu_min, args.mu_max))
        jit_auto.count_calls(stop=True)
    print("lanes 2^%d, %s α %.3g %s, %d repeats, load %s"
          % (args.lanes, args.distribution, args.alpha, "glass η %.3g" % args.ior if args.surface == "dielectric"
             else "Cu", args.repeats, open("/proc/loadavg").read().split()[:3]))
    print("%-10s %-12s %10s %8s %12s %8s" % ("call", "model", "kernel ms", "× built-in", "CPU ms", "× built-in"))
    for call in args.calls.split(","):
        times = {k: [] for k in bsdfs}
        for k, b in bsdfs.items():
            run(b, call)  # compiles
        for _ in range(args.repeats):
            for k, b in bsdfs.items():
                times[k].append(run(b, call))
        ref = [statistics.median(t[i] for t in times["built-in"]) for i in (0, 1)]
        for k in bsdfs:
            t = [statistics.median(x[i] for x in times[k]) for i in (0, 1)]
            print("%-10s %-12s %10.2f %8.2f %12.2f %8.2f" % (call, k, 1000 * t[0], t[0] / ref[0], 1000 * t[1],
                                                            t[1] / ref[1]))
        sys.stdout.flush()


if __name__ == "__main__":
    main()
