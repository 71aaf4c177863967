"""Gradient-step benchmark: one step of inverse rendering — a ``prb`` render with one parameter differentiated,
the squared error against a target and its backward pass — for Mitsuba's built-in BSDF and the differentiable
msx models, in ``llvm_ad_rgb``, one process, every configuration of every section interleaved over the repeats
(median kept). Each timed step follows an untimed one on the same freshly loaded scene (which compiles or loads
its kernels), as in an optimisation loop. Only the ratios to the built-in measured in one run mean anything
(machines are shared and noisy).

Sections (scene, parameter):

- copper α: examples/fit_roughness.py's scene (a copper sphere under a sky and a sun), ``roughconductor``
  against every msx conductor model, and the ``correlated`` and ``invariance`` walks with ``estimator="bdpt"``;
- glass α and glass η: a rough glass sphere (GGX α = 0.5, IOR 1.5) in front of a checkered wall under the same
  sky and sun, ``roughdielectric`` against the msx dielectric models; ``eta`` is the relative IOR
  (``ball.bsdf.eta`` for the built-in and msx alike). A configuration that refuses to be differentiated in the parameter (some glass
  walks in η) is reported as "refuses";
- normal map: examples/fit_normal_map.py's scene (a Beckmann α = 0.5 copper plate under three coloured suns,
  its 6 × 6 normal map differentiated through Mitsuba's ``normalmap``), ``roughconductor`` against ``single``
  and the walks that differentiate through directions (``differentiate_directions``), Beckmann and GGX.

    python3 benches/gradient_bench.py [--scene copper|glass|normalmap|all] [--param alpha|eta|all]
                                      [--size 64] [--spp 16] [--repeats 7] [--models correlated,heitz]
                                      [--arrangements plain,lean,trim]

``--models`` keeps the msx rows whose model is listed (the built-in's row always runs); ``--arrangements``
runs every msx row once per arrangement of ``jit/gradients.attach`` (``gradients.ARRANGEMENT``: "plain", the
arrangement before the step's cost was cut, "lean", or "trim", the default; docs/gradients.md), interleaved with
the others, labelled "[plain]", "[lean]" or "[trim]".
"""

import argparse
import gc
import os
import statistics
import sys
import time
from pathlib import Path

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
MODELS = ["single", "compensated", "fastmsx", "uncorrelated", "correlated", "heitz", "invariance"]
BDPT_MODELS = ["correlated", "invariance"]
GLASS_MODELS = ["single", "compensated", "uncorrelated", "correlated", "heitz", "invariance"]
# mi.traverse keys of the parameters, per scene (the sphere's BSDF is "ball.bsdf").
KEYS = {"alpha": "ball.bsdf.alpha.value", "eta": "ball.bsdf.eta", "normals": "plate.bsdf.normalmap.data"}
SYMBOLS = {"alpha": "α", "eta": "η", "normals": "the normal map"}
# The walks that differentiate through directions (docs/gradients.md, "Directions through the walks").
DIRECTION_MODELS = ["uncorrelated", "correlated", "auto"]


def glass_scene_dict(bsdf, size):
    """A glass sphere in front of a checkered diffuse wall, under a sky and a sun (max depth 6: the paths
    through the sphere reach the wall and the sky)."""
    import mitsuba as mi

    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    wall = mi.ScalarTransform4f().translate([0, 0, -2.5]).scale([4, 4, 1])
    return {
        "type": "scene",
        "integrator": {"type": "prb", "max_depth": 6},
        "sensor": {
            "type": "perspective",
            "fov": 34,
            "to_world": look,
            "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent"},
        },
        "sky": {"type": "constant", "radiance": 0.35},
        "sun": {"type": "directional", "direction": [0.35, -0.3, -1.0], "irradiance": 4.0},
        "wall": {
            "type": "rectangle",
            "to_world": wall,
            "bsdf": {
                "type": "diffuse",
                "reflectance": {
                    "type": "checkerboard",
                    "color0": {"type": "rgb", "value": [0.1, 0.1, 0.1]},
                    "color1": {"type": "rgb", "value": [0.8, 0.7, 0.5]},
                    "to_uv": mi.ScalarTransform4f().scale([8, 8, 1]),
                },
            },
        },
        "ball": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
    }


def sections(scenes, params):
    """[(scene, parameter, {label: bsdf})]: the built-in first in each."""
    out = []
    if "copper" in scenes and "alpha" in params:
        cu = {"material": "Cu", "distribution": "ggx", "alpha": 0.5}
        configs = {"roughconductor": {"type": "roughconductor", **cu}}
        configs.update({f"msx {m}": {"type": "msx_posfree", "model": m, **cu} for m in MODELS})
        configs.update(
            {f"msx {m} bdpt": {"type": "msx_posfree", "model": m, "estimator": "bdpt", **cu} for m in BDPT_MODELS}
        )
        out.append(("copper", "alpha", configs))
    if "glass" in scenes:
        glass = {"distribution": "ggx", "alpha": 0.5, "int_ior": 1.5}
        configs = {"roughdielectric": {"type": "roughdielectric", **glass}}
        configs.update(
            {f"msx {m}": {"type": "msx_posfree", "surface": "dielectric", "model": m, **glass} for m in GLASS_MODELS}
        )
        out += [("glass", p, configs) for p in ("alpha", "eta") if p in params]
    if "normalmap" in scenes:
        cu = {"material": "Cu", "alpha": 0.5}
        configs = {"roughconductor": {"type": "roughconductor", **cu}, "msx single": {"type": "msx_posfree",
                                                                                      "model": "single", **cu}}
        for dist in ("beckmann", "ggx"):
            configs.update({f"msx {m} {dist}": {"type": "msx_posfree", "model": m, "distribution": dist,
                                                "differentiate_directions": True, **cu} for m in DIRECTION_MODELS})
        configs["msx correlated bdpt"] = {"type": "msx_posfree", "model": "correlated", "estimator": "bdpt",
                                          "differentiate_directions": True, **cu}
        out.append(("normalmap", "normals", configs))
    return out


def messages(err):
    """The messages of an exception and its causes, joined."""
    chain = []
    while err is not None:
        chain.append(f"{type(err).__name__}: {err}")
        err = err.__cause__ or err.__context__
    return "\n".join(chain)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", choices=["copper", "glass", "normalmap", "all"], default="all")
    ap.add_argument(
        "--param",
        choices=["alpha", "eta", "all"],
        default="all",
        help="the differentiated parameter (copper: alpha only; the normal map scene: its map)",
    )
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--models", default=None, help="comma-separated msx models to keep (default: all)")
    ap.add_argument("--arrangements", default=None, help="comma-separated: plain, lean, trim (default: the module's)")
    args = ap.parse_args()
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    from msx.jit import gradients

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    from fit_normal_map import encode, scene_dict as normal_map_scene, true_normals
    from fit_roughness import scene_dict

    flat = true_normals(6) * 0.0 + [0.0, 0.0, 1.0]
    scene_dicts = {"copper": scene_dict, "glass": glass_scene_dict,
                   "normalmap": lambda bsdf, size: normal_map_scene(bsdf, encode(flat), size)}
    scenes = ["copper", "glass", "normalmap"] if args.scene == "all" else [args.scene]
    params = ["alpha", "eta", "normals"] if args.param == "all" else [args.param]
    if args.scene == "normalmap":
        params = ["normals"]
    todo = sections(scenes, params)
    if args.models:
        keep = set(args.models.split(","))
        todo = [(n, p, {label: b for i, (label, b) in enumerate(c.items()) if i == 0 or b.get("model") in keep})
                for n, p, c in todo]
    arrangements = {}  # label → the arrangement it runs with
    if args.arrangements:
        wanted = args.arrangements.split(",")
        expanded = []
        for n, p, c in todo:
            out = {}
            for i, (label, b) in enumerate(c.items()):
                if i == 0 or b.get("type") != "msx_posfree":
                    out[label] = b
                    continue
                for a in wanted:
                    out[f"{label} [{a}]"] = b
                    arrangements[f"{label} [{a}]"] = a
            expanded.append((n, p, out))
        todo = expanded
    if not todo:
        ap.error(f"nothing to measure for --scene {args.scene} --param {args.param} (copper: alpha only)")

    # One target per scene, rendered with the built-in at 64 spp.
    targets = {}
    for name, _, configs in todo:
        if name not in targets:
            builtin = next(iter(configs.values()))
            targets[name] = mi.render(mi.load_dict(scene_dicts[name](builtin, args.size)), spp=64, seed=99)
            dr.eval(targets[name])

    def step(scene, params, key, target, seed):
        dr.enable_grad(params[key])
        dr.clear_grad(params[key])
        params.update()
        img = mi.render(scene, params, spp=args.spp, seed=seed, seed_grad=seed + 1)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        g = dr.grad(params[key])
        dr.eval(g)
        dr.sync_thread()
        return float(dr.ravel(g)[0])

    # Each timed step follows an untimed one on the same scene, as in an optimisation loop (one scene, many
    # steps): the kernels depend on the objects drjit has registered (instance ids are literals in the dispatch
    # code, and a call traces every registered instance of its domain), and the first step on a fresh scene can
    # still trace a BSDF of the previous one, not freed yet, so its kernels differ from the next steps' and may
    # compile (seconds for a walk). The kernels compiled during timed steps are counted and reported.
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    jobs = [(name, p, label, bsdf) for name, p, configs in todo for label, bsdf in configs.items()]
    times = {job[:3]: [] for job in jobs}
    cpu = {job[:3]: [] for job in jobs}  # the process's CPU time (all its threads): less sensitive to others' load
    compiled = {job[:3]: 0 for job in jobs}
    failed = {}  # (scene, parameter, label) → "refuses" or "fails"
    for r in range(args.repeats):
        for name, p, label, bsdf in jobs:
            if (name, p, label) in failed:
                continue
            gc.collect()  # free the previous scene (reference cycles through the Python plugin)
            scene = mi.load_dict(scene_dicts[name](bsdf, args.size))
            params = mi.traverse(scene)
            gradients.ARRANGEMENT = arrangements.get(label, "trim")
            try:
                step(scene, params, KEYS[p], targets[name], 4 * r + 2)  # compiles the kernels (or loads them)
                gc.collect()
                dr.kernel_history()  # clears it
                t0, c0 = time.perf_counter(), time.process_time()
                step(scene, params, KEYS[p], targets[name], 4 * r)
                times[(name, p, label)].append(time.perf_counter() - t0)
                cpu[(name, p, label)].append(time.process_time() - c0)
                compiled[(name, p, label)] += sum(
                    1 for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT and not k.get("cache_hit")
                )
            except Exception as e:  # a walk not differentiable in this parameter refuses at trace time
                text = messages(e)
                failed[(name, p, label)] = "refuses" if "not differentiable" in text else "fails"
                lines = text.splitlines()
                why = next((x for x in lines if "not differentiable" in x), lines[0] if lines else "")
                print(f"{name} {p} {label}: {failed[(name, p, label)]}: {why[:400]}", file=sys.stderr)
            finally:
                del scene, params
    for job, n in compiled.items():
        if n:
            print(f"note: {' '.join(job)} compiled {n} kernel(s) during its timed steps", file=sys.stderr)

    print(
        f"gradient step (prb render + backward), {args.size}², {args.spp} spp, median of {args.repeats}; "
        f"{os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the end\n"
    )
    for name, p, configs in todo:
        builtin = next(iter(configs))
        if len(todo) > 1 or (name, p) != ("copper", "alpha"):
            print(f"### {name}, {SYMBOLS[p]} (`{KEYS[p]}`)\n")
        if (name, p, builtin) in failed:
            print(f"{builtin}: {failed[(name, p, builtin)]} (no ratios)\n")
            continue
        base = statistics.median(times[(name, p, builtin)])
        cpu_base = statistics.median(cpu[(name, p, builtin)])
        print(f"| BSDF | seconds | × {builtin} | CPU seconds | × {builtin} |\n|---|---|---|---|---|")
        for label in configs:
            if (name, p, label) in failed:
                print(f"| {label} | {failed[(name, p, label)]} | – | – | – |")
                continue
            t, c = statistics.median(times[(name, p, label)]), statistics.median(cpu[(name, p, label)])
            print(f"| {label} | {t:.3f} | {t / base:.2f} | {c:.3f} | {c / cpu_base:.2f} |")
        print()


if __name__ == "__main__":
    main()
