"""Energy curves: directional albedo against roughness for every model, at
θ_i = 0°, 60°, 85° — the furnace at a glance. Conductor with F = 1 and with
copper (per RGB channel, Mitsuba's own IOR data), dielectric η = 1.5 (E_r,
E_t, importance mode). Integrals of `eval` with the atlas' proposal."""

from __future__ import annotations

import math

import numpy as np

from msx.plugin.parameters import models
from msx.core import CoreBsdf

from .atlas import ETA, Proposal

THETAS = [0.0, 60.0, 85.0]
# Every model of the core's table of names on each surface (src/config.rs).
MODELS = {s: models(s) for s in ("conductor", "dielectric")}


def copper_rgb(mi):
    """Mitsuba's copper (η, k) in its RGB variants' values (from a built-in roughconductor)."""
    from msx.plugin.parameters import conductor_ior

    eta, k = conductor_ior(mi, "Cu")
    si = mi.SurfaceInteraction3f()

    def rgb(tex):
        v = tex.eval(si)
        return [float(np.asarray(v[c]).reshape(-1)[0]) for c in range(3)]

    return rgb(eta), rgb(k)


def compute(st, copper, progress=None):
    """Rows (surface, material, model, theta_i, alpha, channel/side, value, se)."""
    rows = []
    rng = np.random.default_rng(8)
    cases = [("conductor", "F=1"), ("conductor", "Cu"), ("dielectric", "eta=1.5")]
    total = sum(len(MODELS[s]) for s, _ in cases) * len(st.energy_alphas)
    done = 0
    for surface, material in cases:
        for model in MODELS[surface]:
            for alpha in st.energy_alphas:
                if surface == "conductor":
                    kw = dict(channels=3, eta=copper[0], k=copper[1]) if material == "Cu" else {}
                else:
                    kw = dict(surface="dielectric", ior=ETA, radiance=False)
                b = CoreBsdf(distribution="ggx", model=model, alpha=float(alpha), seed=3, **kw)
                for theta in THETAS:
                    t = math.radians(theta)
                    wi = np.array([math.sin(t), 0.0, math.cos(t)])
                    prop = Proposal(surface, float(alpha), wi, ETA)
                    wo, p = prop.sample(st.energy_calls, rng)
                    f = b.eval(np.tile(wi, (len(wo), 1)), wo)
                    terms = f / p
                    if surface == "conductor":
                        for c in range(terms.shape[0]):
                            rows.append(dict(surface=surface, material=material, model=model, theta_i=theta,
                                             alpha=float(alpha), part="RGB"[c] if material == "Cu" else "E",
                                             value=float(terms[c].mean()),
                                             se=float(terms[c].std() / math.sqrt(terms.shape[1]))))
                    else:
                        for part, sel in (("E_r", wo[:, 2] > 0), ("E_t", wo[:, 2] < 0)):
                            x = np.where(sel, terms[0], 0.0)
                            rows.append(dict(surface=surface, material=material, model=model, theta_i=theta,
                                             alpha=float(alpha), part=part, value=float(x.mean()),
                                             se=float(x.std() / math.sqrt(len(x)))))
                done += 1
                if progress:
                    progress(done, total, "model × α")
    return rows
