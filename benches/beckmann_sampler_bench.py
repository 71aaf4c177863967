"""The Beckmann visible-normal sampler of the Dr.Jit engine (``msx.jit.beckmann.sample_visible_std``) per call,
against Mitsuba's own Beckmann ``sample_visible`` (issue 31, item 2; benches/README.md, "The Beckmann sampler").

    python3 benches/beckmann_sampler_bench.py [--before REV] [--lanes 21] [--repeats 9] [--alpha 0.6]
                                              [--counts-only | --times-only | --walks]

* Times: 2^lanes random directions above the horizon (cos θ > 0, the common case), below it, and both
  mixed, and uniform (u1, u2); ``sample_visible_std`` (and with ``--before REV``, the module of that commit,
  written beside the installed one as ``msx/jit/beckmann_before.py`` and removed at exit) against
  ``mi.MicrofacetDistribution(Beckmann, α, sample_visible=True).sample`` on the same directions. Each call
  is evaluated in one wavefront and timed by the process's CPU time after ``dr.sync_thread()``; the
  variants are interleaved, the median of the repeats (the first round, which compiles, is not counted).
* ``--walks`` (with ``--before``): per call, ``eval`` and ``sample`` of ``correlated`` copper (Beckmann α 0.8)
  and glass (α 0.6, η 1.5, ω_i and ω_o each on either side) with the sampler of ``--before`` and the current
  one (swapped as ``msx.jit.beckmann``, which msx/jit/microfacet.py imports at trace time), interleaved with
  the built-in ``roughconductor`` / ``roughdielectric``; CPU time of the call, median of the repeats.
* ``--frames SCENE`` (with ``--before``): per frame, the scene (320 px wide, as benches/scene_bench.py swaps
  it, ``--set`` overrides such as alpha=0.6) with the built-in BSDF and each of ``--models`` with the sampler of
  ``--before`` and the current one, interleaved, ``--spp`` samples, CPU time, median of the repeats.
* Newton iteration counts: per lane (the step at which its Newton step fell below the tolerance) and per
  16-lane packet (the maximum over 16 consecutive lanes, which is what a packet of the symbolic loop runs),
  over random θ and u on either side of the horizon, and as a table over θ bands.

Only ratios measured in one run mean anything (shared machines).
"""

import argparse
import atexit
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from glass_ab_bench import median_times  # noqa: E402


def install_before(rev, jit_dir):
    text = subprocess.run(["git", "show", "%s:mitsuba_plugin/msx/jit/beckmann.py" % rev], cwd=HERE.parent,
                          check=True, capture_output=True, text=True).stdout
    text = text.replace("from .special import", "from .special_before import")
    sp = subprocess.run(["git", "show", "%s:mitsuba_plugin/msx/jit/special.py" % rev], cwd=HERE.parent,
                        check=True, capture_output=True, text=True).stdout
    paths = [Path(jit_dir) / "beckmann_before.py", Path(jit_dir) / "special_before.py"]
    paths[0].write_text(text)
    paths[1].write_text(sp)
    atexit.register(lambda: [p.unlink() for p in paths if p.exists()])


def directions(np, n, side, rng):
    """n unit directions, uniform on the upper (side 'up'), lower ('down') or whole ('mixed') sphere."""
    z = rng.uniform(0.0, 1.0, n)
    if side == "down":
        z = -z
    elif side == "mixed":
        z = rng.uniform(-1.0, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z]).astype(np.float32)


def newton_counts(beckmann, mi, dr, np, c, s, u):
    """Per-lane Newton iteration counts of ``sample_slope_x`` (13 = not converged in 12)."""
    counts = np.full(len(u), beckmann.NEWTON_ITERATIONS + 1, dtype=np.int32)
    captured = {}
    orig = beckmann.newton_monotone

    def spy(*a, **k):
        x, conv = orig(*a, **k)
        captured["conv"] = conv
        return x, conv

    beckmann.newton_monotone = spy
    try:
        for k in range(beckmann.NEWTON_ITERATIONS, -1, -1):
            beckmann.sample_slope_x(mi.Float(c), mi.Float(s), mi.Float(u), k)
            conv = captured["conv"].numpy()
            counts[conv] = k
    finally:
        beckmann.newton_monotone = orig
    return counts


def walks_ab(args, variants, jit, dr, mi, np, rng, n):
    import msx

    msx.register(backend="jit")
    ctx = mi.BSDFContext()
    print("per call, 2^%d lanes: correlated walks with the sampler before/after (CPU ms, median of %d)"
          % (args.lanes, args.repeats))
    for surface, alpha, builtin in (("conductor", 0.8, "roughconductor"), ("dielectric", 0.6, "roughdielectric")):
        mu = rng.uniform(0.0, 1.0, n)
        phi = rng.uniform(0, 2 * np.pi, n)
        r = np.sqrt(np.maximum(1 - mu * mu, 0))
        wi = np.stack([r * np.cos(phi), r * np.sin(phi), mu]).astype(np.float32)
        wo = directions(np, n, "up", rng)
        if surface == "dielectric":
            wi[2] *= np.where(rng.random(n) < 0.5, 1.0, -1.0).astype(np.float32)
            wo[2] *= np.where(rng.random(n) < 0.5, 1.0, -1.0).astype(np.float32)
        su = rng.random((3, n)).astype(np.float32)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(*[mi.Float(x) for x in wi])
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        wo_v = mi.Vector3f(*[mi.Float(x) for x in wo])
        s1, s2 = mi.Float(su[0]), mi.Point2f(mi.Float(su[1]), mi.Float(su[2]))
        dr.make_opaque(si, wo_v, s1, s2)
        if surface == "dielectric":
            common = {"distribution": "beckmann", "alpha": alpha, "int_ior": 1.5, "ext_ior": 1.0}
            extra = {"surface": "dielectric"}
        else:
            common = {"distribution": "beckmann", "alpha": alpha, "material": "Cu"}
            extra = {}
        ref = mi.load_dict({"type": builtin, **common})
        ours = mi.load_dict({"type": "msx_posfree", "model": "correlated", **extra, **common})
        calls = {"eval": lambda b: (b.eval(ctx, si, wo_v),),
                 "sample": lambda b: (lambda bs, w: (bs.wo, bs.pdf, w))(*b.sample(ctx, si, s1, s2))}
        for call, f in calls.items():
            fns = {"built-in": (None, ref)}
            for name, mod in variants.items():
                fns[name] = (mod, ours)
            times = {k: [] for k in fns}
            for rep in range(args.repeats + 1):
                for k, (mod, b) in fns.items():
                    if mod is not None:
                        jit.beckmann = mod  # msx/jit/microfacet.py: ``from . import beckmann`` at trace time
                    t0 = time.process_time()
                    dr.eval(*f(b))
                    dr.sync_thread()
                    if rep:
                        times[k].append(time.process_time() - t0)
            jit.beckmann = variants.get("after", variants.get("msx"))
            med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
            print("  %-10s α %.1f %-6s " % (surface, alpha, call)
                  + "  ".join("%s %.1f ms (%.2fx)" % (k, v, v / med["built-in"]) for k, v in med.items())
                  + ("   after/before %.2fx" % (med["after"] / med["before"]) if "before" in med else ""),
                  flush=True)


def frames_ab(args, variants, jit, dr, mi):
    import msx

    sys.path.insert(0, str(HERE))
    import scene_bench

    msx.register()
    path = scene_bench.resolve(args.frames)
    text = path.read_text()
    mi.file_resolver().prepend(str(path.parent))
    over = dict(kv.split("=", 1) for kv in args.set)
    models = [m for m in args.models.split(",") if m]
    sources = {m: scene_bench._drop_duplicates(scene_bench.swap(text, m, over), over) for m in [None] + models}
    probe = mi.load_string(sources[None])
    film = probe.sensors()[0].film().size()
    width, height = 320, max(1, round(film[1] * 320 / film[0]))
    del probe
    configs = [(None, "built-in")] + [(m, k) for m in models for k in variants]
    times = {c: [] for c in configs}
    for rep in range(args.repeats + 1):
        for m, k in configs:
            if m is not None:
                jit.beckmann = variants[k]  # msx/jit/microfacet.py: ``from . import beckmann`` at trace time
            scene = mi.load_string(sources[m])
            scene_bench.resize(mi, scene, width, height)
            t0 = time.process_time()
            dr.eval(mi.render(scene, spp=args.spp, seed=1 + rep))
            dr.sync_thread()
            if rep:
                times[(m, k)].append(time.process_time() - t0)
            del scene
    jit.beckmann = variants.get("after", variants.get("msx"))
    t = {c: statistics.median(v) for c, v in times.items()}
    ref = t[(None, "built-in")]
    print("per frame, %s %s, %d×%d, %d spp: built-in %.2f s CPU (median of %d); × built-in:"
          % (args.frames, " ".join(args.set), width, height, args.spp, ref, args.repeats))
    print("| model | " + " | ".join(variants) + (" | after/before |" if "before" in variants else " |"))
    for m in models:
        row = "| `%s` | " % m + " | ".join("%.2f" % (t[(m, k)] / ref) for k in variants)
        if "before" in variants:
            row += " | %.2f" % (t[(m, "after")] / t[(m, "before")])
        print(row + " |", flush=True)
    print("load at the end %s" % open("/proc/loadavg").read().split()[:3])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", default=None)
    ap.add_argument("--lanes", type=int, default=21)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--alpha", type=float, default=0.6)
    ap.add_argument("--counts-only", action="store_true")
    ap.add_argument("--times-only", action="store_true")
    ap.add_argument("--walks", action="store_true", help="per-call A/B of the correlated walks (needs --before)")
    ap.add_argument("--frames", default=None, help="per-frame A/B on this scene (needs --before)")
    ap.add_argument("--models", default="correlated")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--set", action="append", default=[], help="name=value on every swapped BSDF")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi
    import numpy as np

    mi.set_variant("llvm_ad_rgb")
    from msx import jit
    from msx.jit import beckmann

    variants = {"msx": beckmann}
    if args.before:
        install_before(args.before, os.path.dirname(jit.__file__))
        from msx.jit import beckmann_before
        variants = {"before": beckmann_before, "after": beckmann}
    print("uptime:", os.popen("uptime").read().strip())
    rng = np.random.default_rng(1)
    n = 1 << args.lanes

    if args.walks:
        walks_ab(args, variants, jit, dr, mi, np, rng, n)
        return
    if args.frames:
        frames_ab(args, variants, jit, dr, mi)
        return
    if not args.counts_only:
        dist = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, args.alpha, True)
        print("per call, 2^%d lanes, α %.2f (CPU ms, median of %d; ratio to Mitsuba's sample_visible)"
              % (args.lanes, args.alpha, args.repeats))
        for side in ("up", "down", "mixed"):
            w = directions(np, n, side, rng)
            u = rng.uniform(0.0, 1.0, (2, n)).astype(np.float32)
            wv = mi.Vector3f(*(mi.Float(w[i]) for i in range(3)))
            # Stretched by α as the walks do (msx/jit/microfacet.py): the std sampler sees (αx, αy, z).
            ws = dr.normalize(mi.Vector3f(args.alpha * wv.x, args.alpha * wv.y, wv.z))
            u1, u2 = mi.Float(u[0]), mi.Float(u[1])
            dr.eval(wv, ws, u1, u2)
            fns = {}
            for name, mod in variants.items():
                fns[name] = (lambda mod=mod: mod.sample_visible_std(ws, u1, u2))
            if side == "up":
                # Mitsuba's sampler is defined above the horizon only (it flips nothing): same inputs.
                fns["mitsuba"] = lambda: dist.sample(wv, mi.Point2f(u1, u2))
            med = {k: v * 1e3 for k, v in median_times(fns, args.repeats, dr).items()}
            line = "  %-5s " % side + "  ".join("%s %.1f ms" % (k, v) for k, v in med.items())
            if "mitsuba" in med:
                line += "   ratios: " + ", ".join("%s %.2fx" % (k, med[k] / med["mitsuba"])
                                                  for k in variants)
            if "before" in med:
                line += "   after/before %.2fx" % (med["after"] / med["before"])
            print(line, flush=True)

    if not args.times_only:
        m = 1 << 18
        for name, mod in variants.items():
            print("Newton iterations (%s): per lane / per 16-lane packet (max), 2^18 random lanes" % name)
            for side in ("up", "down"):
                w = directions(np, m, side, rng)
                theta = np.arccos(np.clip(w[2], -1, 1))
                c = np.cos(theta).astype(np.float32)
                s = np.sin(theta).astype(np.float32)
                u = rng.uniform(0.0, 1.0, m).astype(np.float32)
                cnt = newton_counts(mod, mi, dr, np, c, s, u)
                pk = cnt.reshape(-1, 16).max(axis=1)
                hl = np.bincount(cnt, minlength=14)
                hp = np.bincount(pk, minlength=14)
                print("  %-4s lanes mean %.2f, packets mean %.2f" % (side, cnt.mean(), pk.mean()))
                print("       count: " + " ".join("%6d" % i for i in range(14)))
                print("       lanes: " + " ".join("%6d" % v for v in hl[:14]))
                print("     packets: " + " ".join("%6d" % v for v in hp[:14]))
            # Over a θ × u grid: the mean count per θ band.
            ths = np.linspace(0.01, np.pi - 0.01, 60)
            us = np.linspace(0.0, 1.0, 1025)[1:-1]
            th, uu = np.meshgrid(ths, us, indexing="ij")
            cnt = newton_counts(mod, mi, dr, np, np.cos(th.ravel()).astype(np.float32),
                                np.sin(th.ravel()).astype(np.float32), uu.ravel().astype(np.float32))
            cnt = cnt.reshape(len(ths), -1)
            print("  θ band : mean / max count over u (1023 u per θ)")
            for lo in range(0, 60, 6):
                band = cnt[lo:lo + 6]
                print("   θ %.2f–%.2f: %.2f / %d" % (ths[lo], ths[min(lo + 5, 59)], band.mean(), band.max()))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
