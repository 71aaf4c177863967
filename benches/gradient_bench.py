"""Gradient-step benchmark: one step of inverse rendering — a ``prb`` render with α differentiated, the
squared error against a target and its backward pass — for Mitsuba's ``roughconductor`` and every
differentiable msx model, in ``llvm_ad_rgb``, one process, configurations interleaved over the repeats
(median kept). The scene is examples/fit_roughness.py's (a copper sphere under a sky and a sun). Only the
ratios to the built-in measured in one run mean anything (machines are shared and noisy).

    python3 benches/gradient_bench.py [--size 64] [--spp 16] [--repeats 7]
"""

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
MODELS = ["single", "compensated", "fastmsx", "uncorrelated", "correlated", "heitz", "invariance"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    from fit_roughness import scene_dict

    configs = {"roughconductor": {"type": "roughconductor", "material": "Cu", "distribution": "ggx", "alpha": 0.5}}
    configs.update({f"msx {m}": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx", "model": m,
                                 "alpha": 0.5} for m in MODELS})
    target = mi.render(mi.load_dict(scene_dict(configs["roughconductor"], args.size)), spp=64, seed=99)
    dr.eval(target)

    def step(scene, params, seed):
        key = "ball.bsdf.alpha.value"
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, spp=args.spp, seed=seed, seed_grad=seed + 1)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        g = dr.grad(params[key])
        dr.eval(g)
        dr.sync_thread()
        return float(g[0])

    times = {k: [] for k in configs}
    for r in range(args.repeats + 1):
        for label, bsdf in configs.items():
            scene = mi.load_dict(scene_dict(bsdf, args.size))
            params = mi.traverse(scene)
            t0 = time.perf_counter()
            step(scene, params, 2 * r)
            if r > 0:  # the first repeat compiles the kernels
                times[label].append(time.perf_counter() - t0)
            del scene, params
    base = statistics.median(times["roughconductor"])
    print(f"gradient step (prb render + backward), {args.size}², {args.spp} spp, median of {args.repeats}; "
          f"{os.cpu_count()} cores\n")
    print("| BSDF | seconds | × roughconductor |\n|---|---|---|")
    for label, ts in times.items():
        t = statistics.median(ts)
        print(f"| {label} | {t:.3f} | {t / base:.2f} |")


if __name__ == "__main__":
    main()
