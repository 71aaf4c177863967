"""Stability atlas: where each model breaks, over roughness α × incidence θ_i.

Per cell (model, surface, α, θ_i), through the core's batched C ABI:

- furnace error |1 − E|: E = ∫ f·cos θ_o dω_o estimated with N directions from
  a proposal whose density is known exactly and owes nothing to the core
  (uniform on the sphere plus Walter 2007's sampling of the GGX normal
  distribution for reflection and refraction, written here with NumPy) — it
  measures `eval`, not the sampler.
  Conductor with F = 1 and dielectric η = 1.5 conserve energy, so E = 1 is
  the truth for every energy-conserving model; `single` loses energy by
  design, Fast-MSX gains and loses (its signed error is charted too);
- noise per call: relative standard deviation of repeated `eval` calls at fixed
  (ω_i, ω_o) (median over a few ω_o drawn from the proposal);
- raw non-finite and negative values: what the C ABI had to clean during the
  cell's calls (counted before sanitising; see docs/conventions.md);
- largest contribution: max over the N furnace terms of (f/p) / E — the
  firefly risk of the estimator;
- nanoseconds per `eval` call.
"""

from __future__ import annotations

import math
import time

import numpy as np

import msx
from msx.core import CoreBsdf, pexit_study

from .common import model_rows

# Every model × estimator of the evaluation (common.model_rows: the core's table of names).
CONDUCTOR_MODELS = model_rows("conductor")
DIELECTRIC_MODELS = model_rows("dielectric")
SURFACES = {"conductor": CONDUCTOR_MODELS, "dielectric_outside": DIELECTRIC_MODELS,
            "dielectric_inside": DIELECTRIC_MODELS}
ETA = 1.5

# "Where each method fails": thresholds of the generated table.
FAIL = {
    "furnace_error": 0.05,   # more than 5 % of the energy missing or created (beyond 3 standard errors)
    "rel_std": 2.0,          # one call's noise twice its mean
    "max_weight": 200.0,     # one call carries more than 200 × the mean: fireflies
    "nonfinite": 0,          # any raw NaN/Inf/negative value
}


def _direction(theta, inside):
    d = np.array([math.sin(theta), 0.0, math.cos(theta)])
    return -d if inside else d


def _uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _ggx_d(alpha, cos_h):
    """Isotropic GGX normal distribution D(h) of cos θ_h (written here, independent of the core)."""
    c2 = cos_h * cos_h
    return np.where(cos_h > 0, alpha * alpha / (np.pi * (c2 * (alpha * alpha - 1.0) + 1.0) ** 2), 0.0)


class Proposal:
    """A density known exactly and independent of the core's samplers (Walter 2007's sampling of the GGX
    normal distribution D(h)·cos θ_h, written with NumPy): 20 % uniform on the sphere, the rest reflection
    about h — half reflection, half refraction for a dielectric. A draw that cannot refract (total internal
    reflection, a back-facing h) is a draw of nothing: it counts with value 0, so the mixture stays exact."""

    def __init__(self, surface, alpha, wi, eta=None):
        self.alpha = float(alpha)
        self.flip = wi[2] < 0  # work on ω_i's side: the inside is the flipped microsurface
        self.wi = -np.asarray(wi, dtype=np.float64) if self.flip else np.asarray(wi, dtype=np.float64)
        self.eta = (1.0 / eta if self.flip else eta) if surface == "dielectric" else None
        self.weights = (0.2, 0.4, 0.4) if self.eta is not None else (0.2, 0.8, 0.0)

    def sample(self, n, rng):
        counts = rng.multinomial(n, self.weights)
        parts = [_uniform_sphere(rng.random(counts[0]), rng.random(counts[0]))]
        for kind, k in (("r", counts[1]), ("t", counts[2])):
            if k == 0:
                continue
            u, v = rng.random(k), rng.random(k)
            tan2 = self.alpha ** 2 * u / np.maximum(1.0 - u, 1e-300)
            cos_t = 1.0 / np.sqrt(1.0 + tan2)
            sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
            phi = 2.0 * np.pi * v
            h = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)
            c = h @ self.wi
            if kind == "r":
                wo = 2.0 * c[:, None] * h - self.wi
            else:
                e = self.eta
                s2 = (1.0 - c * c) / (e * e)
                ok = (c > 0) & (s2 < 1.0)
                wo = h * (c / e - np.sqrt(np.maximum(0.0, 1.0 - s2)))[:, None] - self.wi / e
                wo[~ok] = np.nan  # a draw of nothing
            parts.append(wo)
        wo = np.concatenate(parts)
        valid = np.all(np.isfinite(wo), axis=1)
        wo[~valid] = (0.0, 0.0, 1.0)
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        p = self.pdf_local(wo)
        p[~valid] = np.inf  # contributes f/p = 0
        return (-wo if self.flip else wo), p

    def pdf_local(self, wo):
        p = np.full(len(wo), self.weights[0] / (4.0 * np.pi))
        # Reflection: h = normalize(ω_i + ω_o) (oriented up), density D(h) cos θ_h / (4 |ω_o·h|).
        h = wo + self.wi
        ln = np.linalg.norm(h, axis=1)
        ok = ln > 1e-12
        h = h / np.where(ok, ln, 1.0)[:, None]
        h = np.where(h[:, 2:3] < 0, -h, h)
        co = np.abs(np.sum(wo * h, axis=1))
        p += np.where(ok & (co > 0), self.weights[1] * _ggx_d(self.alpha, h[:, 2]) * h[:, 2] / (4.0 * np.maximum(co, 1e-300)), 0.0)
        if self.eta is not None:
            e = self.eta
            h = -(self.wi[None, :] + e * wo)
            ln = np.linalg.norm(h, axis=1)
            ok = ln > 1e-12
            h = h / np.where(ok, ln, 1.0)[:, None]
            h = np.where(h[:, 2:3] < 0, -h, h)
            ci, co = h @ self.wi, np.sum(wo * h, axis=1)
            ok &= (ci > 0) & (co < 0)
            den = (ci + e * co) ** 2
            p += np.where(ok, self.weights[2] * _ggx_d(self.alpha, h[:, 2]) * h[:, 2] * e * e * np.abs(co) /
                          np.maximum(den, 1e-300), 0.0)
        return p

    def pdf(self, wo):
        return self.pdf_local(-wo if self.flip else wo)


def cell(bsdf: CoreBsdf, proposal: Proposal, wi, calls, repeat, rng):
    """The atlas metrics of one configuration at one incident direction."""
    before = msx.diagnostics()
    wo, p = proposal.sample(calls, rng)
    wis = np.tile(wi, (len(wo), 1))
    t0 = time.perf_counter()
    f = bsdf.eval(wis, wo)[0]
    ns = (time.perf_counter() - t0) / len(wo) * 1e9
    terms = f / p
    e = float(terms.mean())
    se = float(terms.std() / math.sqrt(len(terms)))
    max_w = float(terms.max() / e) if e > 0 else float("nan")
    # Noise per call at a few fixed pairs where the BSDF is not zero.
    k, m = repeat
    stds = []
    candidates = wo[np.argsort(-terms)[: max(1, len(wo) // 4)]]  # from the quarter that carries the energy
    for j in range(min(k, len(candidates))):
        o = candidates[rng.integers(len(candidates))]
        vals = bsdf.eval(np.tile(wi, (m, 1)), np.tile(o, (m, 1)))[0]
        if vals.mean() > 0:
            stds.append(vals.std() / vals.mean())
    after = msx.diagnostics()
    raw = (after["nonfinite"] - before["nonfinite"]) + (after["negative"] - before["negative"])
    return dict(energy=e, furnace_error=abs(1.0 - e), furnace_se=se, rel_std=float(np.median(stds)) if stds else 0.0,
                nonfinite=int(raw), max_weight=max_w, ns_per_call=ns)


def compute(st, progress=None, distribution="ggx"):
    """Rows of atlas.csv (model, surface, alpha, theta_i, furnace_error, rel_std, nonfinite, max_weight,
    ns_per_call, energy, estimator)."""
    rows = []
    total = sum(len(m) for m in SURFACES.values()) * len(st.atlas_alphas)
    done = 0
    rng = np.random.default_rng(2026)
    for surface, models in SURFACES.items():
        inside = surface == "dielectric_inside"
        kind = "conductor" if surface == "conductor" else "dielectric"
        for alpha in st.atlas_alphas:
            for model, est in models:
                # Importance mode: the unscaled BSDF, whose furnace integral is 1 (radiance mode carries
                # Mitsuba's 1/η² on transmission, which moves energy between the sides by design).
                kw = dict(surface="dielectric", ior=ETA, radiance=False) if kind == "dielectric" else {}
                b = CoreBsdf(distribution=distribution, model=model, estimator=est, alpha=alpha, seed=11, **kw)
                for theta_deg in st.atlas_thetas:
                    wi = _direction(math.radians(theta_deg), inside)
                    proposal = Proposal(kind, alpha, wi, ETA)
                    r = cell(b, proposal, wi, st.atlas_calls, st.atlas_repeat, rng)
                    rows.append(dict(model=model, estimator=est, surface=surface, alpha=float(alpha),
                                     theta_i=float(theta_deg), **r))
                done += 1
                if progress:
                    progress(done, total, "model × α columns")
    return rows


def pexit_map(st, vertices=6, paths=400):
    """Bitterli & d'Eon's p_exit: median relative error against the stable form, per α × θ_i, GGX and Beckmann."""
    out = {}
    for dist in ("ggx", "beckmann"):
        grid = np.zeros((len(st.atlas_alphas), len(st.atlas_thetas)))
        nonfinite = np.zeros_like(grid)
        for i, a in enumerate(st.atlas_alphas):
            for j, t in enumerate(st.atlas_thetas):
                med, _, nf = pexit_study(dist, a, math.radians(min(t, 89.0)), vertices, paths, seed=i * 100 + j)
                grid[i, j], nonfinite[i, j] = med, nf
        out[dist] = (grid, nonfinite)
    return out


def is_failing(c, metric, thresholds=FAIL):
    """Whether cell c crosses the threshold of `metric` (the rule of the table "where each method fails").
    single and fastmsx do not conserve energy by design: their furnace error is charted, not failed."""
    if metric not in thresholds:
        return False
    thr = thresholds[metric]
    if metric == "furnace_error":  # beyond the threshold by more than 3 standard errors of the estimate
        return c["model"] not in ("single", "fastmsx") and c[metric] - 3.0 * c["furnace_se"] > thr
    if metric == "nonfinite":
        return c[metric] > 0
    return not (c[metric] <= thr)


def failures(rows, thresholds=FAIL):
    """The generated table "where each method fails": per model and surface, each failing metric with the
    region of (α, θ_i) cells where it fails."""
    out = []
    by = {}
    for r in rows:
        by.setdefault((r["model"], r["estimator"], r["surface"]), []).append(r)
    for (model, est, surface), cells in by.items():
        for metric, thr in thresholds.items():
            bad = [c for c in cells if is_failing(c, metric, thresholds)]
            if not bad:
                continue
            alphas = sorted({c["alpha"] for c in bad})
            thetas = sorted({c["theta_i"] for c in bad})
            worst = max(bad, key=lambda c: c[metric] if math.isfinite(c[metric]) else float("inf"))
            out.append(dict(model=model, estimator=est, surface=surface, metric=metric, threshold=thr,
                            cells=len(bad), of=len(cells), alpha_range=(alphas[0], alphas[-1]),
                            theta_range=(thetas[0], thetas[-1]), worst=worst[metric],
                            worst_at=(worst["alpha"], worst["theta_i"])))
    return out
