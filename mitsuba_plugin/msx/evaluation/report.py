"""The report page: one self-contained HTML file (images embedded), whose
first section — which model to use — is derived from this run's numbers."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

from .common import row_label

CSS = """
body{font-family:system-ui,sans-serif;max-width:1250px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}h3{margin-top:1.5em}
table{border-collapse:collapse;font-size:.85em;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}
th{background:#f3f3f3}td.l,th.l{text-align:left}img{max-width:100%;border:1px solid #eee}
.ok{color:#080;font-weight:bold}.bad{color:#b00;font-weight:bold}.warn{color:#b60;font-weight:bold}.note{color:#555;font-size:.9em}
.box{background:#f7f9fc;border:1px solid #dde5f0;padding:.6em 1em;border-radius:4px}
"""


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return f'<p><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"><br><span class="note">{html.escape(alt)} ' \
           f'(<code>{Path(path).name}</code>)</span></p>'


def _sec(t):
    if t is None or not math.isfinite(t):
        return "never (bias floor above the target)" if t == float("inf") else "—"
    if t < 1:
        return f"{t * 1000:.0f} ms"
    if t < 600:
        return f"{t:.1f} s"
    return f"{t / 60:.0f} min"


def _e(x, digits=2):
    return "—" if x is None or not math.isfinite(x) else f"{x:.{digits}e}"


def _which_model(scenes):
    """Per scene type and error target: the fastest row that reaches the target, among all rows and among
    estimators of the Smith reference itself."""
    out = ["<h2>Which model should I use?</h2>",
           '<p class="note">Derived from this run: for each scene and each target error (relative MSE over the '
           "object's pixels, against the converged Smith multiple-scattering reference), the model × estimator "
           "that reaches the target in the least render time, from the fit error(t) = bias² + c/t of its sweep. "
           "A model whose bias² is above the target never reaches it, whatever the time.</p>",
           "<table><tr><th class=l>scene</th><th class=l>lighting</th><th>target</th><th class=l>fastest overall</th>"
           "<th>time</th><th class=l>fastest unbiased (Smith reference)</th><th>time</th><th class=l>cannot reach it</th></tr>"]
    for rep in scenes:
        sc = rep["scene"]
        for target, key in ((1e-2, "t1"), (1e-3, "t01")):
            rows = [t for t in rep["table"] if t["label"] != "built-in" or True]
            finite = [t for t in rows if math.isfinite(t[key])]
            best = min(finite, key=lambda t: t[key]) if finite else None
            unb = [t for t in finite if t["unbiased"]]
            best_u = min(unb, key=lambda t: t[key]) if unb else None
            never = [t["label"] for t in rows if t[key] == float("inf")]
            out.append(f"<tr><td class=l>{sc.name}</td><td class=l>{sc.lighting}</td><td>{target * 100:g} %</td>"
                       f"<td class=l>{best['label'] if best else '—'}</td><td>{_sec(best[key]) if best else '—'}</td>"
                       f"<td class=l>{best_u['label'] if best_u else '—'}</td><td>{_sec(best_u[key]) if best_u else '—'}</td>"
                       f"<td class=l>{', '.join(never) or '—'}</td></tr>")
    out.append("</table>")
    # Closest biased model to the reference per scene (lowest bias²), stated from the numbers.
    lines = []
    for rep in scenes:
        biased = [t for t in rep["table"] if not t["unbiased"] and t["label"] not in ("built-in", "single")]
        if biased:
            b = min(biased, key=lambda t: t["bias2"])
            order = ", ".join(f"{t['label']} {t['bias2']:.1e}" for t in sorted(biased, key=lambda t: t["bias2"]))
            lines.append(f"<li><b>{rep['scene'].name}</b>: the approximation closest to the Smith reference is "
                         f"<b>{b['label']}</b> (bias² {b['bias2']:.1e}); all of them, closest first: {order}.</li>")
    out.append("<p>Closest approximations to the reference in this run (bias² = relative MSE of the converged "
               "render against the reference, noise removed; negative values are noise):</p><ul>" + "".join(lines) + "</ul>")
    return "\n".join(out)


def _scene_section(rep):
    sc = rep["scene"]
    ref = rep["ref"]
    sp = rep["speed"]
    out = [f"<h3>{html.escape(sc.title)}</h3>"]
    out.append(_img(rep["pngs"]["evt"], f"error against time, {sc.name}"))
    out.append(f'<p class="box">Reference: <b>{row_label(ref["row"])}</b> (Heitz\'s BSDF with the heights integrated '
               f"out; its efficiency 1/(variance × time) in this sweep is {ref['efficiency_vs_heitz']:.2f} × heitz's) "
               f"at {ref['spp']} spp, {_sec(ref['seconds'])}"
               f"{' (from the cache)' if ref['cached'] else ''}; its own noise, from two independent halves, "
               f"{_e(ref['noise'])} relative MSE = {ref['noise'] / ref['smallest']:.3f} × the smallest plotted error "
               f"({_e(ref['smallest'])}). Object pixels: {rep['mask_pixels']}.</p>")
    ratio = sp["ratio"]
    verdict = ("meets" if ratio <= 0.25 else "misses") if math.isfinite(ratio) else "cannot evaluate"
    out.append(f'<p class="box">Speed target: heitz reaches relative MSE {_e(sp["target"])} at {sp["spp"]} spp in '
               f"{_sec(sp['heitz_seconds'])}; {html.escape(sp['best'])} (the faster invariance estimator here) needs "
               f"{_sec(sp['best_seconds'])} for the same error: "
               f"<b>{ratio:.2f} × heitz's time</b> (target ≤ 0.25: {verdict}"
               f"{'' if ratio <= 0.25 or not math.isfinite(ratio) else f', by {ratio / 0.25:.1f}×'}).</p>")
    if sp.get("single_seconds"):
        # Where the time goes: `single` costs what the route costs around any BSDF (ray tracing, the plugin's
        # per-call overhead); what a model adds to it is its own cost.
        own_h = sp["heitz_seconds"] - sp["single_seconds"]
        own_i = sp["best_top_seconds"] - sp["single_seconds"]
        share = own_i / sp["best_top_seconds"] if sp["best_top_seconds"] > 0 else float("nan")
        own_ratio = sp["best_seconds"] * share / own_h if own_h > 0 else float("nan")
        out.append(f'<p class="note">Where the time goes at {sp["spp"]} spp: <code>single</code> takes '
                   f'{_sec(sp["single_seconds"])} in this route ({sp["single_seconds"] / sp["builtin_seconds"]:.1f} × '
                   f"the built-in), which every model pays; beyond it heitz adds {_sec(own_h)} and {html.escape(sp['best'])} "
                   f"{_sec(own_i)}. Counting only the models' own cost (the share of each render beyond "
                   f"<code>single</code>), {html.escape(sp['best'])} would reach heitz's error in {own_ratio:.2f} × "
                   "heitz's time.</p>")
    out.append("<table><tr><th class=l>model</th><th>bias²</th><th>variance at top spp</th><th>slope (var vs spp)</th>"
               "<th>time to 1 %</th><th>time to 0.1 %</th><th>seconds at top spp</th><th>mean over object</th></tr>")
    for t in rep["table"]:
        out.append(f"<tr><td class=l>{t['label']}{' (unbiased)' if t['unbiased'] else ''}</td><td>{_e(t['bias2'])}</td>"
                   f"<td>{_e(t['top']['variance'])}</td><td>{t['slope']:.2f}</td><td>{_sec(t['t1'])}</td>"
                   f"<td>{_sec(t['t01'])}</td><td>{t['top']['seconds']:.3f}</td>"
                   f"<td>{rep['energy'][t['label']]:.4f}</td></tr>")
    out.append("</table>")
    out.append(_img(rep["pngs"]["crops"], f"equal-time crops, {sc.name}"))
    out.append(_img(rep["pngs"]["models"], f"converged renders per model, {sc.name}"))
    out.append(_img(rep["pngs"]["diff"], f"difference to the built-in, {sc.name}"))
    return "\n".join(out)


def _side_section(rep):
    out = [f"<h3>{html.escape(rep['title'])}</h3>", "<table><tr><th class=l>model</th><th>mean over the object</th>"
           f"<th>built-in</th><th>ratio</th><th>± s.e. of the difference</th></tr>"]
    for e in rep["energy"]:
        out.append(f"<tr><td class=l>{e['label']}</td><td>{e['value']:.4f}</td><td>{e['builtin']:.4f}</td>"
                   f"<td>{e['ratio']:.3f}</td><td>{e['se']:.4f}</td></tr>")
    out.append("</table>")
    out.append(_img(rep["pngs"]["models"], f"{rep['name']} per model"))
    out.append(_img(rep["pngs"]["diff"], f"{rep['name']}: difference to the built-in"))
    return "\n".join(out)


def _fail_table(fails):
    if not fails:
        return "<p>No cell crossed a threshold.</p>"
    out = ["<table><tr><th class=l>model</th><th class=l>surface</th><th class=l>fails on</th><th>threshold</th>"
           "<th>cells</th><th class=l>α range</th><th class=l>θ_i range (°)</th><th>worst</th><th class=l>at (α, θ_i)</th></tr>"]
    for f in sorted(fails, key=lambda f: (f["surface"], f["model"], f["estimator"], f["metric"])):
        label = f["model"] if f["estimator"] == "pt" else f"{f['model']} {f['estimator']}"
        out.append(f"<tr><td class=l>{label}</td><td class=l>{f['surface']}</td><td class=l>{f['metric']}</td>"
                   f"<td>{f['threshold']:g}</td><td>{f['cells']}/{f['of']}</td>"
                   f"<td class=l>{f['alpha_range'][0]:.3g} – {f['alpha_range'][1]:.3g}</td>"
                   f"<td class=l>{f['theta_range'][0]:g} – {f['theta_range'][1]:g}</td><td>{f['worst']:.3g}</td>"
                   f"<td class=l>({f['worst_at'][0]:.3g}, {f['worst_at'][1]:g})</td></tr>")
    out.append("</table>")
    return "\n".join(out)


def page(ctx):
    st = ctx["settings"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>msx evaluation</title><style>{CSS}</style>"
             "</head><body>",
             f"<h1>msx evaluation{' (quick)' if st.quick else ''}: speed against accuracy</h1>",
             f'<p class="note">Route: {html.escape(ctx["route"])}. Machine: {ctx["machine"]}. Total time of this run: '
             f"{ctx['seconds']:.0f} s. Sweep: {st.size}×{st.size} pixels, spp {st.spps}, {st.seeds} seeds per spp. "
             "Every number and chart on this page was computed by this run; the CSV files beside it hold them "
             "(<code>results.csv</code>, <code>atlas.csv</code>, <code>energy.csv</code>).</p>"]
    parts.append(_which_model(ctx["scenes"]))
    parts.append("<h2>Physics checks of this run</h2><ul>")
    for c in ctx["checks"]:
        cls, state = ("bad", "FAILED") if not c["ok"] else ("warn", "warning") if c.get("warning") else ("ok", "ok")
        warning = f" — <b>{html.escape(c['warning'])}</b>" if c.get("warning") else ""
        parts.append(f"<li><span class={cls}>{state}</span> {html.escape(c['name'])}: {html.escape(c['detail'])}"
                     f"{warning}</li>")
    parts.append("</ul>")
    parts.append("<h2>Error against time</h2><p class='note'>Relative MSE = mean((I − R)²) / mean(R²) over the pixels "
                 "covered by the object (all channels), R the reference; one line per model × estimator over the spp "
                 "sweep (mean over seeds; seconds = wall time of <code>mi.render</code>). Dashed horizontal lines: the "
                 "bias floors of the approximations. bias² is the seed-mean at the top spp against the reference with "
                 "both noises subtracted; variance is the spread of one render over seeds.</p>")
    for rep in ctx["scenes"]:
        parts.append(_scene_section(rep))
    parts.append("<h2>Side by side</h2>")
    for rep in ctx["side"]:
        parts.append(_side_section(rep))
    parts.append("<h2>Stability atlas</h2><p class='note'>Per cell: the furnace error |1 − E| (F = 1 conductor, "
                 "η = 1.5 dielectric in importance mode, E integrated from <code>eval</code> with a proposal independent "
                 "of the core), the noise of one <code>eval</code> call at fixed directions, raw non-finite or negative "
                 "values counted by the C ABI before it cleans them (×), the largest single contribution to the "
                 "furnace estimate relative to its mean (firefly risk) and the time per call.</p>")
    parts.append("<h3>Where each method fails</h3>" + _fail_table(ctx["fails"]))
    for p in ctx["stability"]:
        parts.append(_img(p, Path(p).stem))
    parts.append(_img(ctx["extras"], "p_exit cancellation and Fast-MSX energy"))
    parts.append("<h2>Lobes</h2><p class='note'>f·cos θ_o in the plane of incidence per scattering order (analytic "
                 "models: their whole value as order 1), with the energy each model reflects (E_r) and transmits "
                 "(E_t).</p>")
    for p in ctx["lobes"]:
        parts.append(_img(p, Path(p).stem))
    parts.append("<h2>Energy</h2>" + _img(ctx["energy"], "directional albedo against roughness"))
    if ctx.get("micro"):
        parts.append("<h2>Against explicit microgeometry</h2><p class='note'>Every model against rays traced on "
                     "generated Beckmann height fields (docs/microgeometry.md): relative energy error per scattering "
                     "order and L1 of the lobe; charts in <code>microgeometry/</code>.</p>" + ctx["micro"]["html"])
    parts.append("</body></html>")
    return "\n".join(parts)
