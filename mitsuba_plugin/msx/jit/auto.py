"""``model="auto"`` in the Dr.Jit engine: twin of ``src/models/auto/``.

The position-free ``correlated`` model whose bounce cap is 1 (its analytic order 1, no walk) wherever the
core's rule finds order 1 alone within ``auto_tolerance`` of the scattered energy for the call's
max(α_u, α_v), |cos θ_i| and the relative IOR seen from ω_i, and the full model elsewhere. The rule is
the core's own: ``msx_auto_rule`` hands over the α threshold of each μ cell; a lane compares its α with
the threshold of its cell (μ below the grid, and a conductor's ω_i below the surface, run the full model).

On a conductor an order-1 lane computes order 1 in closed form (``order_one_*`` below; jit/bsdf.py
``ConductorModel``), with the visible-normal reflection density as its ``pdf`` and sampler: in ``eval`` and
``pdf`` the walk runs behind a symbolic ``dr.if_stmt``, which the LLVM backend skips in a packet none of whose
lanes walk; ``sample`` runs the walk sampler capped at one vertex on those lanes (benches/README.md, "``auto``
at single's price"). Dielectric and diffuse microsurfaces run the capped walk.
"""

import drjit as dr
import mitsuba as mi

from .microfacet import BECKMANN, dot, half_vector


class OrderOneRule:
    """The thresholds of one surface, distribution, tolerance and relative IOR."""

    def __init__(self, surface, distribution, tolerance, eta=1.0):
        from .._native import ffi, lib

        surfaces = {"conductor": lib.MSX_SURFACE_CONDUCTOR, "dielectric": lib.MSX_SURFACE_DIELECTRIC,
                    "diffuse": lib.MSX_SURFACE_DIFFUSE}
        dist = lib.MSX_DISTRIBUTION_BECKMANN if distribution == BECKMANN else lib.MSX_DISTRIBUTION_GGX
        axis = ffi.new("MsxAxis *")
        values = ffi.new("double[64]")
        err = ffi.new("char[]", 512)
        rc = lib.msx_auto_rule(surfaces[surface], dist, tolerance, eta, axis, values, 64, err, 512)
        if rc != lib.MSX_OK:
            raise RuntimeError("msx_auto_rule: " + ffi.string(err).decode(errors="replace"))
        self.lo, self.hi, self.n = axis.lo, axis.hi, axis.n
        self.thresholds = [values[i] for i in range(axis.n - 1)]

    def order_one_suffices(self, alpha, mu):
        """Per lane: whether order 1 alone omits at most the tolerance (``OrderOneRule::order_one_suffices``)."""
        mu = dr.minimum(mu, 1.0)
        x = (mu * mu - self.lo) * ((self.n - 1) / (self.hi - self.lo))
        cell = dr.minimum(mi.UInt32(dr.maximum(x, 0.0)), self.n - 2)
        threshold = dr.gather(mi.Float, mi.Float(self.thresholds), cell)
        return (mu * mu >= self.lo) & (alpha <= threshold)


# benches/scene_bench.py's count of auto's calls: [calls, calls that walk], while counting (``count_calls``).
_COUNTER = [None]


def count_calls(stop=False):
    """Starts counting ``auto``'s calls in the kernels traced from now on (returns the counter: calls, calls
    that walk), or stops (``stop``). For measurement: a counting kernel is a kernel of its own."""
    _COUNTER[0] = None if stop else dr.zeros(mi.UInt32, 2)
    if not stop:
        dr.make_opaque(_COUNTER[0])
    return _COUNTER[0]


def walked_fraction(counter):
    """The fraction of the counted calls that walked (NaN if none was counted)."""
    calls, walks = (int(v) for v in counter.numpy())
    return walks / calls if calls else float("nan")


def order_one(rule, mf, mu, full=True):
    """Per lane: whether the call is reduced to order 1 (the rule, where ``full`` allows it), counted while
    ``count_calls`` counts."""
    one = rule.order_one_suffices(dr.maximum(mf.alpha_u, mf.alpha_v), mu) & full
    counter = _COUNTER[0]
    if counter is not None:
        # One per lane: a literal value and index would make a scatter of width 1 outside a loop.
        dr.scatter_reduce(dr.ReduceOp.Add, counter, dr.full(mi.UInt32, 1, dr.width(one)), mi.UInt32(0))
        dr.scatter_reduce(dr.ReduceOp.Add, counter, mi.UInt32(1), mi.UInt32(1), active=~one)
    return one


def cap(rule, mf, mu, max_bounces, full=True):
    """The bounce cap of each lane: 1 where order 1 suffices (and ``full`` allows the rule), else
    ``max_bounces``."""
    return dr.select(order_one(rule, mf, mu, full), mi.UInt32(1), mi.UInt32(max_bounces))


# ------------------------------------------------------------------ a conductor's order 1 in closed form
# (twin of ``order_one_eval``, ``order_one_pdf``, ``order_one_sample`` in src/models/auto/mod.rs)


def _order_one_terms(mf, wi, wo):
    """What order 1's value and density share: (w·h, D(h), L_0 = 1 + Λ(ω_i), valid) with h the half vector."""
    h, length = half_vector(wi, wo)
    cos_wh = dot(wi, h)
    ok = (length > 0.0) & (cos_wh > 0.0) & (dot(wo, h) > 0.0) & (wi[2] > 0.0) & (wo[2] > 0.0)
    return cos_wh, mf.d(h), mf.abs_lambda(-wi), ok


def order_one_eval(mf, fresnel, wi, wo):
    """Order 1 of ``correlated``: F(ω_i·h)·D(h)/(4 cos θ_i (L_0 + Λ_o)), L_0 = 1 + Λ(ω_i) — the walk's next
    event at its first vertex (``posfree.nee_term`` with the last factor 1/(L_0 + Λ_o)), which is
    deterministic, in the same arithmetic."""
    cos_wh, d, l0, ok = _order_one_terms(mf, wi, wo)
    last = 1.0 / (l0 + mf.lambda_(wo))
    return dr.select(ok, fresnel.eval(cos_wh) * (d * last / (4.0 * dr.abs(wi[2]))), 0.0)


def order_one_pdf(mf, wi, wo):
    """The density of order 1's sample (``order_one_finish``): the visible-normal reflection density
    D_ωi(h)/(4 ω_i·h) = D(h)/(4 cos θ_i L_0) (``Microfacet.reflect_pdf`` with A(ω_i) = cos θ_i·L_0, sharing
    D and L_0 with ``order_one_eval``)."""
    _, d, l0, ok = _order_one_terms(mf, wi, wo)
    return dr.select(ok, d / (4.0 * wi[2] * l0), 0.0)


def order_one_finish(mf, wi, wo, fresnel_weight):
    """Order 1's sample (twin of ``order_one_sample`` in src/models/auto/mod.rs) from the walk sampler capped
    at one vertex: its ω_o, the reflection of ω_i about the visible normal drawn with (u1, u2), and its weight
    F(ω_i·m), times the exit probability L_0/(L_0 + Λ_o) in place of the walk's random exit (weight = eval/pdf),
    with ``order_one_pdf``, the density of that draw. Returns (ω_o, pdf, weight, valid)."""
    pdf = order_one_pdf(mf, wi, wo)
    l0 = mf.abs_lambda(-wi)
    weight = fresnel_weight * (l0 / (l0 + mf.lambda_(wo)))
    valid = (pdf > 0.0) & dr.isfinite(pdf) & dr.all(dr.isfinite(wo))
    return wo, pdf, dr.select(valid, weight, 0.0), valid
