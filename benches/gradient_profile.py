"""Where a gradient step's time goes: prb's primal and adjoint passes of one step (a ``prb`` render with one
parameter differentiated, the loss, its backward pass; benches/gradient_bench.py's scenes), for Mitsuba's
built-in and msx walks. Per pass, from ``dr.kernel_history()``: the kernels' run time (execution), their
compile time (codegen + backend, 0 when the kernel cache hit) and their IR size; and, counted while prb traces
its loop, the BSDF entry points each pass calls per path vertex, the walk loops each one records
(``dr.while_loop``) and the forward-mode passes ``gradients.attach`` adds (each one more loop in the kernel,
carrying the walk's state and its tangent).

    python3 benches/gradient_profile.py [--models correlated,heitz,invariance:bdpt] [--arrangements lean,trim]
                                        [--size 64] [--spp 16] [--repeats 5]

A model written ``name:bdpt`` runs with ``estimator="bdpt"``.

The step's wall time minus its kernels' run and compile time is the tracing: Python recording prb's loop (twice,
drjit's OptimizeLoops) and in it the BSDF calls, their walks and forward passes. ``--arrangements`` runs each
msx row per arrangement of ``jit/gradients.attach`` (``gradients.ARRANGEMENT``).
"""

import argparse
import collections
import os
import statistics
import sys
import time
from pathlib import Path

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="correlated")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--arrangements", default="trim")
    args = ap.parse_args()
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx
    from msx.jit import gradients

    msx.register()
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    from fit_roughness import scene_dict

    # ---- counting what prb traces, per pass
    phase = ["outside"]
    counts = collections.Counter()
    inner_while = dr.while_loop

    def while_loop(state, cond, body, labels=(), label=None, **kw):
        if label is not None and label.startswith("Path Replay"):
            old = phase[0]
            phase[0] = "primal" if "Primal" in label else "adjoint"
            try:
                return inner_while(state, cond, body, labels=labels, label=label, **kw)
            finally:
                phase[0] = old
        counts[(phase[0], "walk loops")] += 1
        return inner_while(state, cond, body, labels=labels, label=label, **kw)

    dr.while_loop = while_loop
    inner_forward = dr.forward_from

    def forward_from(*a, **kw):
        counts[(phase[0], "forward passes")] += 1
        return inner_forward(*a, **kw)

    dr.forward_from = forward_from

    cu = {"material": "Cu", "distribution": "ggx", "alpha": 0.5}
    configs = {"roughconductor": {"type": "roughconductor", **cu}}
    arrangement = {}
    for m in args.models.split(","):
        model, _, estimator = m.partition(":")
        for a in args.arrangements.split(","):
            label = f"msx {model}{' ' + estimator if estimator else ''} [{a}]"
            configs[label] = {"type": "msx_posfree", "model": model, **cu,
                              **({"estimator": estimator} if estimator else {})}
            arrangement[label] = a
    target = mi.render(mi.load_dict(scene_dict(configs["roughconductor"], args.size)), spp=64, seed=99)
    dr.eval(target)
    key = "ball.bsdf.alpha.value"
    dr.set_flag(dr.JitFlag.KernelHistory, True)

    def step(scene, params, seed):
        dr.enable_grad(params[key])
        dr.clear_grad(params[key])
        params.update()
        img = mi.render(scene, params, spp=args.spp, seed=seed, seed_grad=seed + 1)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        g = dr.grad(params[key])
        dr.eval(g)
        dr.sync_thread()

    rows = {label: collections.defaultdict(list) for label in configs}
    traced_counts = {}
    for r in range(args.repeats):
        for label, bsdf in configs.items():
            scene = mi.load_dict(scene_dict(bsdf, args.size))
            params = mi.traverse(scene)
            obj = scene.shapes()[0].bsdf()
            gradients.ARRANGEMENT = arrangement.get(label, "trim")
            calls = collections.Counter()
            originals = {}
            if label != "roughconductor" and r == 0:  # count the entry points prb traces, per pass
                cls = type(obj)
                for name in ("sample", "eval", "eval_pdf", "pdf"):
                    originals[name] = orig = cls.__dict__[name]

                    def wrapped(self, *a, _orig=orig, _name=name, **kw):
                        calls[(phase[0], _name)] += 1
                        return _orig(self, *a, **kw)

                    setattr(cls, name, wrapped)
            counts.clear()
            try:
                step(scene, params, 4 * r + 2)  # traces and compiles
            finally:
                for name, orig in originals.items():
                    setattr(type(obj), name, orig)
            if r == 0:
                traced_counts[label] = (dict(counts), dict(calls))
            dr.kernel_history()
            t0, c0 = time.perf_counter(), time.process_time()
            step(scene, params, 4 * r)
            rows[label]["step"].append(time.perf_counter() - t0)
            rows[label]["CPU"].append(time.process_time() - c0)
            hist = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
            # prb's kernels: the largest two by IR are its primal and adjoint passes, in that order.
            big = sorted(range(len(hist)), key=lambda i: -hist[i].get("operation_count", 0))[:2]
            big.sort()
            for name, i in zip(("primal", "adjoint"), big):
                k = hist[i]
                rows[label][name + " run"].append(k["execution_time"] / 1000.0)
                rows[label][name + " compile"].append((k.get("codegen_time", 0) + k.get("backend_time", 0)) / 1000.0)
                rows[label][name + " ops"].append(k.get("operation_count", 0))
            rows[label]["other kernels run"].append(
                sum(k["execution_time"] for i, k in enumerate(hist) if i not in big) / 1000.0)
            rows[label]["kernels"].append(len(hist))
            del scene, params, obj
    print(f"gradient step profile, copper α, {args.size}², {args.spp} spp, median of {args.repeats}; "
          f"load {os.getloadavg()}\n")
    base = statistics.median(rows["roughconductor"]["step"])
    cols = ["step", "CPU", "primal run", "adjoint run", "other kernels run", "primal compile", "adjoint compile",
            "primal ops", "adjoint ops", "kernels"]
    print("| BSDF | " + " | ".join(cols) + " | step × built-in |")
    print("|---" * (len(cols) + 2) + "|")
    for label, d in rows.items():
        vals = []
        for c in cols:
            v = statistics.median(d[c]) if d[c] else float("nan")
            vals.append(f"{v:.0f}" if c.endswith("ops") or c == "kernels" else f"{v:.4f}")
        print(f"| {label} | " + " | ".join(vals) + f" | {statistics.median(d['step']) / base:.2f} |")
    print()
    for label, (c, calls) in traced_counts.items():
        print(label, "traced per pass:", {k: v for k, v in sorted(calls.items())}, {k: v for k, v in sorted(c.items())})


if __name__ == "__main__":
    main()
