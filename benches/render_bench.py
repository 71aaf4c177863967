"""Render benchmark: the Fig. 9 scene (copper sphere, GGX α = 1, directional
light; scenes/fig09_copper_sphere.xml) rendered at equal spp by Mitsuba's
built-in roughconductor and by msx_posfree through every route:

- scalar_rgb, native back end (C++ plugin on the Rust core) and Python back
  end, each with 1 render thread and with all threads;
- llvm_ad_rgb with the Dr.Jit engine (msx/jit/, traced into Mitsuba's kernels; drjit's default symbolic
  mode): every model and the built-in in one process with msx registered, **one scene alive at a time**,
  interleaved over the repeats; and the built-in in a process without msx (what registering msx costs
  other scenes). One scene at a time because a symbolic BSDF call compiles every live BSDF instance into
  the kernel: with all the models alive at once each kernel holds all their walks, which slowed even the
  built-in ≈ 1.8×; and one process because across processes this shared machine's timings moved ±40 %;

- llvm_ad_rgb with the batched route (batched native calls in drjit's evaluated mode), against the
  built-in in drjit's default (symbolic) mode and in evaluated mode.

Each route runs in its own process; within a process the configurations are
interleaved over repeats and the median is kept. Only ratios measured in one
run are meaningful (machines are shared and noisy).

    python3 benches/render_bench.py [--spp 16] [--res 128] [--repeats 5] [--routes llvm]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

MODELS = ["single", "correlated", "invariance", "heitz"]
LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"


def _render(mi, dr, scene, spp):
    """One render, waited for: drjit launches LLVM kernels asynchronously, so without a sync a timing
    measures the launch (and the wait for the previous render)."""
    img = mi.render(scene, spp=spp)
    if not mi.variant().startswith("scalar"):
        dr.eval(img)
        dr.sync_thread()
    return img


def worker(route, res, spp, repeats):
    """One route in this process: {label: median seconds}."""
    variant, backend, threads = route.split(":")
    if variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(variant)
    import msx
    from msx._render import scenes_dir

    path = str(scenes_dir() / "fig09_copper_sphere.xml")
    size = dict(width=str(res), height=str(res))
    configs = {}
    if backend == "builtin-symbolic":  # no msx in this process: drjit's default mode stays on
        configs["roughconductor (symbolic)"] = mi.load_file(path, bsdf="roughconductor", **size)
    elif backend == "jit-registered":  # msx registered, the scene has no msx: what registering costs others
        msx.register(backend="jit")
        configs["roughconductor (msx registered)"] = mi.load_file(path, bsdf="roughconductor", **size)
    else:
        msx.register(backend=None if backend == "auto" else backend)
        if variant.startswith("scalar"):
            dr.set_thread_count(os.cpu_count() if threads == "all" else 1)
        if backend == "jit":
            return _one_scene_at_a_time(mi, dr, path, size, spp, repeats)
        else:
            label = "roughconductor" + (" (evaluated)" if backend == "batched" else "")
            configs[label] = mi.load_file(path, bsdf="roughconductor", **size)
            models = MODELS if backend != "python" else MODELS[:2]
        for m in models:
            try:
                configs[f"msx {m}"] = mi.load_file(path, bsdf="msx_posfree", model=m, **size)
            except Exception as e:  # a model this route refuses (it says why)
                print(f"{route}: msx {m} skipped: {str(e).strip().splitlines()[-1]}", file=sys.stderr)
    for s in configs.values():
        _render(mi, dr, s, 1)  # warm-up (kernel compilation in LLVM)
    times = {k: [] for k in configs}
    for _ in range(repeats):
        for k, s in configs.items():
            t0 = time.perf_counter()
            _render(mi, dr, s, spp)
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def _one_scene_at_a_time(mi, dr, path, size, spp, repeats):
    """The engine's route: each configuration loaded, rendered and dropped in turn, so that no other BSDF
    instance is alive while it renders (module docstring); {label: median seconds}."""
    import gc

    from msx.jit.bsdf import ENGINE_MODELS

    configs = {"roughconductor": dict(bsdf="roughconductor")}
    configs.update({f"msx {m}": dict(bsdf="msx_posfree", model=m) for m in ENGINE_MODELS["conductor"]})
    times = {k: [] for k in configs}
    for r in range(repeats):
        for k, extra in configs.items():
            try:
                scene = mi.load_file(path, **extra, **size)
            except Exception as e:  # a model this route refuses (it says why)
                if r == 0:
                    print(f"jit: {k} skipped: {str(e).strip().splitlines()[-1]}", file=sys.stderr)
                times.pop(k, None)
                continue
            _render(mi, dr, scene, 1)  # compiles on the first repeat, a kernel-cache hit after
            t0 = time.perf_counter()
            _render(mi, dr, scene, spp)
            times[k].append(time.perf_counter() - t0)
            del scene
            gc.collect()
    return {k: statistics.median(v) for k, v in times.items() if v}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--routes", default="all", help="all, llvm (the vectorized routes only) or scalar")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.res, args.spp, args.repeats)))
        return
    routes = []
    if args.routes in ("all", "scalar"):
        routes += ["scalar_rgb:native:1", "scalar_rgb:native:all", "scalar_rgb:python:1", "scalar_rgb:python:all"]
    if args.routes in ("all", "llvm"):
        routes += ["llvm_ad_rgb:builtin-symbolic:all", "llvm_ad_rgb:jit-registered:all", "llvm_ad_rgb:jit:all",
                   "llvm_ad_rgb:batched:all"]
    results = {}
    for r in routes:
        p = subprocess.run([sys.executable, __file__, "--worker", r, "--res", str(args.res), "--spp", str(args.spp),
                            "--repeats", str(args.repeats)], capture_output=True, text=True)
        for line in p.stderr.splitlines():
            if " skipped: " in line:
                print(line, file=sys.stderr)
        if p.returncode != 0:
            print(f"{r}: failed: {p.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
            continue
        results[r] = json.loads(p.stdout.strip().splitlines()[-1])
    cores = os.cpu_count()
    print(f"Fig. 9 scene, {args.res}x{args.res}, {args.spp} spp, median of {args.repeats}; {cores} cores\n")
    print("| route | threads | BSDF | seconds | × built-in (same route) |")
    print("|---|---|---|---|---|")
    for r, res in results.items():
        variant, backend, threads = r.split(":")
        base_key = next((k for k in res if k.startswith("roughconductor")), None)
        if backend in ("builtin-symbolic", "jit-registered"):
            continue
        base = res[base_key]
        for k, t in res.items():
            print(f"| {variant} {backend} | {threads if variant.startswith('scalar') else 'all'} | {k} | {t:.3f} | "
                  f"{t / base:.2f} |")
    sym = results.get("llvm_ad_rgb:builtin-symbolic:all", {}).get("roughconductor (symbolic)")
    reg = results.get("llvm_ad_rgb:jit-registered:all", {}).get("roughconductor (msx registered)")
    if sym and reg:
        print(f"\nThe built-in in a process with msx registered (no msx in the scene) / without msx: {reg / sym:.2f} ×")
    for route in ("llvm_ad_rgb:jit:all", "llvm_ad_rgb:batched:all"):
        if sym and route in results:
            print(f"\n{route}, against the built-in in drjit's default (symbolic) mode in a process without msx:")
            for k, t in results[route].items():
                print(f"  {k}: {t / sym:.2f} ×")
    n1, na = results.get("scalar_rgb:native:1"), results.get("scalar_rgb:native:all")
    if n1 and na:
        print("\nThread scaling of the native back end (1 thread / all threads):")
        for k in n1:
            print(f"  {k}: {n1[k] / na[k]:.2f} ×")


if __name__ == "__main__":
    main()
