"""The glass walks of the Dr.Jit engine per call, in `llvm_ad_rgb` (issue 31; benches/README.md, "`invariance`
through glass, second pass"):

    python3 benches/glass_walk_profile.py [--models invariance,heitz,correlated] [--lanes 20] [--alpha 0.6]
                                          [--repeats 4]

For each walk's ``eval`` and ``sample`` on 2^lanes random ω_i and ω_o (each on either side, Beckmann α
``--alpha``, η 1.5, one wavefront, as benches/glass_ab_bench.py): the CPU time per call (the median of the
repeats after the first, which compiles), the kernel's static operation count (``dr.kernel_history()``) and,
for every ``walk.while_loop`` the call runs, its iterations per lane, the largest, and what a packet of 8 or
16 lanes pays — the mean over packets of their longest lane's iterations (the LLVM backend runs a packet's
loop until all its lanes have ended) — and the share of lanes that enter the loop. The iterations are counted
by a counter added to each loop's state (the walk's values are unchanged). Only ratios from one run mean
anything (shared machines).
"""

import argparse
import os
import statistics
import time

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--models", default="invariance,heitz,correlated")
    ap.add_argument("--lanes", type=int, default=20)
    ap.add_argument("--alpha", type=float, default=0.6)
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    from msx.jit import bsdf as jit_bsdf
    from msx.jit import walk

    counted = []  # (label, iterations per lane) of every loop traced in the current call
    plain_loop = walk.while_loop

    def counting_loop(state, body, label, cond="active"):
        state = dict(state, n_iterations=mi.UInt32(0))

        def counted_body(n_iterations, **s):
            return dict(body(**s), n_iterations=n_iterations + 1)

        out = plain_loop(state, counted_body, label, cond)
        counted.append((label, out.pop("n_iterations")))
        return out

    walk.while_loop = counting_loop  # the walks call it through the module

    from glass_ab_bench import glass_calls

    wi, wo, key, s, mf, eta = glass_calls(1 << args.lanes, args.alpha)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    print("2^%d lanes, Beckmann α %g, load %s" % (args.lanes, args.alpha, open("/proc/loadavg").read().split()[:3]))
    print("| walk | call | CPU ms | kernel ops | loop | iterations per lane (max) | per 8-lane packet | "
          "per 16-lane packet | lanes in the loop |\n|---|---|---|---|---|---|---|---|---|")
    for m in [m for m in args.models.split(",") if m]:
        w = jit_bsdf.DIELECTRIC_WALKS[m]
        calls = {"eval": lambda: w.eval_pt(mf, eta, True, wi, wo, 64, key),
                 "sample": lambda: w.sample_walk(mf, eta, True, wi, s[0], s[1], s[2], 64, key)[0]}
        for call, f in calls.items():
            times = []
            for _ in range(args.repeats):
                counted.clear()
                dr.kernel_history()  # empties it
                t0 = time.process_time()
                dr.eval(f(), *[x for _, x in counted])
                dr.sync_thread()
                times.append(time.process_time() - t0)
                history = dr.kernel_history()
            ops = [k.get("operation_count") for k in history if k.get("type") == dr.KernelType.JIT]
            lead = "| `%s` | `%s` | %.1f | %s" % (m, call, 1000 * statistics.median(times[1:]),
                                                 "+".join(str(o) for o in ops))
            for label, x in counted:
                a = x.numpy().astype(np.float64)
                print("%s | `%s` | %.3f (%d) | %.3f | %.3f | %.3f |" % (
                    lead, label, a.mean(), a.max(), a.reshape(-1, 8).max(axis=1).mean(),
                    a.reshape(-1, 16).max(axis=1).mean(), (a > 0).mean()))
                lead = "| | | |"
    print("load at the end %s" % open("/proc/loadavg").read().split()[:3])


if __name__ == "__main__":
    main()
