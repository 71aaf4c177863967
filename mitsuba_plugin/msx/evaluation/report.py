"""The report page: one self-contained HTML file (images embedded), whose
first section — which model to use — is derived from this run's numbers."""

from __future__ import annotations

import base64
import html
import math
import os
from pathlib import Path

from . import scene_advice, uncertainty
from .atlas import FAIL
from .common import row_label
from .common import pct as _pct
from .two_references import SMITH

CSS = """
body{font-family:system-ui,sans-serif;max-width:1250px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}h3{margin-top:1.5em}
table{border-collapse:collapse;font-size:.85em;margin:.6em 0}td,th{border:1px solid #ccc;padding:.25em .5em;text-align:right}
th{background:#f3f3f3}td.l,th.l{text-align:left}img{max-width:100%;border:1px solid #eee}
.ok{color:#080;font-weight:bold}.bad{color:#b00;font-weight:bold}.warn{color:#b60;font-weight:bold}.note{color:#555;font-size:.9em}
.box{background:#f7f9fc;border:1px solid #dde5f0;padding:.6em 1em;border-radius:4px}
"""


_OUT = [None]  # the page's folder while page() writes it: links are relative to it


def _rel(path) -> str:
    """A link to a file of the run, relative to the page's folder."""
    out = _OUT[0]
    return os.path.relpath(path, out).replace(os.sep, "/") if out else Path(path).name


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode()
    return f'<p><img alt="{html.escape(alt)}" src="data:image/png;base64,{data}"><br><span class="note">{html.escape(alt)} ' \
           f'(<a href="{html.escape(_rel(path))}">{html.escape(Path(path).name)}</a>)</span></p>'


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


def _bias(t):
    """bias² ± its standard error, and a word when it is zero within noise (negative values are noise)."""
    b, se = t["bias2"], t.get("bias2_se", t.get("se"))
    txt = f"{_e(b)} ± {_e(se, 1)}"
    return txt + (" (0 within noise)" if b <= uncertainty.Z * se else "")


def _rms_bias(b2, se):
    """The converged render's relative RMS error against the reference, √bias², in %, with 0 when bias² is
    zero within noise."""
    if not math.isfinite(b2):
        return "—"
    if b2 <= uncertainty.Z * se:
        return f"≤ {100 * math.sqrt(max(b2, 0.0) + uncertainty.Z * se):.1f} %"
    return f"{100 * math.sqrt(b2):.1f} %"


def _time_cell(tf, status=None):
    """A time to a target and what it is: measured (inside the row's sweep), extrapolated ×f (f = the spp it
    needs ÷ the row's largest spp), or not reachable with the measured bias floor (uncertainty.target_status)."""
    t, f = tf
    s = (status or {}).get("status")
    if s == uncertainty.NOT_REACHABLE:
        return (f"<span class=warn>not reachable: bias floor {status['floor_pct']:.1f} ± "
                f"{status['floor_se_pct']:.1f} %</span>")
    if s == uncertainty.UNDECIDED and math.isfinite(status.get("floor_pct", float("nan"))) and status["floor_pct"] > 0:
        return f"— (bias floor {status['floor_pct']:.1f} ± {status['floor_se_pct']:.1f} %: at the target within noise)"
    if t is None or not math.isfinite(t):
        return _sec(t)
    if f <= 1.0:
        return f"{_sec(t)} (measured)"
    return f"{_sec(t)} <span class=warn>(extrapolated ×{f:.0f})</span>" if f >= 10 else \
        f"{_sec(t)} <span class=warn>(extrapolated ×{f:.1f})</span>"


def _ratio(t):
    """A row's render time per sample ÷ the built-in's, flagged as noise when its render or the built-in's took
    less than scene_advice.NOISY_RENDER (t['noisy_time'], set by the driver: the rule of msx compare SCENE.xml)."""
    txt = f"×{t['time_ratio']:.2f}"
    if t.get("noisy_time"):
        txt += " <span class=warn>(noise: renders of a few ms)</span>"
    return txt


def _mean_word(t):
    return uncertainty.sign_word(t["mean_error"], t["mean_error_se"])


# "Looks right": the converged render differs from the Smith reference by at most LOOK_MEAN % in mean radiance
# over the object and LOOK_RMS % RMS per pixel (both within noise).
LOOK_MEAN, LOOK_RMS = 2.0, 5.0


def _verdict(b2, b2_se, mean, mean_se):
    """'right' when both bounds (3 se on the pessimistic side) are within LOOK_MEAN / LOOK_RMS, 'off' when
    either error is beyond its threshold by more than 3 se, else 'undecided' (this run's noise is too large to
    tell)."""
    z = uncertainty.Z
    rms_hi = 100 * math.sqrt(max(b2 + z * b2_se, 0.0))
    rms_lo = 100 * math.sqrt(max(b2 - z * b2_se, 0.0))
    if abs(mean) + z * mean_se <= LOOK_MEAN and rms_hi <= LOOK_RMS:
        return "right"
    if abs(mean) - z * mean_se > LOOK_MEAN or rms_lo > LOOK_RMS:
        return "off"
    return "undecided"


# One label per ranking entry (docs/evaluation.md, "The advice"), in this order: "matches" needs both the
# verdict "right" and the ranking's tie with the Smith model's entry (with mean radiance within noise); an entry
# tied with the Smith model whose verdict is "undecided" is only "cannot tell" (the tie is then no evidence).
LABELS = [("matches", "<b>Matches the Smith model</b> (looks right, bias² tied with the reference's model and mean "
                      "radiance within noise)"),
          ("right", f"<b>Looks right</b> (converged render within {LOOK_MEAN:g} % of the reference in mean radiance "
                    f"and {LOOK_RMS:g} % RMS)"),
          ("undecided", "<b>Cannot tell at this run's noise</b> (the bounds straddle the thresholds)"),
          ("off", "<b>Visibly off</b>")]


def _one_label(verdict, tied_smith):
    """The one label of an entry: 'matches' when it looks right and matches the Smith model, else its verdict."""
    return "matches" if verdict == "right" and tied_smith else verdict


def _looks_right(t):
    return _verdict(t["bias2"], t["bias2_se"], t["mean_error"], t["mean_error_se"]) == "right"


def _cheap_ranges(atlas, surface, model, limit=None, theta_max=60.0):
    """Per α column of the atlas (θ_i ≤ theta_max): 'ok' when every cell's furnace error is within `limit`
    by 3 standard errors, 'fail' when one exceeds it by more than 3 standard errors, else 'undecided'.
    Returns ({alpha: state}, alphas)."""
    limit = FAIL["furnace_error"] if limit is None else limit
    z = uncertainty.Z
    cells = [r for r in atlas if r["surface"] == surface and r["model"] == model and r["estimator"] == "pt"
             and r["theta_i"] <= theta_max]
    alphas = sorted({r["alpha"] for r in cells})
    state = {}
    for a in alphas:
        col = [r for r in cells if r["alpha"] == a]
        if any(r["furnace_error"] - z * r["furnace_se"] > limit for r in col):
            state[a] = "fail"
        elif all(r["furnace_error"] + z * r["furnace_se"] <= limit for r in col):
            state[a] = "ok"
        else:
            state[a] = "undecided"
    return state, alphas


def _alpha_list(xs):
    return "{" + ", ".join(f"{a:.2g}" for a in xs) + "}"


def _alpha_span(state, alphas):
    """Words for the α columns per state."""
    if not alphas:
        return "not measured"
    parts = []
    for key, word in (("ok", "enough at α ∈ "), ("fail", "not enough at α ∈ "),
                      ("undecided", "undecided at this run's noise at α ∈ ")):
        xs = [a for a in alphas if state[a] == key]
        if xs:
            parts.append(word + _alpha_list(xs))
    return "; ".join(parts)


def _auto_saving(atlas, surface):
    """Per α: auto's time per eval call against correlated's (median over θ_i)."""
    out = []
    for a in sorted({r["alpha"] for r in atlas if r["surface"] == surface}):
        ta = [r["ns_per_call"] for r in atlas if r["surface"] == surface and r["model"] == "auto" and r["alpha"] == a]
        tc = [r["ns_per_call"] for r in atlas if r["surface"] == surface and r["model"] == "correlated"
              and r["estimator"] == "pt" and r["alpha"] == a]
        if ta and tc:
            out.append((a, sorted(ta)[len(ta) // 2] / sorted(tc)[len(tc) // 2]))
    return out


def _entries(rep):
    """The entries of a sweep scene's ranking (rows that are one model here), each with its verdict (from the
    entry's bias² and its best-measured member's mean radiance) and its one label (LABELS)."""
    by = {t["label"]: t for t in rep["table"]}
    z = uncertainty.Z
    entries = []
    for tier in rep["ranking"]:
        for e in tier:
            best = by[min(e["members"], key=lambda m: by[m]["bias2_se"])]
            cost = ", ".join(f"{m} {_ratio(by[m])}" for m in e["members"])
            entries.append(dict(e, mean=best["mean_error"], mean_se=best["mean_error_se"], cost=cost,
                                tied_smith=any(x["unbiased"] for x in tier),
                                verdict=_verdict(e["bias2"], e["se"], best["mean_error"], best["mean_error_se"])))
    for e in entries:
        e["label_key"] = _one_label(e["verdict"], not e["unbiased"] and e["tied_smith"] and
                                    abs(e["mean"]) <= z * e["mean_se"])
    return entries


def _scene_advice(rep):
    """Sentences for one sweep scene, every one from this run's numbers: per entry of the ranking (rows that
    are one model here), its one label (matches the Smith model, looks right, cannot tell, visibly off) and
    what it costs."""
    entries = _entries(rep)
    approx = [e for e in entries if not e["unbiased"]]
    lines = []
    if approx and not any(e["label_key"] == "matches" for e in approx):
        best = min(approx, key=lambda e: e["bias2"])
        lines.append(f"<b>Matches the Smith model</b>: no approximation does at this run's noise; the closest in "
                     f"bias² is <b>{best['label']}</b> (converged RMS error {_rms_bias(best['bias2'], best['se'])}, "
                     f"mean radiance {_pct(best['mean'], best['mean_se'])}); for the Smith model itself use its "
                     "unbiased estimators (heitz, invariance).")
    for key, head in LABELS:
        sel = [e for e in entries if e["label_key"] == key]
        if sel:
            lines.append(head + ": " + "; ".join(
                f"{html.escape(e['label'])} (mean radiance {_pct(e['mean'], e['mean_se'])}, "
                f"{uncertainty.sign_word(e['mean'], e['mean_se'])}; RMS {_rms_bias(e['bias2'], e['se'])}; "
                f"time per sample ÷ built-in: {e['cost']})" for e in sel) + ".")
    rms = min(rep["targets"])  # the scene's smallest target (common.SWEEP_TARGETS)
    ok = [t for t in rep["table"] if _verdict(t["bias2"], t["bias2_se"], t["mean_error"], t["mean_error_se"]) != "off"]
    measured = [(t["times"][rms][0], t) for t in ok if _finite(t["times"][rms][0]) and t["times"][rms][1] <= 1.0]
    if measured:
        tt, t = min(measured, key=lambda x: x[0])
        lines.append(f"<b>Fastest to {rms:g} % RMS error</b> (this scene's smallest target, inside the measured "
                     f"renders) among the rows not visibly off: <b>{t['label']}</b>, {_sec(tt)} here.")
    else:
        ext = [(t["times"][rms], t) for t in ok if _finite(t["times"][rms][0])]
        if ext:
            (tt, f), t = min(ext, key=lambda x: x[0][0])
            lines.append(f"<b>Fastest to {rms:g} % RMS error</b> (this scene's smallest target): no row reached it "
                         f"inside the measured renders; the fit's fastest is {t['label']}, {_time_cell((tt, f))}.")
    never = [t for t in rep["table"] if t["status"][rms]["status"] == uncertainty.NOT_REACHABLE]
    if never:
        lines.append(f"Cannot reach {rms:g} % RMS at any render time (bias floor above it beyond noise): " +
                     ", ".join(f"{t['label']} (floor {t['status'][rms]['floor_pct']:.1f} ± "
                               f"{t['status'][rms]['floor_se_pct']:.1f} %)" for t in never) + ".")
    return lines


def _finite(x):
    return x is not None and math.isfinite(x)


# The a priori cost order of the papers' models (ties of measured time go to the first: benches/README.md);
# scene_advice.CANDIDATES is the same order for the candidates of `msx compare SCENE.xml`.
COST_ORDER = ["builtin", "single", "compensated", "fastmsx", "uncorrelated", "auto", "correlated", "invariance",
              "heitz"]
DEFAULT_MODEL = "correlated"  # msx_posfree's default `model` (README, core.py)


def _row_states(rep):
    """Per row of a sweep scene's table (by label): the one label of its ranking entry (_entries: rows that
    are one model here share it) and whether it is an unbiased row."""
    return {m: dict(label=e["label_key"], unbiased=e["unbiased"]) for e in _entries(rep) for m in e["members"]}


def _choices(rep):
    """(accurate, fast) rows of a sweep scene's table, with the rules of `msx compare SCENE.xml`
    (scene_advice.choose, docs/evaluation.md): fast = the cheapest row that looks right; accurate = the
    cheapest that looks right and matches the Smith model, else the unbiased walk. Cost: render time per
    sample ÷ the built-in's; times from renders shorter than scene_advice.NOISY_RENDER tie with every other."""
    states = _row_states(rep)
    cand = [dict(t, model=t["row"][0], cost=t["time_ratio"], noisy_time=t.get("noisy_time", False))
            for t in rep["table"]]
    fast = scene_advice.choose([c for c in cand if states[c["label"]]["label"] in ("matches", "right")], COST_ORDER)
    accurate = scene_advice.choose([c for c in cand if states[c["label"]]["label"] == "matches" or c["unbiased"]],
                                   COST_ORDER)
    return accurate, fast


VERDICT_WORDS = {"matches": "<span class=ok>matches the Smith model</span>", "right": "<span class=ok>looks right</span>",
                 "off": "<span class=bad>visibly off</span>", "undecided": "<span class=warn>cannot tell at this run's noise</span>"}


def _model_cell(t):
    if t is None:
        return "<span class=warn>cannot tell at this run's noise</span>"
    name = "single (= built-in)" if t["row"][0] == "builtin" else t["label"]
    flag = " <b>(the default)</b>" if t["row"][0] == DEFAULT_MODEL else ""
    return f"<b>{html.escape(name)}</b>{flag} <span class=note>{_ratio(t)}</span>"


def _summary_table(ctx):
    """The page's first table: per material class and sweep scene, the accurate and the fast model."""
    out = ["<table><tr><th class=l>material class</th><th class=l>scene</th><th class=l>accurate model</th>"
           f"<th class=l>fast model</th><th class=l>the default, {DEFAULT_MODEL}</th></tr>"]
    for title, kind, _ in CLASSES:
        for rep in [r for r in ctx["scenes"] if r["scene"].surface == kind]:
            accurate, fast = _choices(rep)
            states = _row_states(rep)
            dflt = [t for t in rep["table"] if t["row"] == (DEFAULT_MODEL, "pt")]
            dcell = "not in this sweep"
            if dflt:
                st = states[dflt[0]["label"]]
                dcell = (VERDICT_WORDS[st["label"]]
                         + f" <span class=note>{_ratio(dflt[0])}</span>")
            out.append(f"<tr><td class=l>{html.escape(title)}</td><td class=l><a href='#{rep['scene'].name}'>"
                       f"{html.escape(rep['scene'].title)}</a></td><td class=l>{_model_cell(accurate)}</td>"
                       f"<td class=l>{_model_cell(fast)}</td><td class=l>{dcell}</td></tr>")
    if any(r["name"] == "fig08_diffuse" for r in ctx.get("side", [])):
        out.append("<tr><td class=l>Rough diffuse</td><td class=l>Wang 2022 Fig. 8 (side by side only)</td>"
                   "<td class=l colspan=3>no converged reference in this evaluation: see <i>Rough diffuse</i> "
                   "below</td></tr>")
    out.append("</table>")
    out.append(f"<p class=note><b>Accurate model</b>: the cheapest that looks right and matches the Smith model "
               "(definitions below), else the unbiased walk. <b>Fast model</b>: the cheapest that looks right; "
               "“cannot tell” when none does at this run's noise. Cheapest: render time per sample ÷ the built-in's "
               f"(×); within {scene_advice.TIME_TIE:.0%} of each other, or from renders shorter than "
               f"{scene_advice.NOISY_RENDER * 1000:.0f} ms (their ratios are noise: flagged so), the simpler model "
               f"({', '.join(COST_ORDER)}) — the rules of <code>msx compare SCENE.xml</code>. <b>(the default)</b>: "
               f"<code>{DEFAULT_MODEL}</code>, msx_posfree's default model; its own column says how it fares.</p>")
    return "\n".join(out)


CLASSES = [("Rough conductors (metals)", "conductor", ["conductor"]),
           ("Glass: reflection and transmission", "dielectric", ["dielectric_outside", "dielectric_inside"])]


def _advice(ctx):
    """The first section: per material class, which model for which goal, from this run's numbers."""
    atlas = ctx.get("atlas") or []
    out = ["<h2 id=advice>Which model should I use?</h2>",
           "<p class=note>Every sentence below is computed from this run's numbers (sections further down). "
           f"<b>Looks right</b>: the converged render differs from the Smith reference by at most {LOOK_MEAN:g} % in "
           f"mean radiance over the object (about the smallest brightness step people see between two patches "
           f"side by side, 1–2 %) and {LOOK_RMS:g} % RMS per pixel, each bound taken "
           f"{uncertainty.Z:g} standard errors on the pessimistic side. <b>Matches the Smith model</b>: looks "
           "right, and its bias² is tied with the reference's own model (the ranking rule below) with mean radiance "
           "within noise. Each model gets one label: matches the Smith model, else looks right, cannot tell at this "
           "run's noise, or visibly off. Times: render time per sample "
           "relative to Mitsuba's built-in single-scattering BSDF on the same scene and route.</p>"]
    out.append(_summary_table(ctx))
    for title, kind, surfaces in CLASSES:
        reps = [r for r in ctx["scenes"] if r["scene"].surface == kind]
        out.append(f"<h3>{title}</h3><ul>")
        for rep in reps:
            out.append(f"<li>{html.escape(rep['scene'].title)}:<ul>" +
                       "".join(f"<li>{x}</li>" for x in _scene_advice(rep)) + "</ul></li>")
        for surface in surfaces:
            lim = FAIL["furnace_error"]
            for model, what in (("single", f"loses ≤ {lim:.0%} of the energy"),
                                ("compensated", f"keeps the energy within {lim:.0%} (its lobe's shape: the scenes "
                                                "above)")):
                state, alphas = _cheap_ranges(atlas, surface, model)
                if not alphas:
                    continue
                grazing, _ = _cheap_ranges(atlas, surface, model, theta_max=90.0)
                ok_all = [a for a in alphas if grazing[a] == "ok"]
                out.append(f"<li><b>{model}</b> ({surface.replace('_', ' ')}, atlas furnace, F = 1 / η 1.5; "
                           f"“enough”: {what} at every θ_i ≤ 60°, by 3 standard errors): {_alpha_span(state, alphas)}"
                           + (f"; up to grazing incidence too at α ∈ {_alpha_list(ok_all)}" if ok_all else "")
                           + ".</li>")
        sav = _auto_saving(atlas, surfaces[0])
        if sav:
            cheaper = [a for a, r in sav if r < 0.9]
            txt = (f"costs ≤ 0.9× correlated's time per eval call at α ∈ {{{', '.join(f'{a:.2g}' for a in cheaper)}}}"
                   if cheaper else "is not ≤ 0.9× correlated's time per eval call at any α of the atlas")
            rest = [r for a, r in sav if a not in cheaper]
            span = f"; at the other α ×{min(rest):.2f}–{max(rest):.2f}" if rest else ""
            out.append(f"<li><b>auto</b> ({surfaces[0].replace('_', ' ')}, atlas, median over θ_i) {txt}{span}.</li>")
        out.append("</ul>")
    diff = next((r for r in ctx.get("side", []) if r["name"] == "fig08_diffuse"), None)
    if diff:
        out.append("<h3>Rough diffuse</h3><ul>" + "".join(f"<li>{x}</li>" for x in _diffuse_advice(diff)) + "</ul>")
    if ctx.get("micro_summary"):
        out.append("<h3>Against the physical microgeometry</h3><ul>" +
                   "".join(f"<li>{x}</li>" for x in ctx["micro_summary"]["advice"]) + "</ul>")
    else:
        out.append("<p class=note>The comparison with ray-traced microgeometry (\"matches the physical "
                   "microgeometry\") runs in the full run only.</p>")
    return "\n".join(out)


def _diffuse_advice(rep):
    """Fig. 8 has no sweep: each model's mean over the object against the Smith model (mean of heitz and
    invariance), with the standard error from the seeds."""
    by = {e["label"]: e for e in rep["energy"]}
    ref = [by[m] for m in SMITH if m in by]
    if not ref:
        return []
    import numpy as np

    rv = np.mean([np.mean(e["seeds"]) for e in ref])
    rse = math.sqrt(sum(np.var(e["seeds"], ddof=1) / len(e["seeds"]) for e in ref)) / len(ref)
    lines = []
    for e in rep["energy"]:
        if e["label"] in SMITH:
            continue
        v = float(np.mean(e["seeds"]))
        se = math.hypot(float(np.std(e["seeds"], ddof=1) / math.sqrt(len(e["seeds"]))), rse)
        rel, rel_se = 100 * (v / rv - 1), 100 * se / rv
        lines.append(f"{e['label']}: mean over the object {_pct(rel, rel_se)} against the Smith model (heitz, "
                     f"invariance), {uncertainty.sign_word(rel, rel_se)}.")
    return [f"No converged reference here (side by side only, {rep['spp']} spp): " + " ".join(lines)]


def _ranking_section(rep):
    """Models ranked by bias², with ties."""
    out = ["<table><tr><th>rank</th><th class=l>model (rows that are one model here)</th><th>bias² ± s.e.</th>"
           "<th>RMS error of the converged render</th><th class=l>why one entry</th></tr>"]
    for k, g in enumerate(rep["ranking"], 1):
        for j, e in enumerate(g):
            tie = "" if len(g) == 1 else " (tied)"
            why = html.escape(e["why"]) + (" — <span class=bad>members differ beyond noise: " +
                                           html.escape(", ".join(e["members_differ"])) + "</span>"
                                           if e["members_differ"] else "")
            out.append(f"<tr><td>{k if j == 0 else ''}{tie if j == 0 else ''}</td><td class=l>{html.escape(e['label'])}"
                       f" <span class=note>({html.escape(', '.join(e['members']))})</span></td><td>{_bias(e)}</td>"
                       f"<td>{_rms_bias(e['bias2'], e['se'])}</td><td class=l>{why}</td></tr>")
    out.append("</table>")
    out.append(f"<p>Ranking: <b>{html.escape(uncertainty.ranking_text(rep['ranking']))}</b> "
               "(“=”: tied within noise).</p>")
    return "\n".join(out)


def _scene_section(rep):
    sc = rep["scene"]
    ref = rep["ref"]
    out = [f"<h3 id='{sc.name}'>{html.escape(sc.title)}</h3>"]
    out.append(_img(rep["pngs"]["evt"], f"error against time, {sc.name}"))
    out.append(f'<p class="box">Reference: <b>{row_label(ref["row"])}</b> (Heitz\'s BSDF with the heights integrated '
               f"out; its efficiency 1/(variance × time) in this sweep is {ref['efficiency_vs_heitz']:.2f} × heitz's) "
               f"at {ref['spp']} spp, {_sec(ref['seconds'])}"
               f"{' (from the cache)' if ref['cached'] else ''}; its own noise, from two independent halves, "
               f"{_e(ref['noise'])} relative MSE = {ref['noise'] / ref['smallest']:.3f} × the smallest plotted error "
               f"({_e(ref['smallest'])}). Object pixels: {rep['mask_pixels']}.</p>")
    out.append("<h4>Closest to the Smith reference</h4>" + _ranking_section(rep))
    targets = list(rep["targets"])
    out.append("<h4>Every row</h4><table><tr><th class=l>model</th><th>RMS error at the largest spp</th>"
               "<th>mean radiance error ± s.e.</th><th class=l></th><th>bias² ± s.e.</th>"
               "<th>render time per sample ÷ built-in</th>" +
               "".join(f"<th>time to {x:g} % RMS</th>" for x in targets) +
               "<th>largest spp</th><th>slope of the variance against spp</th><th>relative MSE at the largest spp</th></tr>")
    for t in rep["table"]:
        out.append(f"<tr><td class=l>{t['label']}{' (unbiased)' if t['unbiased'] else ''}</td>"
                   f"<td>{t['top']['rel_rms_pct']:.1f} %</td><td>{_pct(t['mean_error'], t['mean_error_se'], 2)}</td>"
                   f"<td class=l>{_mean_word(t)}</td><td>{_bias(t)}</td><td>{_ratio(t)}</td>" +
                   "".join(f"<td>{_time_cell(t['times'][x], t.get('status', {}).get(x))}</td>" for x in targets) +
                   f"<td>{t.get('spp_max', '—')}</td><td>{t['slope']:.2f}</td><td>{_e(t['top']['rel_mse'])}</td></tr>")
    out.append("</table>")
    lo = min(t["seconds_range"][0] for t in rep["table"])
    hi = max(t["seconds_range"][1] for t in rep["table"])
    cap = rep.get("cap")
    out.append(f"<p class=note>Renders of this sweep took {_sec(lo)} to {_sec(hi)} each. A time ratio whose render "
               f"(the row's or the built-in's, at the top fixed spp) took less than "
               f"{scene_advice.NOISY_RENDER * 1000:.0f} ms is flagged as noise: at a few ms the launch and scheduling "
               "jitter of one render is of the size of the difference between models (single and the built-in, "
               "identical by construction, then differ by tens of %). The sweep is adaptive: "
               f"after the fixed spps {rep.get('fixed_spps', '')} a row's spp doubles "
               f"(up to {cap} spp here) while a target it has not reached is predicted within that cap. Times to a "
               "target come from the fit error(t) = bias² + c/t of each row's sweep: <b>measured</b> when the "
               "target lies inside the row's sweep (its error at its largest spp is at or below it), else "
               "<span class=warn>extrapolated ×f</span> (f = the spp the fit needs ÷ the row's largest spp); "
               "<span class=warn>not reachable</span>: the row's bias floor (√bias², ± its standard error) is above "
               "the target by more than 3 standard errors. Per row and target in "
               f'<a href="{html.escape(_rel(Path(_OUT[0] or ".") / "times.csv"))}">times.csv</a>. '
               "RMS error = √(relative MSE) at the row's largest spp; the mean radiance "
               "error is that of the seed mean at the largest spp over the object's pixels (signed: negative = too "
               "dark).</p>")
    out.append(_targets_note(rep))
    out.append(_img(rep["pngs"]["crops"], f"equal-time crops, {sc.name}"))
    out.append(_img(rep["pngs"]["models"], f"converged renders per model, {sc.name}"))
    out.append(_img(rep["pngs"]["diff"], f"difference to the built-in, {sc.name}"))
    return "\n".join(out)


def _targets_note(rep):
    """The scene's targets (common.SWEEP_TARGETS) with the reason, and per target: how many rows measured it,
    and whether the reference resolves it (its noise ≤ 1/10 of the target's relative MSE)."""
    ref = rep["ref"]
    parts = []
    for x in rep["targets"]:
        n = sum(1 for t in rep["table"] if t["status"][x]["status"] == uncertainty.MEASURED)
        ratio = ref["noise"] / (x / 100.0) ** 2
        resolved = "resolved by the reference" if ratio <= 0.1 else "<span class=warn>not resolved by the reference</span>"
        parts.append(f"{x:g} % RMS: measured for {n} of {len(rep['table'])} rows; {resolved} (its noise "
                     f"{ratio:.3f} × the target's relative MSE, limit 0.1)")
    return (f"<p class=note>This scene's targets: <b>{', '.join(f'{x:g} %' for x in rep['targets'])}</b> RMS error, "
            f"measured up to the cap of {rep.get('cap')} spp — {html.escape(rep.get('targets_why', ''))} "
            "(the targets and caps of every scene: <code>evaluation/common.py</code> <code>SWEEP_TARGETS</code>, "
            "docs/evaluation.md). " + "; ".join(parts) + ".</p>")


def _side_section(rep):
    out = [f"<h3>{html.escape(rep['title'])}</h3>", "<table><tr><th class=l>model</th><th>mean over the object</th>"
           "<th>built-in</th><th>ratio</th><th>± s.e. of the difference</th></tr>"]
    for e in rep["energy"]:
        out.append(f"<tr><td class=l>{e['label']}</td><td>{e['value']:.4f}</td><td>{e['builtin']:.4f}</td>"
                   f"<td>{e['ratio']:.3f}</td><td>{e['se']:.4f}</td></tr>")
    out.append("</table>")
    out.append(_img(rep["pngs"]["models"], f"{rep['name']} per model"))
    out.append(_img(rep["pngs"]["diff"], f"{rep['name']}: difference to the built-in"))
    return "\n".join(out)


METRIC_WORDS = {"furnace_error": "energy lost or created (furnace |1 − E|)",
                "rel_std": "noise of one call (std ÷ mean)",
                "max_weight": "largest single contribution ÷ mean (fireflies)",
                "nonfinite": "raw NaN, infinite or negative values"}


def _fail_table(fails):
    if not fails:
        return "<p>No cell crossed a threshold.</p>"
    out = ["<table><tr><th class=l>model</th><th class=l>surface</th><th class=l>fails on</th><th>threshold</th>"
           "<th>cells</th><th class=l>α range</th><th class=l>θ_i range (°)</th><th>worst</th><th class=l>at (α, θ_i)</th></tr>"]
    for f in sorted(fails, key=lambda f: (f["surface"], f["model"], f["estimator"], f["metric"])):
        label = f["model"] if f["estimator"] == "pt" else f"{f['model']} {f['estimator']}"
        out.append(f"<tr><td class=l>{label}</td><td class=l>{f['surface']}</td><td class=l>{METRIC_WORDS.get(f['metric'], f['metric'])}</td>"
                   f"<td>{f['threshold']:g}</td><td>{f['cells']}/{f['of']}</td>"
                   f"<td class=l>{f['alpha_range'][0]:.3g} – {f['alpha_range'][1]:.3g}</td>"
                   f"<td class=l>{f['theta_range'][0]:g} – {f['theta_range'][1]:g}</td><td>{f['worst']:.3g}</td>"
                   f"<td class=l>({f['worst_at'][0]:.3g}, {f['worst_at'][1]:g})</td></tr>")
    out.append("</table>")
    return "\n".join(out)


def _micro_section(ctx):
    """The two references side by side (summary, chart, orderings), then the microgeometry charts, the long
    per-configuration table folded."""
    micro, ms = ctx["micro"], ctx.get("micro_summary") or {}
    out = ["<h2 id=references>Two references: the Smith model and explicit microgeometry</h2>",
           "<p class=note>The sweeps above measure each model against the converged <b>Smith</b> multiple-scattering "
           "reference (GGX, the scenes' materials). Here every model is also measured against rays traced on "
           "generated <b>Beckmann height fields</b> (docs/microgeometry.md; lossless facets, every α and θ_i of "
           "the grid): the lobe's L1 distance ∫|f_model − f_traced| cos θ_o dω (fraction of the incident flux), "
           "averaged over the configurations. Microgeometry ranking rule: a model ranks before another when its "
           f"L1 is smaller by more than {uncertainty.Z:g} standard errors of the mean per-configuration difference "
           "(it must be closer consistently), else tied.</p>"]
    if ms.get("chart"):
        out.append(_img(ms["chart"], "each model against the two references"))
    if ms.get("rankings"):
        out.append("<table><tr><th class=l>surface</th><th class=l>against the Smith reference (bias², this page's "
                   "sweeps)</th><th class=l>against the traced surfaces (mean lobe L1)</th><th class=l>opposite "
                   "orderings</th><th class=l>Smith model's own energy error per order</th></tr>")
        for surface, (smith, mtext) in ms["rankings"].items():
            st = "<br>".join(f"{html.escape(n)}: {html.escape(t)}" for n, t in smith) or "— (no sweep scene)"
            dis = ms["disagree"].get(surface) or []
            dtext = "<br>".join(f"{html.escape(s)}: Smith {html.escape(a)} before {html.escape(b)}, traced the "
                                "other way" for s, a, b in dis) or "none"
            oe = ms["order_errors"].get(surface, {})
            otext = ", ".join(f"{lab}: {v['mean'] * 100:+.1f} % (worst {v['worst'] * 100:.0f} %, mean |z| "
                              f"{v['z']:.1f})" for lab, v in oe.items()) or "—"
            out.append(f"<tr><td class=l>{surface}</td><td class=l>{st}</td><td class=l>{html.escape(mtext)}</td>"
                       f"<td class=l>{dtext}</td><td class=l>{otext}</td></tr>")
        out.append("</table><p class=note>Why the orderings can differ: the Smith model is itself an approximation "
                   "of a height field (uncorrelated heights, the Smith shadowing); its own energy error per order "
                   "against the traced surfaces is the last column (|z| = error ÷ its standard error: above ≈ 3 the "
                   "difference is real). A model closer to Smith is not closer to the physical surface where Smith's "
                   "error is of the size of the model's. The sweeps use GGX, the traced surfaces Beckmann.</p>")
    out.append("<h3>Microgeometry: energy per order</h3>")
    for c in micro.get("energy_charts", []):
        out.append(_img(c, Path(c).stem.replace("_", " ")))
    if micro.get("surface_chart"):
        out.append(_img(micro["surface_chart"], "generated surfaces against Beckmann"))
    lobes = [c for c in micro.get("charts", []) if c and Path(c).name.startswith("lobes_")]
    if lobes:
        out.append("<p>Lobes per order, one chart per configuration: " + ", ".join(
            f"<a href='{html.escape(_rel(c))}'>{html.escape(Path(c).stem)}</a>" for c in lobes) + ".</p>")
    base = Path(micro["csv"]).parent
    out.append("<details><summary>Every configuration (long table; also "
               f"<a href='{_rel(base / 'errors.html')}'>errors.html</a>, <a href='{_rel(base / 'errors.csv')}'>"
               f"errors.csv</a>, <a href='{_rel(base / 'summary.md')}'>summary.md</a>)</summary>" + micro["html"] +
               "</details>")
    return "\n".join(out)


def _cusp_note(cusp):
    """What the narrow spike along the normal in correlated's order-3/4+ lobes is, measured by this run."""
    out, has = [], {}
    for m, vals in cusp.items():
        (_, v0, s0), (t1, v1, s1) = vals[0], vals[1]
        drop, se = v0 - v1, math.hypot(s0, s1)
        has[m] = drop > uncertainty.Z * se
        cells = ", ".join(f"{t:g} rad: {v:.4f} ± {s:.4f}" for t, v, s in vals)
        verdict = (f"falls by {drop:.4f} already at θ_o = {t1:g} rad ({drop / se:.1f} standard errors): a cusp at "
                   f"ω_o = n, not a smooth peak (which would change by about ({t1:g})² relative)"
                   if has[m] else f"changes by {drop:+.4f} ± {se:.4f} at θ_o = {t1:g} rad: no measurable cusp")
        out.append(f"<li><b>{m}</b>: θ_o = {cells} — {verdict}.</li>")
    end = ""
    if has.get("correlated") and not has.get("heitz", True):
        end = ("<p class=note>correlated has a cusp at the normal that the Smith model (heitz) does not: the spike "
               "in its lobes is a property of the height-correlated model, not noise.</p>")
    return ("<p class=note>The spike along the normal in correlated's order-3 and 4+ lobes, measured: f·cos θ_o "
            "at θ_i = 0 (GGX conductor α 0.5, F = 1, 100 000 eval calls per point) near the normal, in the plane "
            "of incidence:</p><ul class=note>" + "".join(out) + "</ul>" + end)


def page(ctx):
    _OUT[0] = ctx.get("out")
    st = ctx["settings"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>msx evaluation</title><style>{CSS}</style>"
             "</head><body>",
             f"<h1>msx evaluation{' (quick)' if st.quick else ''}: speed against accuracy</h1>",
             f'<p class="note">Route: {html.escape(ctx["route"])}. Machine: {ctx["machine"]}. Total time of this run: '
             f"{ctx['seconds']:.0f} s. Sweep: {st.size}×{st.size} pixels, spp {st.spps}, {st.seeds} seeds per spp, then "
             "adaptive (each row doubles its spp while a target is still to be measured, up to a cap per scene; "
             "each scene names the targets its cap can measure). "
             "Every number and chart on this page was computed by this run; the CSV files beside it hold them "
             "(<a href='results.csv'>results.csv</a>, <a href='times.csv'>times.csv</a>, <a href='atlas.csv'>atlas.csv</a>, "
             "<a href='energy.csv'>energy.csv</a>).</p>"]
    if st.quick:
        parts.append("<p class=note><b>--quick is a first look</b> (CI): its sweep is small (top fixed spp "
                     f"{max(st.spps)}), so most times to a target are extrapolated (marked so, with the factor) and "
                     "many comparisons cannot be told at its noise; the full run (without --quick) measures the "
                     "targets each scene names.</p>")
    parts.append(_advice(ctx))
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
                 "both noises subtracted; variance is the spread of one render over seeds.</p>"
                 "<p class=box><b>Uncertainty and ranking rule.</b> bias² carries its standard error: every pixel is "
                 "an independent Monte Carlo estimate whose variance the independent seeds measure, so the standard "
                 "error is the spread of the per-pixel contributions ÷ √(pixels) (conservative: it also counts how the "
                 "bias varies over the object). Two models are compared on the same pixels (paired). A model ranks "
                 f"below another only when its bias² is larger by more than {uncertainty.Z:g} standard errors of the "
                 "difference (two-sided false alarm ≈ 0.3 % per pair); otherwise they are <b>tied within noise</b>. "
                 "Rows that are one model at the scene's parameters are one entry: the estimators of a model (PT, "
                 "BDPT), <code>single</code> and the built-in, heitz and invariance (the reference's model), and "
                 "<code>auto</code> with <code>correlated</code> where both give identical values at the scene's "
                 "roughness.</p>")
    for rep in ctx["scenes"]:
        parts.append(_scene_section(rep))
    parts.append("<h2>Side by side</h2>")
    for rep in ctx["side"]:
        parts.append(_side_section(rep))
    parts.append("<h2>Stability atlas</h2><p class='note'>Per cell: the furnace error |1 − E| (F = 1 conductor, "
                 "η = 1.5 dielectric in importance mode, E integrated from <code>eval</code> with a proposal independent "
                 "of the core), the noise of one <code>eval</code> call at fixed directions, raw non-finite or negative "
                 "values counted by the C ABI before it cleans them (×), the largest single contribution to the "
                 "furnace estimate relative to its mean (firefly risk) and the time per call. One image per surface "
                 "(conductor; dielectric from outside; from inside), one row of panels per model, one column per "
                 "metric, each cell one (α, θ_i). <b>White dots</b>: cells beyond the threshold of the table below. "
                 "<b>White cells</b> have no colour because they have no value on the log scale: marked <b>0</b> in "
                 "the noise column, the median noise of one call is exactly 0 — at most of the fixed direction pairs "
                 "the repeated calls returned the same value (analytic models such as <code>single</code>, "
                 "<code>compensated</code> and <code>fastmsx</code> everywhere, where the panel says "
                 "“deterministic”; the walks at some cells, mostly at small α, where a path rarely scatters twice); unmarked, the "
                 "metric is not finite or not measured there (e.g. the largest contribution ÷ mean of a zero furnace estimate). "
                 "<code>single</code> and <code>fastmsx</code> do not "
                 "conserve energy by design: their furnace error is charted (Fast-MSX's signed error separately), "
                 "not counted as a failure.</p>")
    parts.append("<h3>Where each method fails</h3>" + _fail_table(ctx["fails"]))
    for p in ctx["stability"]:
        surface = Path(p).stem.removeprefix("stability_")
        parts.append(f"<h3>Atlas: {html.escape(surface.replace('_', ' '))}</h3>" + _img(p, Path(p).stem))
    parts.append(_img(ctx["extras"], "p_exit cancellation and Fast-MSX energy"))
    parts.append("<h2>Lobes</h2><p class='note'>f·cos θ_o in the plane of incidence per scattering order (analytic "
                 "models: their whole value as order 1), with the energy each model reflects (E_r) and transmits "
                 "(E_t).</p>")
    if ctx.get("cusp"):
        parts.append(_cusp_note(ctx["cusp"]))
    for p in ctx["lobes"]:
        parts.append(_img(p, Path(p).stem))
    parts.append("<h2>Energy</h2>" + _img(ctx["energy"], "directional albedo against roughness"))
    if ctx.get("micro"):
        parts.append(_micro_section(ctx))
    parts.append("</body></html>")
    return "\n".join(parts)
