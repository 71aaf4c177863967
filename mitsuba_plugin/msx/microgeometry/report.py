"""Ground truth from explicit microgeometry: the report's parts — the error tables (CSV, Markdown, HTML), the
lobe and energy charts per configuration and the chart of the generated surfaces. :func:`msx.microgeometry.compare`
calls them; the numbers come from the API (``__init__.py``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..evaluation.common import pct
from . import _ERR_LEN, MODELS, ORDER_LABELS, SimResult, _alpha_label, _has_order, _native


def _fmt_pct(x, se=None):
    """A fraction as a signed percentage with its standard error (as the evaluation's report writes them)."""
    return pct(None if x is None else x * 100, None if se is None else se * 100)


_CSV_COLUMNS = (
    ["surface", "alpha", "alpha_u", "alpha_v", "theta_i", "model"]
    + [f"{p}{lab}{q}" for lab in ORDER_LABELS for p, q in
       (("E", "_sim"), ("E", "_sim_se"), ("E", "_model"), ("E", "_model_se"), ("rel", ""), ("rel", "_se"))]
    + ["ER_sim", "ER_model", "relR", "ET_sim", "ET_model", "relT", "L1", "L1_noise"]
)


def write_tables(out, rows, surfaces, link_prefix=""):
    """errors.csv (everything), errors.md and errors.html (per configuration),
    and a summary table per surface and model (returned as Markdown)."""
    import csv

    with open(out / "errors.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(_CSV_COLUMNS)
        for r in rows:
            w.writerow([r[c] if isinstance(r[c], str) else f"{r[c]:.6g}" for c in _CSV_COLUMNS])
    # Summary: mean |relative error| per order and mean L1 per surface and model.
    summ = ["| surface | model | order 1 | order 2 | order 3 | order 4+ | total | reflected (dielectric) "
            "| L1 total lobe (noise) |",
            "|---|---|---|---|---|---|---|---|---|"]
    for s in surfaces:
        for model in MODELS[s]:
            sel = [r for r in rows if r["surface"] == s and r["model"] == model]
            if not sel:
                continue
            cells = []
            for lab in ORDER_LABELS:
                if not _has_order(model, lab):
                    cells.append("—")
                    continue
                v = [abs(r[f"rel{lab}"]) for r in sel if np.isfinite(r[f"rel{lab}"]) and r[f"E{lab}_sim"] > 1e-3]
                cells.append(f"{np.mean(v) * 100:.1f} % (max {np.max(v) * 100:.0f} %)" if v else "—")
            if s == "dielectric":
                v = [abs(r["relR"]) for r in sel if np.isfinite(r["relR"])]
                cells.append(f"{np.mean(v) * 100:.1f} % (max {np.max(v) * 100:.0f} %)")
            else:
                cells.append("—")
            l1 = np.mean([r["L1"] for r in sel])
            l1n = np.mean([r["L1_noise"] for r in sel])
            summ.append(f"| {s} | {model} | " + " | ".join(cells) + f" | {l1:.4f} ({l1n:.4f}) |")
    summary = ("Mean |relative error| of each order's energy over the configurations (orders carrying more than "
               "0.1 % of the flux), largest in brackets (lossless facets: the total is 1 in the simulation; the "
               "dielectric's reflected share E_r is the informative split); L1 of the total lobe ∫|f_model − f_sim| cos θ_o dω "
               "(fraction of the incident flux; in brackets its expected value from Monte Carlo noise alone). "
               "single is order 1 alone; compensated is a whole lobe without orders (—). Per configuration: "
               f"[errors.md]({link_prefix}errors.md), every number: [errors.csv]({link_prefix}errors.csv).\n\n" + "\n".join(summ))
    # Per configuration.
    lines = []
    html = []
    for s in surfaces:
        lines += ["", f"### {s}", "",
                  "| α | θ_i | model | E1 | E2 | E3 | E4+ | total | L1 (noise) |", "|---|---|---|---|---|---|---|---|---|"]
        html += [f"<h3>{s}</h3>", "<table>", "<tr><th>α</th><th>θ<sub>i</sub></th><th>model</th><th>E1</th>"
                 "<th>E2</th><th>E3</th><th>E4+</th><th>total</th><th>L1 (noise)</th></tr>"]
        sel = [r for r in rows if r["surface"] == s]
        keys = []
        for r in sel:
            if (r["alpha"], r["theta_i"]) not in keys:
                keys.append((r["alpha"], r["theta_i"]))
        for a, t in keys:
            cfg_rows = [r for r in sel if r["alpha"] == a and r["theta_i"] == t]
            r0 = cfg_rows[0]
            sim_cells = [f"{r0[f'E{lab}_sim']:.4f} ± {r0[f'E{lab}_sim_se']:.4f}" for lab in ORDER_LABELS]
            lines.append(f"| {a} | {math.degrees(t):.0f}° | **simulation** | " + " | ".join(sim_cells) + " | |")
            html.append(f"<tr><td>{a}</td><td>{math.degrees(t):.0f}°</td><td><b>simulation</b></td>"
                        + "".join(f"<td>{c}</td>" for c in sim_cells) + "<td></td></tr>")
            for r in cfg_rows:
                cells = []
                for lab in ORDER_LABELS:
                    if not _has_order(r["model"], lab):
                        cells.append("—")
                    else:
                        cells.append(_fmt_pct(r[f"rel{lab}"], r[f"rel{lab}_se"]))
                l1 = f"{r['L1']:.4f} ({r['L1_noise']:.4f})"
                lines.append(f"| | | {r['model']} | " + " | ".join(cells) + f" | {l1} |")
                html.append(f"<tr><td></td><td></td><td>{r['model']}</td>" + "".join(f"<td>{c}</td>" for c in cells)
                            + f"<td>{l1}</td></tr>")
        html.append("</table>")
    head = ("Simulated energy per order (fraction of the incident flux, ± standard error) and each model's "
            "relative error (model − simulation)/simulation ± its standard error; L1 of the total lobe with the "
            "value expected from noise alone in brackets.\n")
    (out / "errors.md").write_text(head + "\n".join(lines) + "\n")
    html_s = "<p>" + head + "</p>\n" + "\n".join(html) + "\n"
    (out / "errors.html").write_text(html_s)
    return summary, html_s


def surface_chart(out_dir, alpha=(1.0, 0.1), grid=1024, corr_cells=16.0, n_surfaces=16, seed=0):
    """surfaces.png: one generated surface (heights) and the slope histograms
    of `n_surfaces` realisations along x and y (standardised by Beckmann's
    α/√2) against the unit Gaussian of Beckmann's P22, with the spread between
    realisations as error bars. Returns the path (None without matplotlib)."""
    plt = _plt()
    if plt is None:
        return None
    ffi, lib = _native()
    p = ffi.new("MsxSimParams *")
    p.surface = lib.MSX_SURFACE_CONDUCTOR
    p.alpha_u, p.alpha_v, p.theta_i, p.k = alpha[0], alpha[1], 0.0, 1.0
    p.grid, p.corr_cells, p.surfaces, p.seed = grid, corr_cells, n_surfaces, seed
    out = ffi.new("MsxSim **")
    err = ffi.new("char[]", _ERR_LEN)
    if lib.msx_sim_new(p, out, err, _ERR_LEN) != lib.MSX_OK:
        raise ValueError(ffi.string(err).decode(errors="replace"))
    sim = ffi.gc(out[0], lib.msx_sim_free)
    h = np.empty(grid * grid)
    dx, dy = ffi.new("double *"), ffi.new("double *")
    edges = np.linspace(-4, 4, 33)
    hx, hy = [], []
    first = None
    for s in range(n_surfaces):
        lib.msx_sim_surface(sim, s, ffi.cast("double *", h.ctypes.data), h.size, dx, dy)
        g = h.reshape(grid, grid).copy()
        first = g if first is None else first
        sx = (np.roll(g, -1, axis=1) - g) / dx[0] / (alpha[0] / math.sqrt(2))
        sy = (np.roll(g, -1, axis=0) - g) / dy[0] / (alpha[1] / math.sqrt(2))
        hx.append(np.histogram(sx, edges, density=True)[0])
        hy.append(np.histogram(sy, edges, density=True)[0])
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    ext = [0, grid * dx[0], 0, grid * dy[0]]
    im = ax[0].imshow(first[: grid // 4, : grid // 4], origin="lower", extent=[e / 4 for e in ext], aspect="auto",
                      cmap="gray")
    fig.colorbar(im, ax=ax[0], label="height / σ")
    ax[0].set_title(f"a quarter of one surface (α = {_alpha_label(alpha)})", fontsize=8)
    ax[0].set_xlabel("x / σ", fontsize=8)
    ax[0].set_ylabel("y / σ", fontsize=8)
    centres = 0.5 * (edges[1:] + edges[:-1])
    gauss = np.exp(-centres ** 2 / 2) / math.sqrt(2 * math.pi)
    for a, hist, name in ((ax[1], hx, "x"), (ax[2], hy, "y")):
        hist = np.array(hist)
        a.errorbar(centres, hist.mean(0), yerr=hist.std(0, ddof=1) / math.sqrt(len(hist)), fmt="k.", ms=4,
                   label=f"{n_surfaces} generated surfaces")
        a.plot(centres, gauss, "r-", lw=1, label="Beckmann P22 marginal")
        a.set_yscale("log")
        a.set_ylim(1e-5, 1)
        a.set_xlabel(f"slope along {name} / (α_{name}/√2)", fontsize=8)
        a.legend(fontsize=7)
    fig.tight_layout()
    path = Path(out_dir) / "surfaces.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)


def _plt():
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        return plt
    except ImportError:
        return None


def _color(model):
    """The evaluation's one colour per model (evaluation/palette.py), so that a model looks the same here and
    in every chart of the report."""
    from ..evaluation.palette import color

    return color(model)


def _in_plane(res: SimResult, v):
    """Values of the φ bins centred on φ_i (plotted at −θ_o) and φ_i + π (at +θ_o)
    as one curve over the signed angle in degrees."""
    te = res.theta_edges()
    tc = np.degrees(0.5 * (te[:-1] + te[1:]))
    back = v[..., 0]
    fwd = v[..., res.phi_bins // 2]
    x = np.concatenate([-tc[::-1], tc])
    y = np.concatenate([back[..., ::-1], fwd], axis=-1)
    return x, y


def lobe_chart(out, res, model_data, surface, alpha, theta):
    plt = _plt()
    if plt is None:
        return None
    sv, sse = res.lobe_estimates()
    fig, axes = plt.subplots(1, 5, figsize=(17, 3.3))
    limit = 180 if surface == "dielectric" else 90
    for k, lab in enumerate(ORDER_LABELS):
        ax = axes[k]
        x, y = _in_plane(res, sv[k])
        _, ye = _in_plane(res, sse[k])
        sel = np.abs(x) <= limit
        ax.errorbar(x[sel], y[sel], yerr=ye[sel], fmt="k.", ms=3, lw=0.8, label="simulation", zorder=5)
        for model, (mv, _) in model_data.items():
            if not _has_order(model, lab):
                continue
            _, my = _in_plane(res, mv[k])
            ax.plot(x[sel], my[sel], "-", color=_color(model), lw=1.1, label=model)
        for v in (-90, 90):
            if limit > 90:
                ax.axvline(v, color="0.7", lw=0.6)
        ax.set_title(f"order {lab}")
        ax.set_xlabel("θ_o in the plane of incidence (°; < 0: towards the light)", fontsize=7)
        ax.set_xlim(-limit, limit)
        ax.tick_params(labelsize=7)
    axes[0].set_ylabel("dE/dω = f·|cos θ_o| (1/sr)")
    axes[4].legend(fontsize=6)
    return _save(plt, fig, out / f"lobes_{surface}_a{alpha[0]:g}-{alpha[1]:g}_t{theta:g}.png",
                 f"{surface}, Beckmann α = {_alpha_label(alpha)}, θ_i = {math.degrees(theta):.0f}°")


def energy_chart(out, rows, surface, alphas, thetas):
    plt = _plt()
    if plt is None:
        return None
    sel = [r for r in rows if r["surface"] == surface]
    if not sel:
        return None
    fig, axes = plt.subplots(len(alphas), 5, figsize=(16, 2.6 * len(alphas)), squeeze=False)
    for ia, a in enumerate(alphas):
        al = _alpha_label(a)
        for k, lab in enumerate(ORDER_LABELS):
            ax = axes[ia][k]
            rs = sorted({r["theta_i"] for r in sel if r["alpha"] == al})
            xs = [math.degrees(t) for t in rs]
            base = [next(r for r in sel if r["alpha"] == al and r["theta_i"] == t) for t in rs]
            ax.errorbar(xs, [b[f"E{lab}_sim"] for b in base], yerr=[b[f"E{lab}_sim_se"] for b in base], fmt="ko",
                        ms=4, label="simulation", zorder=5)
            for model in MODELS[surface]:
                if not _has_order(model, lab):
                    continue
                ms = [next(r for r in sel if r["alpha"] == al and r["theta_i"] == t and r["model"] == model) for t in rs]
                ax.plot(xs, [m[f"E{lab}_model"] for m in ms], "-", marker=".", color=_color(model), lw=1,
                        label=model)
            ax.set_title(f"α = {al}, order {lab}", fontsize=8)
            ax.tick_params(labelsize=7)
            if ia == len(alphas) - 1:
                ax.set_xlabel("θ_i (degrees)", fontsize=7)
    axes[0][4].legend(fontsize=6)
    return _save(plt, fig, out / f"energy_{surface}.png",
                 f"{surface}: energy per scattering order (fraction of the incident flux)")


def _save(plt, fig, path, title):
    """Titles, lays out and writes a chart; returns its path."""
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)
