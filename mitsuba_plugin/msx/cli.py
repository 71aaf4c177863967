"""Command line: ``msx render SCENE.xml`` and ``msx compare``.

Scalar variants run one render thread per process (the GIL serialises Python
BSDFs, see INTEGRATION.md) and parallelise over worker processes, each
rendering a share of the samples with its own seed; the shares are averaged.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

DEFAULT_VARIANT = "scalar_rgb"

# ----------------------------------------------------------------- workers

_worker_scene = None


def _setup(variant: str):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(variant)
    if variant.startswith("scalar"):
        dr.set_thread_count(1)
    import msx

    msx.register()
    if variant.startswith("llvm_"):
        # Native code cannot run in drjit's symbolic kernels (INTEGRATION.md).
        msx.evaluated_mode().enable()
    return mi


def _worker_init(variant: str, scene_path: str, params: dict):
    global _worker_scene
    mi = _setup(variant)
    _worker_scene = mi.load_file(scene_path, **params)


def _worker_render(task):
    import mitsuba as mi
    import numpy as np

    seed, spp = task
    t0 = time.perf_counter()
    img = mi.render(_worker_scene, seed=seed, spp=spp)
    return seed, spp, np.array(img, dtype=np.float64), time.perf_counter() - t0


def _chunks(spp: int, n: int):
    n = max(1, min(n, spp))
    base, extra = divmod(spp, n)
    return [base + (1 if k < extra else 0) for k in range(n)]


def render_scene(scene: str, *, variant: str = DEFAULT_VARIANT, spp: int | None = None, params: dict | None = None,
                 workers: int = 1, seed: int = 0, chunks: int | None = None, progress: bool = True, label: str = ""):
    """Renders `scene` and returns (image as float64 array [H, W, C], per-chunk images, wall seconds).

    The samples are split into `chunks` renders with distinct seeds (default:
    max(workers, 4)), run on `workers` processes and averaged (weighted by spp).
    """
    import numpy as np

    params = {k: str(v) for k, v in (params or {}).items()}
    if spp is None:
        spp = int(params.get("spp", 16))
    params["spp"] = str(spp)
    counts = _chunks(spp, chunks or max(workers, 4))
    tasks = [(seed * 1000 + k, c) for k, c in enumerate(counts)]
    results = []
    t0 = time.perf_counter()

    def report(done):
        if progress:
            el = time.perf_counter() - t0
            eta = el / done * (len(tasks) - done) if done else 0.0
            sys.stderr.write(f"\r{label or Path(scene).name}: {done}/{len(tasks)} chunks, {el:6.1f} s elapsed, ETA {eta:6.1f} s ")
            sys.stderr.flush()

    report(0)
    if workers <= 1:
        _worker_init(variant, scene, params)
        for t in tasks:
            results.append(_worker_render(t))
            report(len(results))
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_worker_init, initargs=(variant, scene, params)) as pool:
            for r in pool.imap_unordered(_worker_render, tasks):
                results.append(r)
                report(len(results))
    if progress:
        sys.stderr.write("\n")
    wall = time.perf_counter() - t0
    results.sort(key=lambda r: r[0])
    total = sum(r[1] for r in results)
    image = sum(r[2] * r[1] for r in results) / total
    if not np.all(np.isfinite(image)):
        raise RuntimeError(f"non-finite pixels in the render of {scene}")
    return image, [(r[1], r[2]) for r in results], wall


def write_image(path: Path, image, variant: str = DEFAULT_VARIANT):
    """Writes an EXR (linear) and a PNG (sRGB) next to each other."""
    import mitsuba as mi
    import numpy as np

    if mi.variant() is None:
        mi.set_variant(variant)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.ascontiguousarray(image, dtype=np.float32)
    bmp = mi.Bitmap(arr, pixel_format=mi.Bitmap.PixelFormat.RGB if arr.shape[-1] == 3 else mi.Bitmap.PixelFormat.Y)
    bmp.write(str(path.with_suffix(".exr")))
    bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True).write(str(path.with_suffix(".png")))


def _parse_defines(items):
    params = {}
    for item in items or []:
        if "=" not in item:
            raise SystemExit(f"-D expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        params[k] = v
    return params


def cmd_render(args):
    params = _parse_defines(args.define)
    out = Path(args.output or Path(args.scene).with_suffix("").name + ".exr")
    img, _, wall = render_scene(args.scene, variant=args.variant, spp=args.spp, params=params,
                                workers=args.workers, seed=args.seed)
    write_image(out, img, args.variant)
    print(f"wrote {out.with_suffix('.exr')} and {out.with_suffix('.png')} ({wall:.1f} s)")


def main(argv=None):
    p = argparse.ArgumentParser(prog="msx", description="Multiple-scattering microfacet BSDFs for Mitsuba 3")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render one scene")
    r.add_argument("scene")
    r.add_argument("-o", "--output", help="output path (.exr; a .png is written beside it)")
    r.add_argument("--spp", type=int, default=None, help="samples per pixel (default: the scene's)")
    r.add_argument("--variant", default=DEFAULT_VARIANT)
    r.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="worker processes")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("-D", "--define", action="append", help="scene parameter key=value (XML <default>)")
    r.set_defaults(func=cmd_render)

    c = sub.add_parser("compare", help="render the paper comparisons side by side with Mitsuba's built-ins")
    c.add_argument("--scenes", default="scenes", help="folder with the scene XMLs")
    c.add_argument("--out", default="out", help="report folder")
    c.add_argument("--spp", type=int, default=32)
    c.add_argument("--variant", default=DEFAULT_VARIANT)
    c.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    c.add_argument("--seed", type=int, default=0)
    c.set_defaults(func=lambda a: __import__("msx.compare", fromlist=["run"]).run(a))

    args = p.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
