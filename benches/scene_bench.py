"""Scene benchmark: any Mitsuba scene rendered with its rough BSDFs as written (the built-ins) and with every
``roughconductor`` / ``roughdielectric`` turned into ``msx_posfree`` with one model after another — only the
BSDF's ``type`` changes (plus ``surface="dielectric"`` for glass and the ``model``), every other parameter and
the rest of the file stay as they are.

All renders run in this process, in ``llvm_ad_rgb`` with the Dr.Jit engine, one scene alive at a time (a
symbolic BSDF call traces every live BSDF instance into the kernel), the configurations interleaved over
``--repeats`` rounds; each timed render follows an untimed one of the same scene (kernels compiled, drjit's
kernel cache warm) and is waited for (``dr.sync_thread``). Per configuration: the median time and the image
mean, both × the built-in's. For ``auto``: the fraction of its BSDF calls that run a walk (the others are its
closed-form order 1), counted inside the kernel.

Only ratios measured in one run mean anything (machines are shared and noisy).

    python3 benches/scene_bench.py SCENE.xml [SCENE.xml ...] [--models single,auto,correlated,heitz,invariance]
        [--spp 64] [--res 320] [--repeats 3] [--set alpha=0.8] [-D key=value]

A shipped scene may be named instead of a path (``material_preview.xml``, ``fig09_copper_sphere.xml``).
"""

import argparse
import os
import re
import statistics
import sys
import time
from pathlib import Path

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
ROUGH = {"roughconductor": None, "roughdielectric": "dielectric"}
_OPEN = re.compile(r'<bsdf\b[^>]*\btype\s*=\s*"(roughconductor|roughdielectric)"[^>]*>')


def swap(text, model, overrides):
    """The scene's text with every rough built-in turned into msx_posfree ``model`` (None: unchanged), and
    ``overrides`` ({name: value}) set on each of them (a float parameter replaced or added)."""
    def one(match):
        tag = match.group(0)
        surface = ROUGH[match.group(1)]
        if model is not None:
            tag = tag.replace('"%s"' % match.group(1), '"msx_posfree"', 1)
        added = ""
        if model is not None:
            added += '<string name="model" value="%s"/>' % model
            if surface:
                added += '<string name="surface" value="%s"/>' % surface
        for name in overrides:
            added += '<float name="%s" value="%s"/>' % (name, overrides[name])
        if tag.endswith("/>"):
            return tag[:-2] + ">" + added + "</bsdf>"
        return tag + added

    return _OPEN.sub(one, text)


def _drop_duplicates(text, names):
    """Keeps the first value of each overridden parameter inside every swapped BSDF element (the one
    ``swap`` added right after the opening tag), dropping the scene's own."""
    def fix(block):
        body = block.group(0)
        for name in names:
            pat = re.compile(r'\s*<float name="%s" value="[^"]*"\s*/>' % re.escape(name))
            hits = list(pat.finditer(body))
            for h in reversed(hits[1:]):
                body = body[:h.start()] + body[h.end():]
        return body
    return re.sub(r'<bsdf type="(?:msx_posfree|roughconductor|roughdielectric)".*?</bsdf>', fix, text, flags=re.S)


def resize(mi, scene, width, height):
    """The first sensor's film at width × height (uncropped), whatever the scene declares."""
    p = mi.traverse(scene)
    key = next(k for k in p.keys() if k.endswith("film.size"))
    prefix = key[:-len("size")]
    p[key] = mi.ScalarVector2u(width, height)
    p[prefix + "crop_size"] = mi.ScalarVector2u(width, height)
    p[prefix + "crop_offset"] = mi.ScalarPoint2u(0, 0)
    p.update()


def resolve(name):
    """The scene file of ``name`` (a path, or a shipped scene's name), with the generated assets a shipped scene
    refers to (``$assets``, msx/assets.py) written beside it when missing: a checkout's ``scenes/`` has none
    until ``python3 -m msx assets scenes/assets`` or this."""
    p = Path(name)
    import msx

    if p.exists():
        if "$assets" in p.read_text():
            from msx import assets

            assets.ensure(p.resolve().parent / "assets")
        return p.resolve()

    return Path(msx.scene_path(name))


def start_engine():
    """drjit and Mitsuba in ``llvm_ad_rgb`` with msx registered (libLLVM 19 where DRJIT_LIBLLVM_PATH is unset):
    (drjit, mitsuba)."""
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    return dr, mi


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--models", default="single,auto,correlated,heitz,invariance")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=320, help="image width (height keeps the scene's aspect)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], help="name=value set on every swapped BSDF (e.g. alpha=0.8)")
    ap.add_argument("-D", "--define", action="append", default=[], help="scene default key=value")
    args = ap.parse_args(argv)
    dr, mi = start_engine()
    from msx.jit import auto as jit_auto

    overrides = dict(kv.split("=", 1) for kv in args.set)
    defines = dict(kv.split("=", 1) for kv in args.define)
    models = [None] + [m for m in args.models.split(",") if m]
    for name in args.scenes:
        path = resolve(name)
        text = path.read_text()
        if not _OPEN.search(text):
            print("%s: no roughconductor or roughdielectric to swap" % path, file=sys.stderr)
            continue
        sources = {m: _drop_duplicates(swap(text, m, overrides), overrides) for m in models}
        mi.file_resolver().prepend(str(path.parent))  # includes and assets, as load_file
        probe = mi.load_string(sources[None], **defines)
        film = probe.sensors()[0].film().size()
        width = args.res
        height = max(1, round(film[1] * width / film[0]))
        del probe
        params = dict(defines)
        times = {m: [] for m in models}
        cpu = {}  # the process's CPU time of each timed render (less sensitive to other work on the cores)
        means = {}
        walked = {}
        if True:
            for rep in range(args.repeats):
                for m in models:
                    scene = mi.load_string(sources[m], **params)
                    resize(mi, scene, width, height)
                    if m == "auto" and rep == 0:  # an extra render that counts (its own kernel)
                        counter = jit_auto.count_calls()
                        dr.eval(mi.render(scene, spp=args.spp, seed=rep))
                        dr.sync_thread()
                        walked[m] = jit_auto.walked_fraction(counter)
                        jit_auto.count_calls(stop=True)
                    img = mi.render(scene, spp=args.spp, seed=rep)
                    dr.eval(img)
                    dr.sync_thread()
                    t0, c0 = time.perf_counter(), time.process_time()
                    img = mi.render(scene, spp=args.spp, seed=100 + rep)
                    dr.eval(img)
                    dr.sync_thread()
                    times[m].append(time.perf_counter() - t0)
                    cpu.setdefault(m, []).append(time.process_time() - c0)
                    means.setdefault(m, []).append(float(dr.mean(img, axis=None).array[0]))
                    del scene, img
                print("%s: round %d/%d done" % (path.name, rep + 1, args.repeats), file=sys.stderr)
        base_t = statistics.median(times[None])
        base_m = statistics.mean(means[None])
        label = ", ".join("%s=%s" % kv for kv in overrides.items())
        print("\n%s (%d×%d, %d spp%s): built-in %.3f s" % (path.name, width, height, args.spp,
                                                          ", " + label if label else "", base_t))
        base_c = statistics.median(cpu[None])
        print("| model | time × built-in | CPU time × built-in | image mean × built-in | calls that walk |")
        print("|---|---|---|---|---|")
        for m in models[1:]:
            print("| %s | %.2f | %.2f | %.4f | %s |" % (m, statistics.median(times[m]) / base_t,
                                                       statistics.median(cpu[m]) / base_c,
                                                       statistics.mean(means[m]) / base_m,
                                                       "%.1f %%" % (100 * walked[m]) if m in walked else ""))
        print("load average at the end: %s" % " ".join(open("/proc/loadavg").read().split()[:3]))


if __name__ == "__main__":
    main()
