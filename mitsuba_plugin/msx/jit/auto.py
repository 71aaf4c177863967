"""``model="auto"`` in the Dr.Jit engine: twin of ``src/models/auto/``.

The position-free ``correlated`` model whose bounce cap is 1 (its analytic order 1, no walk) wherever the
core's rule finds order 1 alone within ``auto_tolerance`` of the scattered energy for the call's
max(α_u, α_v), |cos θ_i| and the relative IOR seen from ω_i, and the full model elsewhere. The rule is
the core's own: ``msx_auto_rule`` hands over the α threshold of each μ cell; a lane compares its α with
the threshold of its cell (μ below the grid, and a conductor's ω_i below the surface, run the full model).
"""

import drjit as dr
import mitsuba as mi

from .microfacet import BECKMANN


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


def cap(rule, mf, mu, max_bounces, full=True):
    """The bounce cap of each lane: 1 where order 1 suffices (and ``full`` allows the rule), else
    ``max_bounces``."""
    one = rule.order_one_suffices(dr.maximum(mf.alpha_u, mf.alpha_v), mu) & full
    counter = _COUNTER[0]
    if counter is not None:
        dr.scatter_reduce(dr.ReduceOp.Add, counter, mi.UInt32(1), mi.UInt32(0))
        dr.scatter_reduce(dr.ReduceOp.Add, counter, mi.UInt32(1), mi.UInt32(1), active=~one)
    return dr.select(one, mi.UInt32(1), mi.UInt32(max_bounces))
