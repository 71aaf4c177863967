"""Recover the roughness of a rough copper sphere by inverse rendering, with and without multiple scattering.

The target is rendered with msx's ``heitz`` model (Heitz et al. 2016's random walk: the Smith
multiple-scattering BSDF itself), GGX α = 0.8, converged. Then α is fitted from a wrong start with
Mitsuba's Adam optimizer and ``prb`` gradients (Dr.Jit engine, ``llvm_ad_rgb``), once per BSDF:

- ``msx_posfree`` with ``model='correlated'`` (Wang 2022's height-correlated position-free walk: the same
  BSDF up to its segment term, so it should land close to 0.8);
- ``msx_posfree`` with ``model='invariance'`` (Cui 2023: the target's own BSDF in expectation);
- Mitsuba's ``roughconductor`` (single scattering: it loses the energy of the higher orders, so it must
  darken and narrow its lobe to explain the target, and its α is biased).

    python3 examples/fit_roughness.py [--quick] [--out DIR]

Prints the loss per iteration, saves ``fit_roughness.png`` (α and loss against iteration) in DIR (default
``out/``, never the repository root), and ends
with one line: ``fitted alpha: msx-correlated A, msx-invariance B, roughconductor C (true 0.8)``.
"""

import argparse
import os
import sys
import time

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
TRUE_ALPHA = 0.8
START_ALPHA = 0.3


def scene_dict(bsdf, size):
    import mitsuba as mi

    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    return {
        "type": "scene",
        "integrator": {"type": "prb", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 34, "to_world": look,
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent"}},
        "sky": {"type": "constant", "radiance": 0.35},
        "sun": {"type": "directional", "direction": [0.35, -0.3, -1.0], "irradiance": 4.0},
        "ball": {"type": "sphere", "radius": 1.0, "bsdf": bsdf},
    }


def fit(label, bsdf, target, settings, log):
    """Adam on α from START_ALPHA: (α per iteration, loss per iteration)."""
    import drjit as dr
    import mitsuba as mi

    scene = mi.load_dict(scene_dict(bsdf, settings["size"]))
    params = mi.traverse(scene)
    key = "ball.bsdf.alpha.value"
    opt = mi.ad.Adam(lr=settings["lr"])
    opt[key] = mi.Float(START_ALPHA)
    params.update(opt)
    alphas, losses = [], []
    t0 = time.perf_counter()
    for it in range(settings["iterations"]):
        if it == (3 * settings["iterations"]) // 5:
            # Noisy gradients make Adam hover around the optimum with a spread proportional to its step:
            # a smaller step for the last 40 %, whose last quarter gives the fitted value.
            opt.set_learning_rate(settings["lr"] / 4)
        # The primal image and the gradient from different seeds: the squared error's gradient is then an
        # unbiased estimate of the expected loss's.
        img = mi.render(scene, params, spp=settings["spp"], spp_grad=settings["spp"], seed=2 * it,
                        seed_grad=2 * it + 1)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        opt.step()
        opt[key] = dr.clip(opt[key], 0.02, 2.0)
        params.update(opt)
        alphas.append(float(opt[key][0]))
        losses.append(float(loss.array[0]))
        done = it + 1
        eta = (time.perf_counter() - t0) / done * (settings["iterations"] - done)
        log(f"\r{label}: iteration {done}/{settings['iterations']}  alpha {alphas[-1]:.4f}  "
            f"loss {losses[-1]:.3e}  (about {eta:.0f} s left)   ")
    log("\n")
    return alphas, losses


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small settings (a few minutes)")
    ap.add_argument("--out", default="out", help="folder of fit_roughness.png (default: out/, created)")
    args = ap.parse_args(argv)
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19
    import drjit as dr
    import mitsuba as mi

    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception as e:  # no LLVM: say what is needed
        sys.exit(f"fit_roughness: llvm_ad_rgb is not usable here ({e}); it needs libLLVM >= 19 "
                 f"(DRJIT_LIBLLVM_PATH)")
    import msx

    msx.register()
    settings = (dict(size=32, target_spp=2048, spp=16, iterations=100, lr=0.03) if args.quick else
                dict(size=64, target_spp=4096, spp=16, iterations=200, lr=0.03))
    os.makedirs(args.out, exist_ok=True)

    def log(text):
        sys.stderr.write(text)
        sys.stderr.flush()

    log(f"target: heitz, GGX alpha {TRUE_ALPHA}, {settings['target_spp']} spp, {settings['size']}²\n")
    target_scene = mi.load_dict(scene_dict({"type": "msx_posfree", "material": "Cu", "distribution": "ggx",
                                            "model": "heitz", "alpha": TRUE_ALPHA}, settings["size"]))
    target = mi.render(target_scene, spp=settings["target_spp"], seed=10**6)
    dr.eval(target)
    del target_scene

    runs = {
        "msx-correlated": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx", "model": "correlated",
                           "alpha": START_ALPHA},
        "msx-invariance": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx", "model": "invariance",
                           "alpha": START_ALPHA},
        "roughconductor": {"type": "roughconductor", "material": "Cu", "distribution": "ggx",
                           "alpha": START_ALPHA},
    }
    curves = {label: fit(label, bsdf, target, settings, log) for label, bsdf in runs.items()}
    # The fitted value: the mean of the last quarter of the iterations (Adam with noisy gradients hovers).
    fitted = {label: sum(a[-len(a) // 4:]) / len(a[-len(a) // 4:]) for label, (a, _) in curves.items()}

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax_a, ax_l) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
        for label, (alphas, losses) in curves.items():
            ax_a.plot(range(1, len(alphas) + 1), alphas, label=f"{label} (fitted {fitted[label]:.3f})")
            ax_l.semilogy(range(1, len(losses) + 1), losses, label=label)
        ax_a.axhline(TRUE_ALPHA, color="k", ls="--", lw=1, label=f"true alpha {TRUE_ALPHA}")
        ax_a.set_xlabel("iteration")
        ax_a.set_ylabel("GGX alpha")
        ax_a.legend()
        ax_l.set_xlabel("iteration")
        ax_l.set_ylabel("mean squared error against the target")
        ax_l.legend()
        fig.suptitle("Fitting the roughness of rough copper (target: Heitz 2016 multiple scattering, alpha 0.8)")
        os.makedirs(args.out, exist_ok=True)
        path = os.path.join(args.out, "fit_roughness.png")
        fig.savefig(path, dpi=110)
        log(f"wrote {path}\n")
    except ImportError:
        log("matplotlib is not installed: no chart\n")
    print(f"fitted alpha: msx-correlated {fitted['msx-correlated']:.3f}, msx-invariance {fitted['msx-invariance']:.3f}, "
          f"roughconductor {fitted['roughconductor']:.3f} (true {TRUE_ALPHA})")


if __name__ == "__main__":
    main()
