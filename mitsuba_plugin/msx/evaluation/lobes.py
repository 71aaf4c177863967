"""Lobes (Wang 2022 Fig. 6): f·cos θ_o in the plane of incidence, per
scattering order 1, 2, 3, 4+ and in total, for every model, with the energy
each model reflects (E_r) and transmits (E_t).

The orders come from the core's per-order evaluation (`msx_eval_orders_batch`);
each point is the mean of repeated calls. E_r and E_t are furnace integrals
of `eval` with the atlas' proposal (see atlas.py), split by the side of ω_o.
"""

from __future__ import annotations

import math

import numpy as np

from msx.plugin.parameters import models
from msx.core import CoreBsdf

from .atlas import ETA, Proposal

ORDERS = [("1", (1, 1)), ("2", (2, 2)), ("3", (3, 3)), ("4+", (4, 1 << 30))]
THETAS_I = [0.0, 0.5, 1.0, 1.5]
# Every model of the core's table of names on each surface, but those that shortcut another's walk (auto:
# its lobes are correlated's).
MODELS = {s: models(s, shortcut=False) for s in ("conductor", "dielectric", "diffuse")}
# Closed forms have no decomposition into orders: their whole value is shown as order 1.
ANALYTIC = set(models(random_walk=False))


def _bsdf(surface, model, alpha):
    kw = {"conductor": {}, "dielectric": dict(surface="dielectric", ior=ETA, radiance=False),
          "diffuse": dict(surface="diffuse", reflectance=1.0)}[surface]
    return CoreBsdf(distribution="ggx", model=model, alpha=alpha, seed=5, **kw)


def plane_directions(surface, points):
    """θ_o signed in the plane of incidence (x-z plane; θ_o < 0 on the side opposite to ω_i), and the
    directions; for a dielectric also the lower hemisphere (transmission), as θ_o + π."""
    t = np.linspace(-math.pi / 2 * 0.995, math.pi / 2 * 0.995, points)
    dirs = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], axis=1)
    if surface != "dielectric":
        return t, dirs
    tt = t + math.pi
    return np.concatenate([t, tt]), np.concatenate([dirs, np.stack([np.sin(tt), np.zeros_like(tt), np.cos(tt)], 1)])


def compute(st, progress=None):
    """{(surface, alpha, theta_i): {"theta_o": array, model: {order: values, "total": values, "E_r", "E_t"}}}."""
    out = {}
    rng = np.random.default_rng(6)
    cases = [(s, a, t) for s in MODELS for a in st.lobe_alphas for t in THETAS_I]
    for i, (surface, alpha, theta_i) in enumerate(cases):
        theta_o, wo = plane_directions(surface, st.lobe_points)
        # ω_i in the plane, on the side of negative x (so the specular lobe lies at θ_o > 0).
        wi = np.array([-math.sin(theta_i), 0.0, math.cos(theta_i)])
        n = len(wo)
        m = st.lobe_calls
        wis = np.tile(wi, (n * m, 1))
        wos = np.repeat(wo, m, axis=0)
        case = {"theta_o": theta_o}
        proposal = Proposal("dielectric" if surface == "dielectric" else "conductor", alpha, wi, ETA)
        for model in MODELS[surface]:
            b = _bsdf(surface, model, alpha)
            res = {}
            if model in ANALYTIC:
                v = b.eval(np.tile(wi, (n, 1)), wo)[0]
                res["1"] = v
                for name, _ in ORDERS[1:]:
                    res[name] = np.zeros(n)
            else:
                for name, orders in ORDERS:
                    res[name] = b.eval(wis, wos, orders=orders)[0].reshape(n, m).mean(axis=1)
            res["total"] = sum(res[name] for name, _ in ORDERS)
            # Energy reflected and transmitted.
            pw, p = proposal.sample(max(4 * m, 4000), rng)
            terms = b.eval(np.tile(wi, (len(pw), 1)), pw)[0] / p
            res["E_r"] = float(np.mean(np.where(pw[:, 2] > 0, terms, 0.0)))
            res["E_t"] = float(np.mean(np.where(pw[:, 2] < 0, terms, 0.0)))
            case[model] = res
        out[(surface, float(alpha), theta_i)] = case
        if progress:
            progress(i + 1, len(cases), "lobe cases")
    return out


CUSP_THETAS = (0.0, 1e-3, 1e-2, 0.02, 0.05)  # θ_o in radians, in the plane of incidence


def normal_cusp(calls=100_000, alpha=0.5, model="correlated"):
    """f·cos θ_o of `model` (GGX conductor, F = 1) at θ_i = 0 for θ_o near the normal: [(θ_o, mean, se)].
    The height-correlated model's higher orders peak in a narrow cusp at ω_o = n, which shows in the lobe
    charts as a spike along the normal; these values measure it."""
    b = CoreBsdf(distribution="ggx", model=model, alpha=alpha, seed=21)
    wi = np.array([0.0, 0.0, 1.0])
    out = []
    for t in CUSP_THETAS:
        wo = np.array([math.sin(t), 0.0, math.cos(t)])
        v = b.eval(np.tile(wi, (calls, 1)), np.tile(wo, (calls, 1)))[0] * math.cos(t)
        out.append((t, float(v.mean()), float(v.std(ddof=1) / math.sqrt(calls))))
    return out
