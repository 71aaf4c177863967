"""The glass walks of the Dr.Jit engine against their code at an earlier commit, in one process (issue 31,
item 2; benches/README.md, "Glass walks per frame").

    python3 benches/glass_ab_bench.py [--before 0d52f77] [--models correlated,heitz,invariance]
                                      [--calls-only | --frames-only] [--lanes 21] [--spp 16] [--repeats 5]
                                      [--alpha 0.6]

The modules ``posfree_dielectric``, ``heitz`` and ``invariance_dielectric`` of ``--before`` (``git show``) are
written beside the installed ones as ``msx/jit/<name>_before.py`` (removed at exit) and imported, so the
before and after walks run in the same process, interleaved, each timed by the process's CPU time after
``dr.sync_thread()``, the median of the repeats (the first round, which compiles, is not counted):

* per call: ``eval`` and ``sample`` of each walk directly (2^lanes random ω_i and ω_o, each on either side,
  Beckmann α ``--alpha`` (0.6), η 1.5, one wavefront);
* per frame: the shipped ``matpreview_glass.xml`` at α ``--alpha`` (320×240, as benches/scene_bench.py swaps it), the
  built-in ``roughdielectric`` and each model with its walk from before and after (the model's walk is
  swapped in ``jit/bsdf.py``'s table before the scene is loaded).

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
MODULES = ("posfree_dielectric", "heitz", "invariance_dielectric")


def install_before(rev, jit_dir):
    """Writes the modules of ``rev`` as ``<name>_before.py`` into the installed msx/jit (removed at exit)."""
    written = []
    for name in MODULES:
        text = subprocess.run(["git", "show", "%s:mitsuba_plugin/msx/jit/%s.py" % (rev, name)], cwd=HERE.parent,
                              check=True, capture_output=True, text=True).stdout
        text = text.replace("from . import heitz, ", "from . import heitz_before as heitz, ")
        path = Path(jit_dir) / ("%s_before.py" % name)
        path.write_text(text)
        written.append(path)
    atexit.register(lambda: [p.unlink() for p in written if p.exists()])


def glass_calls(n, alpha):
    """The per-call inputs of the glass benches (this file and glass_walk_profile.py): ``n`` lanes of ω_i and ω_o,
    each cosine-distributed on a random side, lane keys, three uniforms per lane, Beckmann statistics of ``alpha``
    and η = 1.5 (fixed seed; every array opaque, so that a kernel is traced once for all of them)."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np
    from msx.jit.microfacet import BECKMANN, Microfacet

    rng = np.random.default_rng(1)

    def directions():
        u, phi = rng.random(n), rng.uniform(0, 2 * np.pi, n)
        s = np.sqrt(u)
        v = np.stack([s * np.cos(phi), s * np.sin(phi), np.sqrt(1 - u)]).astype(np.float32)
        v[2] *= np.where(rng.random(n) < 0.5, 1, -1)
        out = mi.Vector3f(*[mi.Float(x) for x in v])
        dr.make_opaque(out)
        return out

    wi, wo = directions(), directions()
    key = mi.UInt32(rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32))
    s = [mi.Float(x) for x in rng.random((3, n)).astype(np.float32)]
    dr.make_opaque(key, *s)
    return wi, wo, key, s, Microfacet(BECKMANN, mi.Float(alpha), mi.Float(alpha)), mi.Float(1.5)


def median_times(fns, repeats, dr):
    """{key: median CPU seconds} of the callables ``fns`` (each returns what to evaluate), interleaved."""
    times = {k: [] for k in fns}
    for rep in range(repeats + 1):
        for k, f in fns.items():
            t0 = time.process_time()
            dr.eval(f())
            dr.sync_thread()
            if rep:
                times[k].append(time.process_time() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", default="0d52f77")
    ap.add_argument("--models", default="correlated,heitz,invariance")
    ap.add_argument("--lanes", type=int, default=21)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--alpha", type=float, default=0.6)
    ap.add_argument("--calls-only", action="store_true")
    ap.add_argument("--frames-only", action="store_true")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx
    from msx import jit

    install_before(args.before, os.path.dirname(jit.__file__))
    msx.register()
    from msx.jit import bsdf as jit_bsdf
    from msx.jit import heitz_before, invariance_dielectric_before, posfree_dielectric_before
    from msx.jit.model import DielectricWalk

    models = [m for m in args.models.split(",") if m]
    after = dict(jit_bsdf.DIELECTRIC_WALKS)
    before = {**posfree_dielectric_before.DIELECTRIC_WALKS, **heitz_before.DIELECTRIC_WALKS,
              "invariance": DielectricWalk(invariance_dielectric_before.eval, invariance_dielectric_before.sample,
                                           differentiable=True)}
    print("before = %s, load %s" % (args.before, open("/proc/loadavg").read().split()[:3]))

    if not args.frames_only:
        wi, wo, key, s, mf, eta = glass_calls(1 << args.lanes, args.alpha)
        fns = {}
        for m in models:
            for label, table in (("before", before), ("after", after)):
                w = table[m]
                fns[(m, "eval", label)] = lambda w=w: w.eval_pt(mf, eta, True, wi, wo, 64, key)
                fns[(m, "sample", label)] = lambda w=w: w.sample_walk(mf, eta, True, wi, s[0], s[1], s[2], 64, key)[0]
        t = median_times(fns, args.repeats, dr)
        print("per call, 2^%d lanes, CPU ms (median of %d)" % (args.lanes, args.repeats))
        print("| model | call | before | after | after/before |\n|---|---|---|---|---|")
        for m in models:
            for call in ("eval", "sample"):
                a, b = t[(m, call, "before")], t[(m, call, "after")]
                print("| `%s` | `%s` | %.1f | %.1f | %.3f |" % (m, call, 1000 * a, 1000 * b, b / a))
        sys.stdout.flush()

    if not args.calls_only:
        sys.path.insert(0, str(HERE))
        import scene_bench

        path = scene_bench.resolve("matpreview_glass.xml")
        text = path.read_text()
        mi.file_resolver().prepend(str(path.parent))
        over = {"alpha": repr(args.alpha)}
        sources = {m: scene_bench._drop_duplicates(scene_bench.swap(text, m, over), over) for m in [None] + models}
        configs = [(None, "after")] + [(m, label) for m in models for label in ("before", "after")]

        times = {c: [] for c in configs}
        for rep in range(args.repeats + 1):
            for m, label in configs:
                jit_bsdf.DIELECTRIC_WALKS.clear()
                jit_bsdf.DIELECTRIC_WALKS.update(after if label == "after" else {**after, **before})
                scene = mi.load_string(sources[m])  # one scene alive at a time (scene_bench.py)
                scene_bench.resize(mi, scene, 320, 240)
                t0 = time.process_time()
                dr.eval(mi.render(scene, spp=args.spp, seed=1 + rep))  # seed 0 traces another kernel
                dr.sync_thread()
                if rep:
                    times[(m, label)].append(time.process_time() - t0)
                del scene
        t = {c: statistics.median(v) for c, v in times.items()}
        jit_bsdf.DIELECTRIC_WALKS.clear()
        jit_bsdf.DIELECTRIC_WALKS.update(after)
        ref = t[(None, "after")]
        print("per frame, matpreview_glass.xml α %g, 320×240, %d spp: built-in %.2f s CPU (median of %d); "
              "× built-in:" % (args.alpha, args.spp, ref, args.repeats))
        print("| model | before | after |\n|---|---|---|")
        for m in models:
            print("| `%s` | %.2f | %.2f |" % (m, t[(m, "before")] / ref, t[(m, "after")] / ref))
    print("load at the end %s" % open("/proc/loadavg").read().split()[:3])


if __name__ == "__main__":
    main()
