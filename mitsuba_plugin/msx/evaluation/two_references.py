"""One story across the two references: each model against the converged Smith reference (the sweep scenes)
and against rays traced on explicit microgeometry (msx/microgeometry/), with the orderings side by side and
the Smith model's own error against the traced surfaces, per scattering order.

Pure Python on the numbers of the run (no rendering)."""

from __future__ import annotations

import html
import math

import numpy as np

from ..plugin.parameters import models
from . import uncertainty

ORDERS = ("1", "2", "3", "4+")
# Sweep scene standing for each microgeometry surface.
SURFACE_SCENES = {"conductor": ["fig09_copper_sphere"], "dielectric": ["fig01_dielectric_slab", "fig01_dielectric_sphere"]}
# The models that estimate the Smith BSDF itself (the table's exact models: heitz, invariance).
SMITH = tuple(models(exact=True))


def micro_ranking(rows, surface):
    """Models ranked by their mean lobe L1 against the traced surfaces over the configurations, tied unless a
    difference exceeds Z standard errors of the mean per-configuration difference (paired on the
    configurations: a model must be closer consistently, not on one configuration)."""
    sel = [r for r in rows if r["surface"] == surface]
    models = []
    for r in sel:
        if r["model"] not in models:
            models.append(r["model"])
    entries = []
    for m in models:
        ms = sorted((r for r in sel if r["model"] == m), key=lambda r: (str(r["alpha"]), r["theta_i"]))
        t = np.array([r["L1"] for r in ms])
        mean, se = uncertainty.mean_se(t)
        entries.append(dict(label=m, bias2=mean, se=se if math.isfinite(se) else 0.0, terms=t,
                            unbiased=m in SMITH, noise=float(np.mean([r["L1_noise"] for r in ms]))))
    # heitz and invariance are one model (the Smith model): one entry, the one with the smaller spread.
    smith = [e for e in entries if e["unbiased"]]
    if len(smith) > 1:
        keep = min(smith, key=lambda e: e["se"])
        entries = [e for e in entries if not e["unbiased"]] + [dict(keep, label="Smith model (heitz, invariance)")]
    return uncertainty.rank(entries)


def smith_order_errors(rows, surface):
    """The Smith model's (heitz's) relative energy error per order against the traced surfaces: mean and
    largest |error| over configurations where the order carries > 0.1 % of the flux, and the mean z (error ÷
    its standard error)."""
    out = {}
    sel = [r for r in rows if r["surface"] == surface and r["model"] == "heitz"]
    for lab in ORDERS:
        v = [(r[f"rel{lab}"], r[f"rel{lab}_se"]) for r in sel
             if math.isfinite(r[f"rel{lab}"]) and r[f"E{lab}_sim"] > 1e-3]
        if v:
            out[lab] = dict(mean=float(np.mean([x for x, _ in v])), worst=float(max(abs(x) for x, _ in v)),
                            z=float(np.mean([abs(x) / s for x, s in v if s > 0])) if any(s > 0 for _, s in v)
                            else float("nan"), n=len(v))
    return out


def _order(groups):
    """Model names in ranking order, with their tier index."""
    return {m.strip(): k for k, g in enumerate(groups) for e in g for m in e["label"].split(" = ")}


def summary(scene_reports, micro_rows):
    """{'rankings': {surface: (smith_text, micro_text)}, 'disagree': {surface: [(a, b)]}, 'order_errors',
    'chart_data': (smith, micro), 'advice': [sentences]}."""
    res = dict(rankings={}, disagree={}, order_errors={}, advice=[])
    smith_chart, micro_chart = {}, {}
    for rep in scene_reports:
        z = uncertainty.Z
        smith_chart[rep["scene"].name] = [
            (e["label"], 100 * math.sqrt(max(e["bias2"], 0.0)), 100 * math.sqrt(max(e["bias2"] - z * e["se"], 0.0)),
             100 * math.sqrt(max(e["bias2"], 0.0) + z * e["se"]))
            for g in rep["ranking"] for e in g]
    for surface in ("conductor", "dielectric", "diffuse"):
        groups = micro_ranking(micro_rows, surface)
        if not groups:
            continue
        z = uncertainty.Z
        micro_chart[surface] = [(e["label"], e["bias2"], max(e["bias2"] - z * e["se"], 0.0), e["bias2"] + z * e["se"])
                                for g in groups for e in g]
        micro_text = uncertainty.ranking_text(groups)
        values = "; ".join(f"{e['label']} {e['bias2']:.4f} ± {e['se']:.4f}" for g in groups for e in g)
        res["order_errors"][surface] = smith_order_errors(micro_rows, surface)
        reps = [r for r in scene_reports if r["scene"].name in SURFACE_SCENES.get(surface, [])]
        smith_texts = [(r["scene"].name, uncertainty.ranking_text(r["ranking"])) for r in reps]
        res["rankings"][surface] = (smith_texts, f"{micro_text} (mean L1 ± s.e.: {values})")
        # Pairs of approximations that the two references order oppositely (both orderings significant).
        mo = _order(groups)
        pairs = []
        for r in reps:
            so = _order(r["ranking"])
            common = [m for m in mo if m in so and not m.startswith("Smith") and m not in SMITH]
            for i, a in enumerate(common):
                for b in common[i + 1:]:
                    if (so[a] - so[b]) * (mo[a] - mo[b]) < 0:
                        pairs.append((r["scene"].name, a, b) if so[a] < so[b] else (r["scene"].name, b, a))
        res["disagree"][surface] = pairs
        best = [e["label"] for e in groups[0]]
        oe = res["order_errors"][surface]
        err = ", ".join(f"order {lab} {v['mean'] * 100:+.1f} % (worst {v['worst'] * 100:.0f} %)" for lab, v in oe.items())
        res["advice"].append(f"<b>{surface}</b>: closest to the traced surfaces (mean lobe L1, tied within noise): "
                             f"<b>{html.escape(', '.join(best))}</b>; ordering {html.escape(micro_text)}. The Smith "
                             f"model itself against the traced surfaces, energy per order: {err or '—'}.")
        for scene, a, b in pairs:
            res["advice"].append(f"{surface}: the Smith reference ({scene}) puts <b>{html.escape(a)}</b> before "
                                 f"<b>{html.escape(b)}</b>, the traced surfaces the other way round.")
    res["chart_data"] = (smith_chart, micro_chart)
    return res
