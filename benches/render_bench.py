"""Render benchmark: scalar render time of the Fig. 9 setup (copper sphere, GGX
α = 1, directional light) with `msx_posfree` vs Mitsuba's `roughconductor`.

Times are interleaved over repeats and the median is kept; only ratios
measured in this one run are meaningful (machines are shared and noisy).

    python3 benches/render_bench.py [--spp 16] [--res 128] [--repeats 3] [--variant scalar_rgb]
"""

import argparse
import statistics
import time


def scene_dict(mi, bsdf, res, spp):
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {
            "type": "perspective",
            "fov": 30,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4.2], target=[0, 0, 0], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
        },
        "light": {"type": "directional", "direction": [0, -0.5, -1], "irradiance": {"type": "rgb", "value": 3.0}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--variant", default="scalar_rgb")
    args = ap.parse_args()

    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    dr.set_thread_count(1)
    import msx

    msx.register()
    common = {"material": "Cu", "distribution": "ggx", "alpha": 1.0}
    configs = {
        "roughconductor": {"type": "roughconductor", **common},
        "msx single": {"type": "msx_posfree", "model": "single", **common},
        "msx uncorrelated": {"type": "msx_posfree", "model": "uncorrelated", **common},
        "msx correlated": {"type": "msx_posfree", "model": "correlated", **common},
    }
    scenes = {k: mi.load_dict(scene_dict(mi, v, args.res, args.spp)) for k, v in configs.items()}
    times = {k: [] for k in configs}
    for k, s in scenes.items():  # warm-up
        mi.render(s, spp=1)
    for _ in range(args.repeats):
        for k, s in scenes.items():
            t0 = time.perf_counter()
            mi.render(s, spp=args.spp)
            times[k].append(time.perf_counter() - t0)
    base = statistics.median(times["roughconductor"])
    print(f"{args.variant}, {args.res}x{args.res}, {args.spp} spp, 1 render thread, median of {args.repeats}")
    print(f"{'BSDF':<20} {'median s':>9} {'x roughconductor':>17}")
    for k, ts in times.items():
        m = statistics.median(ts)
        print(f"{k:<20} {m:9.3f} {m / base:17.2f}")


if __name__ == "__main__":
    main()
