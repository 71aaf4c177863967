"""model="auto" vs the converged model it approximates (`correlated`): the
render time saved at equal error, on the comparison scenes and the roughness
ramp (README.md, model table).

For each scene: a reference image of `correlated` at --ref-spp; then
--repeats rounds, each rendering `correlated` and `auto` at --spp with the
same seed (so both share camera and light samples), one render thread, in this
process (scene load and table building happen in an untimed warm-up). Per
model: the median wall time, the mean squared error against the reference
over the msx part of the image, and the energy difference. The efficiency
ratio (t·MSE of correlated)/(t·MSE of auto) is the speed-up at equal error
while auto's bias is small against the noise (its energy difference is
printed to check that). Only ratios from one run mean anything.

    python3 benches/auto_bench.py [--spp 16] [--repeats 5] [--ref-spp 256] [--scale 0.5] [--scenes ...]
"""

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# scene -> (XML, extra parameters, msx region: "right" half or "all")
SCENES = {
    "roughness_ramp": ("roughness_ramp.xml", {}, "right", (160, 400)),
    "fig09_copper_sphere": ("fig09_copper_sphere.xml", {}, "right", (384, 192)),
    "furnace_sphere": ("furnace_sphere.xml", {"bsdf": "msx_posfree"}, "all", (192, 192)),
    "fig01_dielectric_sphere": ("fig01_dielectric_sphere.xml", {"bsdf": "msx_posfree"}, "all", (192, 192)),
}


def region(img, where):
    if where == "right":
        w = img.shape[1] // 2
        return img[:, w:]
    return img


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--scale", type=float, default=0.5, help="resolution scale of the scenes")
    ap.add_argument("--tolerance", type=float, default=None, help="auto_tolerance (default: the library's)")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--variant", default="scalar_rgb")
    args = ap.parse_args()

    import statistics

    import numpy as np

    from msx._render import render_scene

    models = ("correlated", "auto")
    rows = []
    t_all = time.perf_counter()
    for name in args.scenes.split(","):
        xml, extra, where, (w, h) = SCENES[name]
        path = str(ROOT / "scenes" / xml)
        size = {"width": max(8, int(w * args.scale)), "height": max(8, int(h * args.scale))}
        ref, _, _ = render_scene(path, variant=args.variant, spp=args.ref_spp, seed=9001,
                                 params={**extra, **size, "model": "correlated"}, label=f"{name} reference")
        ref_r = region(ref, where)
        params = {m: {**extra, **size, "model": m} for m in models}
        if args.tolerance is not None:
            params["auto"]["auto_tolerance"] = args.tolerance
        for m in models:  # warm-up: scene load, tables built on first use
            render_scene(path, variant=args.variant, spp=1, seed=7, params=params[m], progress=False)
        res = {m: [] for m in models}
        for rep in range(args.repeats):
            for m in models:
                img, _, wall = render_scene(path, variant=args.variant, spp=args.spp, seed=100 + rep, params=params[m],
                                            chunks=1, progress=False)
                r = region(img, where)
                res[m].append((wall, float(np.mean((r - ref_r) ** 2)), float(np.mean(r) / np.mean(ref_r) - 1)))
            sys.stderr.write(f"\r{name}: {rep + 1}/{args.repeats} rounds ")
        sys.stderr.write("\n")
        for m in models:
            t = statistics.median(x[0] for x in res[m])
            mse = statistics.fmean(x[1] for x in res[m])
            de = statistics.fmean(x[2] for x in res[m])
            rows.append((name, m, t, mse, de))

    print(f"\n{args.variant}, scale {args.scale}, {args.spp} spp, {args.repeats} interleaved repeats (median time), "
          f"reference {args.ref_spp} spp (correlated), 1 render thread; total {time.perf_counter() - t_all:.0f} s")
    print(f"{'scene':<24} {'model':<11} {'time s':>8} {'MSE':>10} {'energy Δ':>9} {'time ×':>7} {'MSE ×':>7} {'eff':>7}")
    base = {}
    for name, m, t, mse, de in rows:
        if m == "correlated":
            base[name] = (t, mse)
        bt, bm = base[name]
        print(f"{name:<24} {m:<11} {t:8.2f} {mse:10.3e} {de:+9.4f} {t / bt:7.2f} {mse / bm:7.3f} {bt * bm / (t * mse):6.2f}x")
    print("time ×, MSE ×: relative to correlated; eff = (t·MSE)_correlated / (t·MSE)_model (speed-up at equal error);\n"
          "energy Δ = mean/mean(reference) − 1 (the reference's own noise included).")


if __name__ == "__main__":
    main()
