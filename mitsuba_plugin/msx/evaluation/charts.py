"""The report's charts (matplotlib, Agg backend). Each function writes one PNG
and returns its path."""

from __future__ import annotations

import math

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
from matplotlib.colors import LogNorm, TwoSlopeNorm  # noqa: E402

from .common import row_label  # noqa: E402
from .palette import color  # noqa: E402

# Line style per row label: colour by model (palette.py, shared with the microgeometry charts), dotted for BDPT.
STYLE = {label: dict(color=color(label), ls=ls, marker=m) for label, ls, m in [
    ("built-in", "--", "x"), ("single", "-", "x"), ("uncorrelated", "-", "o"), ("uncorrelated bdpt", ":", "s"),
    ("correlated", "-", "o"), ("correlated bdpt", ":", "s"), ("heitz", "-", "^"), ("invariance", "-", "v"),
    ("invariance bdpt", ":", "s"), ("auto", "-", "d"), ("compensated", "-", "P"), ("fastmsx", "-", "*"),
]}


def tonemap(img, exposure=1.0):
    """Linear RGB to sRGB-encoded [0, 1] (clipped), for display."""
    x = np.clip(img * exposure, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _mantissa_exponent(x):
    e = math.floor(math.log10(x) + 1e-9)
    return round(x / 10.0 ** e, 6), e


def log_ticks(axis):
    """Labels of a log axis that never collide: decades (10ⁿ) as major labels; minor ticks labelled only when
    fewer than two decades are in view, and then only 2·10ⁿ and 5·10ⁿ (matplotlib's default labels a subset of
    2…9·10ⁿ there, whose labels run into each other: "3×10⁻³4×10⁻³")."""
    lo, hi = sorted(axis.get_view_interval())
    if not (lo > 0 and math.isfinite(hi)):
        return
    decades = math.floor(math.log10(hi) + 1e-9) - math.ceil(math.log10(lo) - 1e-9) + 1  # 10ⁿ in view
    axis.set_major_locator(matplotlib.ticker.LogLocator(base=10.0))
    axis.set_major_formatter(matplotlib.ticker.LogFormatterSciNotation())
    axis.set_minor_locator(matplotlib.ticker.LogLocator(base=10.0, subs=np.arange(2, 10), numticks=100))

    def minor(x, pos=None):
        m, e = _mantissa_exponent(x)
        return f"$\\mathdefault{{{m:g}\\times10^{{{e}}}}}$" if m in (2.0, 5.0) else ""

    axis.set_minor_formatter(matplotlib.ticker.FuncFormatter(minor) if decades < 2
                             else matplotlib.ticker.NullFormatter())


def error_vs_time(path, title, stats):
    """Left: relative MSE against render seconds (log-log), one line per model × estimator, dashed at each
    biased model's bias floor. Right: the split of the top-spp error into bias² and variance."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw=dict(width_ratios=[1.5, 1]))
    labels = []
    for r in stats:
        if r["label"] not in labels:
            labels.append(r["label"])
    for label in labels:
        rs = sorted([r for r in stats if r["label"] == label], key=lambda r: r["spp"])
        st = STYLE.get(label, {})
        ax.plot([r["seconds"] for r in rs], [r["rel_mse"] for r in rs], label=label, lw=1.4, ms=4, **st)
        b2 = rs[-1]["bias2"]
        if not rs[-1]["unbiased"] and b2 > 0:
            ax.axhline(b2, color=st.get("color", "k"), lw=0.6, ls=(0, (2, 4)), alpha=0.7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("render seconds (this machine, this route)")
    ax.set_ylabel("relative MSE over the object's pixels")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, ncol=2)
    top = {}
    for r in stats:
        if r["label"] not in top or r["spp"] > top[r["label"]]["spp"]:
            top[r["label"]] = r
    xs = np.arange(len(labels))
    # bias² with 3 standard errors; a value that is zero within noise is drawn as its upper bound (an open
    # triangle), never as a bar at an arbitrary floor.
    z = 3.0
    b2 = np.array([top[lb]["bias2"] for lb in labels])
    se = np.array([top[lb].get("bias2_se", 0.0) for lb in labels])
    var = np.array([top[lb]["variance"] for lb in labels])
    sig = b2 > z * se
    bx.bar(xs[sig] - 0.2, b2[sig], 0.4, label="bias² (converged vs reference), ± 3 s.e.", color="tab:red",
           yerr=z * se[sig], error_kw=dict(lw=0.8, capsize=2))
    if (~sig).any():
        bx.plot(xs[~sig] - 0.2, np.maximum(b2[~sig], 0.0) + z * se[~sig], "v", mfc="none", mec="tab:red", ms=6,
                label="bias² zero within noise: upper bound (3 s.e.)")
    spps = sorted({top[lb]["spp"] for lb in labels})
    at = f"{spps[0]} spp" if len(spps) == 1 else f"the row's largest spp ({spps[0]}–{spps[-1]}, adaptive sweep)"
    bx.bar(xs + 0.2, var, 0.4, label=f"variance of one render at {at}", color="tab:blue")
    bx.set_yscale("log")
    bx.set_xticks(xs, labels, rotation=60, ha="right", fontsize=7)
    bx.set_ylabel("relative squared error (relative MSE units)")
    bx.legend(fontsize=7)
    bx.grid(True, axis="y", which="both", lw=0.3, alpha=0.5)
    for a in (ax.xaxis, ax.yaxis, bx.yaxis):
        a.axes.autoscale_view()
        log_ticks(a)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def image_grid(path, images, labels, title=None, cols=None, exposure=1.0, crop=None):
    """Tone-mapped images with their label under each."""
    n = len(images)
    cols = cols or n
    rows = math.ceil(n / cols)
    h, w = images[0].shape[:2]
    if crop is not None:
        (y0, y1), (x0, x1) = crop
        images = [im[y0:y1, x0:x1] for im in images]
        h, w = y1 - y0, x1 - x0
    fig, axes = plt.subplots(rows, cols, figsize=(2.0 * cols * max(1.0, w / h), 2.7 * rows), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if i < n:
            ax.imshow(tonemap(images[i], exposure), interpolation="nearest")
            ax.text(0.5, -0.03, labels[i], transform=ax.transAxes, ha="center", va="top", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def difference_grid(path, reference, images, labels, mask, title):
    """(image − reference) on the same pixels, luminance, in false colour with one symmetric scale."""
    lum = lambda im: im[..., :3] @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
    diffs = [np.where(mask, lum(im) - lum(reference), np.nan) for im in images]
    finite = np.concatenate([d[np.isfinite(d)] for d in diffs]) if diffs else np.zeros(1)
    lim = float(np.percentile(np.abs(finite), 99.5)) if finite.size else 1.0
    lim = lim if lim > 0 else 1.0
    n = len(images)
    cols = min(n, 6)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.0 * cols + 0.8, 2.3 * rows), squeeze=False)
    im = None
    for i, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if i < n:
            im = ax.imshow(diffs[i], cmap="RdBu_r", norm=TwoSlopeNorm(0.0, -lim, lim), interpolation="nearest")
            ax.text(0.5, -0.03, labels[i], transform=ax.transAxes, ha="center", va="top", fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="luminance difference (object pixels)")
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=110, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


METRICS = [("furnace_error", "energy lost or created, |1 − E|", LogNorm(1e-3, 1.0)),
           ("rel_std", "noise of one call (std ÷ mean)", LogNorm(1e-2, 10.0)),
           ("max_weight", "largest contribution ÷ mean (fireflies)", LogNorm(1.0, 1e3)),
           ("ns_per_call", "time per eval call (ns)", LogNorm(30.0, 1e4))]


def stability(path, rows, surface, alphas, thetas, failing=None):
    """Heat maps over α × θ_i: one row per model, one column per metric; cells with raw non-finite values
    are marked ×; failing(cell, metric) → True marks a cell beyond the atlas' threshold with a white dot."""
    models = []
    for r in rows:
        key = (r["model"], r["estimator"])
        if r["surface"] == surface and key not in models:
            models.append(key)
    fig, axes = plt.subplots(len(models), len(METRICS), figsize=(3.1 * len(METRICS), 1.55 * len(models) + 0.8),
                             squeeze=False)
    ai = {a: i for i, a in enumerate(alphas)}
    ti = {t: i for i, t in enumerate(thetas)}
    for mi_, key in enumerate(models):
        cells = [r for r in rows if r["surface"] == surface and (r["model"], r["estimator"]) == key]
        for mj, (metric, name, norm) in enumerate(METRICS):
            grid = np.full((len(alphas), len(thetas)), np.nan)
            bad, over, zero = [], [], []
            for c in cells:
                if failing is not None and failing(c, metric):
                    over.append((ti[c["theta_i"]], ai[c["alpha"]]))
                v = c[metric]
                if metric == "rel_std" and v == 0:
                    v = np.nan  # no noise: every repeated call returned the same value (left white, written 0)
                    zero.append((ti[c["theta_i"]], ai[c["alpha"]]))
                grid[ai[c["alpha"]], ti[c["theta_i"]]] = max(v, norm.vmin) if np.isfinite(v) else np.nan
                if c["nonfinite"] > 0:
                    bad.append((ti[c["theta_i"]], ai[c["alpha"]]))
            ax = axes[mi_, mj]
            im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", norm=norm)
            for x, y in over:
                ax.plot(x, y, "o", ms=2.5, mfc="white", mec="none")
            for x, y in bad:
                ax.text(x, y, "×", color="red", ha="center", va="center", fontsize=9)
            if zero and len(zero) == len(cells):
                ax.text(0.5, 0.5, "0 everywhere: deterministic\n(the same value at every call)", transform=ax.transAxes,
                        ha="center", va="center", fontsize=7, color="0.35")
            else:
                for x, y in zero:
                    ax.text(x, y, "0", color="0.45", ha="center", va="center", fontsize=6)
            ax.set_xticks(range(len(thetas)), [f"{t:g}" for t in thetas], fontsize=6)
            ax.set_yticks(range(len(alphas)), [f"{a:.2g}" for a in alphas], fontsize=6)
            if mi_ == 0:
                ax.set_title(name, fontsize=8)
            if mj == 0:
                ax.set_ylabel(f"{row_label(key)}\nα", fontsize=7)
            if mi_ == len(models) - 1:
                ax.set_xlabel("θ_i (degrees)", fontsize=7)
            fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02).ax.tick_params(labelsize=6)
    fig.suptitle(f"Stability atlas: {surface.replace('_', ' ')} (× = raw non-finite or negative values; "
                 "white dot = beyond the threshold of the table \"where each method fails\";\nwhite cell marked 0 = "
                 "no noise: at the median direction pair the repeated calls returned the same value; white cell "
                 "unmarked = no finite value)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=100, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def extras(path, pexit, fastmsx_rows, alphas, thetas):
    """Bitterli & d'Eon's p_exit cancellation (median relative error, 6 bounces) and Fast-MSX's signed
    energy error E − 1, over α × θ_i."""
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    for ax, dist in zip(axes[:2], ("ggx", "beckmann")):
        grid, nonfinite = pexit[dist]
        im = ax.imshow(np.maximum(grid, 1e-17), origin="lower", aspect="auto", cmap="magma",
                       norm=LogNorm(1e-16, 1.0))
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                if nonfinite[i, j] > 0:
                    ax.text(j, i, f"{nonfinite[i, j]:.0%}", color="cyan", ha="center", va="center", fontsize=6)
        ax.set_title(f"p_exit (Bitterli & d'Eon), {dist}: median rel. error at 6 bounces\n"
                     "(cyan: share of paths with a division by zero)", fontsize=8)
        fig.colorbar(im, ax=ax)
    grid = np.full((len(alphas), len(thetas)), np.nan)
    for r in fastmsx_rows:
        grid[alphas.index(r["alpha"]), thetas.index(r["theta_i"])] = r["energy"] - 1.0
    lim = float(np.nanmax(np.abs(grid))) if np.isfinite(grid).any() else 1.0
    im = axes[2].imshow(grid, origin="lower", aspect="auto", cmap="RdBu_r", norm=TwoSlopeNorm(0.0, -lim, lim))
    axes[2].set_title("Fast-MSX: furnace energy E − 1 (red: gains energy, blue: loses)", fontsize=8)
    fig.colorbar(im, ax=axes[2])
    for ax in axes:
        ax.set_xticks(range(len(thetas)), [f"{t:g}" for t in thetas], fontsize=6)
        ax.set_yticks(range(len(alphas)), [f"{a:.2g}" for a in alphas], fontsize=6)
        ax.set_xlabel("θ_i (degrees)", fontsize=7)
        ax.set_ylabel("α", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def lobes(path, surface, data, orders):
    """Polar charts of f·cos θ_o in the plane of incidence: rows = (α, θ_i) cases, columns = orders and
    total; every model on each chart; E_r / E_t in the legend of the total."""
    cases = sorted(k for k in data if k[0] == surface)
    cols = [o for o, _ in orders] + ["total"]
    fig = plt.figure(figsize=(3.0 * len(cols) + 2.6, 3.0 * len(cases)))
    for i, key in enumerate(cases):
        case = data[key]
        th = case["theta_o"]
        models = [m for m in case if m != "theta_o"]
        for j, col in enumerate(cols):
            ax = fig.add_subplot(len(cases), len(cols), i * len(cols) + j + 1, projection="polar")
            ax.set_theta_zero_location("N")
            ax.set_theta_direction(-1)  # ω_i comes from the left; the specular lobe lies to the right
            for m in models:
                v = case[m][col]
                lab = f"{m} (E_r {case[m]['E_r']:.2f}, E_t {case[m]['E_t']:.2f})" if col == "total" else m
                # Reflection: θ_o ∈ (−90°, 90°); transmission: θ_o + 180°. Each side drawn separately.
                n = len(th) if surface != "dielectric" else len(th) // 2
                ax.plot(th[:n], v[:n], lw=1.0, label=lab, color=color(m))
                if surface == "dielectric":
                    ax.plot(th[n:], v[n:], lw=1.0, color=color(m))
            if surface != "dielectric":
                ax.set_thetamin(-90)
                ax.set_thetamax(90)
            ax.tick_params(labelsize=7)
            ax.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(3))
            ax.set_title(f"α {key[1]:g}, θ_i {math.degrees(key[2]):.0f}°: "
                         f"{'order ' + col if col != 'total' else 'total'}", fontsize=8, pad=12)
            if col == "total":
                ax.legend(fontsize=6, loc="center left", bbox_to_anchor=(1.1, 0.5))
    fig.suptitle(f"Lobes, {surface}: f·cos θ_o in the plane of incidence (radius), per scattering order", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    fig.savefig(path, dpi=90, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def energy(path, rows, thetas):
    """Directional albedo against α per model: conductor F = 1, copper per RGB channel, dielectric."""
    panels = [("conductor", "F=1", "E", "conductor, F = 1: albedo"),
              ("conductor", "Cu", "R", "copper, R channel"), ("conductor", "Cu", "G", "copper, G channel"),
              ("conductor", "Cu", "B", "copper, B channel"),
              ("dielectric", "eta=1.5", "E_r+E_t", "dielectric η 1.5: E_r + E_t"),
              ("dielectric", "eta=1.5", "E_t", "dielectric η 1.5: E_t")]
    fig, axes = plt.subplots(len(panels), len(thetas), figsize=(4.2 * len(thetas), 2.6 * len(panels)), squeeze=False)
    for i, (surface, material, part, name) in enumerate(panels):
        sel = [r for r in rows if r["surface"] == surface and r["material"] == material]
        models = []
        for r in sel:
            if r["model"] not in models:
                models.append(r["model"])
        for j, theta in enumerate(thetas):
            ax = axes[i, j]
            for m in models:
                rs = [r for r in sel if r["model"] == m and r["theta_i"] == theta]
                alphas = sorted({r["alpha"] for r in rs})
                if part == "E_r+E_t":
                    ys = [sum(r["value"] for r in rs if r["alpha"] == a) for a in alphas]
                else:
                    ys = [next(r["value"] for r in rs if r["alpha"] == a and r["part"] == part) for a in alphas]
                ax.plot(alphas, ys, label=m, lw=1.2, color=color(m), marker=".")
            ax.set_xscale("log")
            if part in ("E", "E_r+E_t"):
                ax.axhline(1.0, color="k", lw=0.6)
            ax.set_title(f"{name}, θ_i = {theta:g}°", fontsize=8)
            ax.set_xlabel("α", fontsize=7)
            ax.grid(True, lw=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=90, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


def two_references(path, smith, micro):
    """Left: each model's converged RMS error against the Smith reference per sweep scene (%, ± 3 s.e. of
    bias² propagated). Right: each model's mean lobe L1 against the ray-traced microgeometry per surface
    (± 3 s.e. over the configurations). Colours: one per model (palette.py). Error bars: the 3-standard-error
    bounds. smith: {scene: [(label, rms_pct, low, high)]}; micro: {surface: [(model, l1, low, high)]}."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6))
    for ax, data, ylabel, title in ((axes[0], smith, "converged RMS error against the Smith reference (%)",
                                     "Against the Smith reference (sweep scenes, GGX)"),
                                    (axes[1], micro, "mean lobe L1 against the traced surfaces (fraction of flux)",
                                     "Against explicit microgeometry (Beckmann, every α, θ_i)")):
        groups = list(data)
        models = []
        for g in groups:
            for m, *_ in data[g]:
                if m not in models:
                    models.append(m)
        width = 0.8 / max(1, len(models))
        for j, m in enumerate(models):
            xs, ys, es = [], [], []
            for i, g in enumerate(groups):
                for mm, v, lo, hi in data[g]:
                    if mm == m:
                        xs.append(i - 0.4 + (j + 0.5) * width)
                        ys.append(v)
                        es.append((v - lo, hi - v))
            ax.bar(xs, ys, width, yerr=np.array(es).T.reshape(2, -1), color=color(m.split(" = ")[0]), label=m,
                   error_kw=dict(lw=0.7, capsize=1.5))
        ax.set_xticks(range(len(groups)), [g.replace("_", " ") for g in groups], fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(title, fontsize=9)
        ax.grid(True, axis="y", lw=0.3)
        ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path
