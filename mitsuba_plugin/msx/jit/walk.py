"""What every random walk of the Dr.Jit engine shares: twin of ``src/walk/mod.rs``."""

import math

import drjit as dr
import mitsuba as mi

from .microfacet import max_channel


def russian_roulette_keep(throughput, u, keep, floor=0.0):
    """Russian roulette that keeps a path surely while its largest channel is ≥ ``keep`` (a Float per
    lane) and otherwise survives with probability max/keep, at least ``floor``, dividing the throughput by
    it (unbiased). ``u`` is the lane's uniform number. Returns (throughput, survived). The survival
    probability is detached: the decision is not differentiated, so neither is the division by it
    (docs/gradients.md)."""
    q = dr.detach(dr.maximum(dr.minimum(max_channel(throughput) / keep, 1.0), floor))
    survived = (q > 0.0) & ((q >= 1.0) | (u < q))
    return dr.select(survived, throughput / q, 0.0), survived


def roulette_from(play, throughput, u, keep=1.0, floor=0.0):
    """A walk's roulette at a vertex: ``russian_roulette_keep`` on the lanes where ``play`` (the vertex is at
    or past the walk's first roulette vertex), the throughput as it is elsewhere. Returns (throughput,
    alive); ``alive`` is False where the path ended."""
    kept, survived = russian_roulette_keep(throughput, u, keep, floor)
    return dr.select(play, kept, throughput), ~play | survived


def cosine_about(n, u1, u2):
    """Cosine-distributed direction about the unit vector n (density ⟨ω, n⟩⁺/π), in the orthonormal basis
    of Duff et al. 2017 as ``cosine_about`` builds it."""
    sign = dr.select(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = mi.Vector3f(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    bt = mi.Vector3f(b, sign + n[1] * n[1] * a, -n[1])
    r = dr.sqrt(u1)
    sp, cp = dr.sincos(2.0 * math.pi * u2)
    z = dr.sqrt(dr.maximum(1.0 - u1, 0.0))
    return dr.normalize(t * (r * cp) + bt * (r * sp) + n * z)
