"""Recover the normal map of a rough copper plate by inverse rendering, through a multiple-scattering walk.

A plate of rough copper (Beckmann α = 0.5, Mitsuba's default distribution) carries a small normal map of
tilted patches (Mitsuba's ``normalmap`` BSDF around the copper). A target image is rendered with the true
map; then the map is fitted from a flat start with Mitsuba's Adam optimizer and ``prb`` gradients (Dr.Jit
engine, ``llvm_ad_rgb``), twice:

- ``msx_posfree`` with ``model='correlated'`` (Wang 2022's height-correlated position-free walk) and
  ``differentiate_directions=true``, on a target rendered with it: the gradients flow through the directions
  the normal map tilts, through the walk (docs/gradients.md, "Directions through the walks");
- Mitsuba's ``roughconductor``, on a target rendered with it: the control, same scene, same settings.

    python3 examples/fit_normal_map.py [--quick] [--out DIR]

Prints the loss per iteration, saves ``fit_normal_map.png`` (the true and fitted maps, and the mean angle
error against iteration) in DIR (default ``out/``, never the repository root), and ends with one line:
``mean normal error (degrees): msx-correlated A, roughconductor B (start C)``.
"""

import argparse
import math
import os
import sys
import time

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
ALPHA = 0.5
TILT = 0.35  # largest tilt of a true normal, radians (20°)


def true_normals(res):
    """Unit tangent-space normals of the target map: one random tilt per texel (fixed seed)."""
    import numpy as np

    rng = np.random.default_rng(1)
    theta = TILT * np.sqrt(rng.uniform(0.2, 1.0, (res, res)))
    phi = rng.uniform(0.0, 2.0 * math.pi, (res, res))
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def scene_dict(inner, data, size):
    import mitsuba as mi

    look = mi.ScalarTransform4f().look_at(origin=[0, -1.2, 3.2], target=[0, 0, 0], up=[0, 1, 0])
    return {
        "type": "scene",
        "integrator": {"type": "prb", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": 36, "to_world": look,
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        # Three coloured suns from three sides (photometric stereo): a texel's colour then fixes both
        # components of its tilt, which one light alone would leave ambiguous.
        "sky": {"type": "constant", "radiance": 0.1},
        "red": {"type": "directional", "direction": [-0.7, 0.0, -1.0], "irradiance": {"type": "rgb", "value": [8, 0, 0]}},
        "green": {"type": "directional", "direction": [0.0, -0.7, -1.0],
                  "irradiance": {"type": "rgb", "value": [0, 8, 0]}},
        "blue": {"type": "directional", "direction": [0.5, 0.5, -1.0], "irradiance": {"type": "rgb", "value": [0, 0, 8]}},
        "plate": {"type": "rectangle",
                  "bsdf": {"type": "normalmap",
                           "normalmap": {"type": "bitmap", "raw": True, "filter_type": "nearest",
                                         "data": mi.TensorXf(data)},
                           "bsdf": inner}},
    }


def encode(normals):
    """The bitmap's values of unit normals: (n + 1)/2."""
    return ((normals + 1.0) * 0.5).astype("float32")


def decode(data):
    """Unit normals of the bitmap's values."""
    import numpy as np

    n = 2.0 * np.asarray(data, dtype=np.float64) - 1.0
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def angle_error(data, truth):
    """Mean angle between fitted and true normals, degrees."""
    import numpy as np

    cos = np.clip(np.sum(decode(data) * truth, axis=-1), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).mean())


def fit(label, inner, truth, settings, log):
    """Adam on the map from flat: (final map values, mean angle error per iteration)."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    res = truth.shape[0]
    target_scene = mi.load_dict(scene_dict(inner, encode(truth), settings["size"]))
    target = mi.render(target_scene, spp=settings["target_spp"], seed=0)
    flat = np.zeros_like(truth)
    flat[..., 2] = 1.0
    scene = mi.load_dict(scene_dict(inner, encode(flat), settings["size"]))
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("normalmap.data"))
    opt = mi.ad.Adam(lr=settings["lr"])
    opt[key] = params[key]
    params.update(opt)
    errors = [angle_error(np.array(params[key]), truth)]
    t0 = time.perf_counter()
    for it in range(settings["iterations"]):
        img = mi.render(scene, params, spp=settings["spp"], seed=it + 1)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        opt.step()
        # Keep the stored normals valid: unit length, in the upper hemisphere.
        n = decode(np.array(opt[key]).reshape(res, res, 3))
        n[..., 2] = np.maximum(n[..., 2], 0.2)
        opt[key] = mi.TensorXf(encode(n / np.linalg.norm(n, axis=-1, keepdims=True)))
        params.update(opt)
        errors.append(angle_error(np.array(params[key]), truth))
        log("%s iteration %d/%d: loss %.3e, mean normal error %.2f°, %.1f s" % (
            label, it + 1, settings["iterations"], float(np.asarray(loss).ravel()[0]), errors[-1], time.perf_counter() - t0))
    return np.array(params[key]).reshape(res, res, 3), errors


def save_chart(path, truth, fits):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(fits) + 2, figsize=(3.2 * (len(fits) + 2), 3.2))
    axes[0].imshow(encode(truth), interpolation="nearest")
    axes[0].set_title("true map")
    for ax, (label, (data, _)) in zip(axes[1:], fits.items()):
        ax.imshow(data, interpolation="nearest")
        ax.set_title("fitted: " + label)
    for ax in axes[:-1]:
        ax.set_xticks([])
        ax.set_yticks([])
    for label, (_, errors) in fits.items():
        axes[-1].plot(errors, label=label)
    axes[-1].set_xlabel("iteration")
    axes[-1].set_ylabel("mean normal error (°)")
    axes[-1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small settings (a couple of minutes)")
    ap.add_argument("--out", default="out", help="folder of fit_normal_map.png (default: out/, created)")
    args = ap.parse_args(argv)
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    settings = ({"res": 4, "size": 32, "spp": 8, "target_spp": 256, "iterations": 40, "lr": 0.03} if args.quick else
                {"res": 6, "size": 48, "spp": 8, "target_spp": 1024, "iterations": 80, "lr": 0.02})
    truth = true_normals(settings["res"])
    start = angle_error(encode(truth * 0.0 + [0.0, 0.0, 1.0]), truth)

    def log(text):
        print(text, file=sys.stderr, flush=True)

    copper = {"material": "Cu", "alpha": ALPHA, "distribution": "beckmann"}
    fits = {
        "msx-correlated": fit("msx-correlated", {"type": "msx_posfree", "model": "correlated",
                                                 "differentiate_directions": True, **copper}, truth, settings, log),
        "roughconductor": fit("roughconductor", {"type": "roughconductor", **copper}, truth, settings, log),
    }
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "fit_normal_map.png")
    save_chart(path, truth, fits)
    log("wrote " + os.path.abspath(path))
    print("mean normal error (degrees): msx-correlated %.2f, roughconductor %.2f (start %.2f)" % (
        fits["msx-correlated"][1][-1], fits["roughconductor"][1][-1], start))


if __name__ == "__main__":
    main()
