"""The conductor walks' MIS density (`mis_density`): today's `single_cosine` against Cui et al. 2023's `cui`
and `cui_typo` (the H-function as the authors' code prints it), docs/paper-notes.md.

Render level (llvm_ad_rgb, the Dr.Jit engine): a rough copper sphere (GGX) under msx's generated sky plus a
small area light, `path` with max_depth 6. For each walk, α and density, RENDERS renders from independent
seeds give the per-pixel variance at equal spp (mean over the sphere's pixels of the per-pixel sample variance
across renders, relative to single_cosine), the time per render (median, kernels compiled beforehand) and the
efficiency 1/(variance × time) relative to single_cosine. The image means must agree (the density changes the
noise, not the expectation): the table prints their difference in units of its standard error.

BSDF level (the Rust core): the L1 distance ∫|p − q| dω of each density p, normalised to integrate to 1, to the
normalised f·cos θ_o lobe q of the walk (Cu, mean of the RGB channels), q estimated from the walk's own samples
(weights binned on the hemisphere, equal-solid-angle bins); `noise` is the L1 that the histogram's noise alone
contributes (half the L1 between two independent halves). Also the integral of each density over the
hemisphere (before normalisation).

    python3 benches/mis_density_bench.py [--quick] [--only render|lobe] [--models correlated,invariance]
        [--alphas 0.1,0.2,0.3,0.6,1.0,1.5] [--renders 32]
"""

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np


def sphere_scene(mi, msx, model, alpha, density, res, spp):
    sky = os.path.join(os.path.dirname(msx.scene_path("fig01_metals.xml")), "assets", "sky.exr")
    T = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 32,
                   "to_world": T().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": spp},
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "env": {"type": "envmap", "filename": sky, "scale": 0.6},
        "light": {"type": "rectangle",
                  "to_world": T().look_at(origin=[2.0, 2.5, 2.0], target=[0, 0, 0], up=[0, 1, 0]) @ T().scale(0.2),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 40.0}}},
        "sphere": {"type": "sphere", "bsdf": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx",
                                              "alpha": alpha, "model": model, "mis_density": density}},
    })


def sphere_mask(res, fov_deg=32.0):
    """Pixels whose centre ray hits the unit sphere seen from distance 4 (a margin of one pixel inside)."""
    t = math.tan(math.radians(fov_deg) / 2)
    c = (np.arange(res) + 0.5) / res * 2 - 1
    x, y = np.meshgrid(c * t, c * t)
    ang = np.arctan(np.hypot(x, y))
    return ang < math.asin(1 / 4) - 2 * t / res


def render_table(args):
    """Per walk and α: the three densities' scenes rendered in turn, seed after seed (so that the machine's
    load hits them alike), RENDERS times each after one compiling render."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import msx

    msx.register()
    densities = ("single_cosine", "cui", "cui_typo")
    mask = sphere_mask(args.res)
    rng = np.random.default_rng(1)
    print("\n| model | α | density | variance / single_cosine (90 % interval) | median pixel variance / single_cosine "
          "| time / single_cosine | efficiency / single_cosine (90 % interval) | mean difference (σ) |")
    print("|---|---|---|---|---|---|---|---|")
    for model in args.models:
        for alpha in args.alphas:
            scenes = {d: sphere_scene(mi, msx, model, alpha, d, args.res, args.spp) for d in densities}
            for i, d in enumerate(densities):
                dr.eval(mi.render(scenes[d], seed=999_999 + i))  # compile
            imgs = {d: [] for d in densities}
            times = {d: [] for d in densities}
            for k in range(args.renders):
                for i, d in enumerate(densities):
                    t0 = time.perf_counter()
                    img = mi.render(scenes[d], seed=100_000 * (i + 1) + k)
                    dr.eval(img)
                    times[d].append(time.perf_counter() - t0)
                    imgs[d].append(np.array(img, np.float64).mean(axis=2)[mask])
            imgs = {d: np.array(v) for d, v in imgs.items()}
            t = {d: statistics.median(v) for d, v in times.items()}
            # Bootstrap over renders (the same resampled indices for every density) for the variance ratio.
            boot = rng.integers(0, args.renders, (300, args.renders))

            def mean_var(a, idx=None):
                a = a if idx is None else a[idx]
                return a.var(axis=0, ddof=1).mean()

            ref = imgs["single_cosine"]
            v0, med0, m0 = mean_var(ref), np.median(ref.var(axis=0, ddof=1)), ref.mean(axis=1)
            for d in densities[1:]:
                a = imgs[d]
                v, med, m = mean_var(a), np.median(a.var(axis=0, ddof=1)), a.mean(axis=1)
                ratios = np.array([mean_var(a, b) / mean_var(ref, b) for b in boot])
                lo, hi = np.nanquantile(ratios, [0.05, 0.95])  # (a resample of one render has no variance)
                tr = t[d] / t["single_cosine"]
                z = (m.mean() - m0.mean()) / math.sqrt(m.var(ddof=1) / len(m) + m0.var(ddof=1) / len(m0))
                print("| %s | %g | %s | %.3f (%.2f–%.2f) | %.3f | %.3f | %.3f (%.2f–%.2f) | %+.1f |"
                      % (model, alpha, d, v / v0, lo, hi, med / med0, tr, 1 / (v / v0 * tr), 1 / (hi * tr),
                         1 / (lo * tr), z))
                sys.stdout.flush()
            print("  %s α=%g: render %.3f s (single_cosine)" % (model, alpha, t["single_cosine"]), file=sys.stderr)


def hemisphere_bins(n_mu, n_phi, sub):
    """Sub-sample directions of equal-solid-angle bins (uniform in μ and φ) and each point's solid angle."""
    mu = (np.arange(n_mu * sub) + 0.5) / (n_mu * sub)
    phi = (np.arange(n_phi * sub) + 0.5) / (n_phi * sub) * 2 * np.pi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M * M)
    dirs = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    return dirs, 2 * np.pi / (n_mu * sub * n_phi * sub)


def bin_sum(values, n_mu, n_phi, sub):
    return values.reshape(n_mu, sub, n_phi, sub).sum(axis=(1, 3))


def lobe_table(args):
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    from msx.core import CoreBsdf

    p = mi.traverse(mi.load_dict({"type": "roughconductor", "material": "Cu"}))
    eta, k = [float(x) for x in np.array(p["eta.value"]).ravel()], [float(x) for x in np.array(p["k.value"]).ravel()]
    n_mu, n_phi, sub = 32, 64, 4
    dirs, dw = hemisphere_bins(n_mu, n_phi, sub)
    densities = ("single_cosine", "cui", "cui_typo")
    print("\n| model | α | θ_i | L1 single_cosine | L1 cui | L1 cui_typo | noise | ∫ single_cosine | ∫ cui | ∫ cui_typo |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(3)
    for model in args.lobe_models:
        for alpha in args.lobe_alphas:
            for theta in args.thetas:
                wi = np.array([math.sin(math.radians(theta)), 0.0, math.cos(math.radians(theta))])
                c = CoreBsdf(model=model, alpha=alpha, eta=eta, k=k, channels=3, seed=11)
                n = args.lobe_samples
                wis = np.repeat(wi[None], n, 0).astype(np.float32)
                wo, weight, pdf = c.sample(wis, rng.random((3, n)).astype(np.float32))
                w = np.asarray(weight, np.float64).mean(axis=0)
                good = (pdf > 0) & (wo[:, 2] > 0)
                i_mu = np.minimum((wo[good, 2] * n_mu).astype(int), n_mu - 1)
                i_phi = np.minimum(((np.arctan2(wo[good, 1], wo[good, 0]) % (2 * np.pi)) / (2 * np.pi) * n_phi)
                                   .astype(int), n_phi - 1)
                halves = []
                for h in (0, 1):
                    sel = np.arange(good.sum()) % 2 == h
                    hist = np.zeros((n_mu, n_phi))
                    np.add.at(hist, (i_mu[sel], i_phi[sel]), w[good][sel])
                    halves.append(hist / hist.sum())
                q = (halves[0] + halves[1]) / 2
                noise = 0.5 * np.abs(halves[0] - halves[1]).sum()
                wi_all = np.repeat(wi[None], len(dirs), 0).astype(np.float32)
                l1, integ = [], []
                for d in densities:
                    pdf_d = CoreBsdf(model=model, alpha=alpha, channels=1, mis_density=d).pdf(
                        wi_all, dirs.astype(np.float32))
                    mass = bin_sum(pdf_d * dw, n_mu, n_phi, sub)
                    integ.append(mass.sum())
                    l1.append(np.abs(mass / mass.sum() - q).sum())
                print("| %s | %g | %g° | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f | %.3f |"
                      % (model, alpha, theta, *l1, noise, *integ))
                sys.stdout.flush()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small settings (a smoke run, not for the tables)")
    ap.add_argument("--only", choices=("render", "lobe"), help="one of the two tables")
    ap.add_argument("--models", default="correlated,invariance", help="the walks of the render table")
    ap.add_argument("--alphas", default="0.1,0.2,0.3,0.6,1.0,1.5", help="the roughnesses of the render table")
    ap.add_argument("--renders", type=int, default=32, help="independent renders per density")
    args = ap.parse_args()
    args.models = tuple(args.models.split(","))
    args.alphas = tuple(float(a) for a in args.alphas.split(","))
    args.res, args.spp = 64, 16
    args.lobe_models = ("correlated",)
    args.lobe_alphas = (0.1, 0.5, 1.0, 1.5)
    args.thetas = (0, 45, 75)
    args.lobe_samples = 1 << 22
    if args.quick:
        args.models, args.alphas, args.res, args.spp, args.renders = ("correlated",), (0.3, 1.0), 32, 4, 4
        args.lobe_alphas, args.thetas, args.lobe_samples = (0.5,), (45,), 1 << 18
    t0 = time.time()
    if args.only != "lobe":
        render_table(args)
    if args.only != "render":
        lobe_table(args)
    print("\n(%.0f s)" % (time.time() - t0))


if __name__ == "__main__":
    main()
