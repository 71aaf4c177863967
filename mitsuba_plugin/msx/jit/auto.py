"""``model="auto"`` in the Dr.Jit engine: twin of ``src/models/auto/``.

The position-free ``correlated`` model whose bounce cap is 1 (its analytic order 1, no walk) wherever the
core's rule finds order 1 alone within ``auto_tolerance`` of the scattered energy for the call's
max(α_u, α_v), |cos θ_i| and the relative IOR seen from ω_i, and the full model elsewhere. The rule is
the core's own: ``msx_auto_rule`` hands over the α threshold of each μ cell; a lane compares its α with
the threshold of its cell (μ below the grid, and a conductor's ω_i below the surface, run the full model).

On a conductor an order-1 lane computes order 1 in closed form (``order_one_*`` below; jit/bsdf.py
``ConductorModel``), with the visible-normal reflection density as its ``pdf`` and sampler: in ``eval`` and
``pdf`` the walk runs behind a symbolic ``dr.if_stmt`` (``eval_pdf``), which the LLVM backend skips in a packet
none of whose lanes walk; ``sample`` draws the walk's first vertex on every lane and takes the walk up from
there behind such a branch (``sample``; benches/README.md, "``auto`` at single's price").

On a dielectric, from either side (``SidedRule``), an order-1 lane does the same with
jit/posfree_dielectric.py ``order_one_*`` (jit/bsdf.py ``DielectricModel``): ``eval`` the walk's first next
event, ``pdf`` and ``sample`` the density of the walk's first vertex (the visible normal, then reflection or
refraction by the Fresnel choice) and its direction with the weight eval/pdf; ``eval``/``pdf`` behind a
per-packet ``dr.if_stmt``, and ``sample`` drawing the walk's first vertex once on every lane and finishing order 1
or taking the walk up at its exit decision behind one (benches/README.md, "``auto`` on glass at single's
price"). The diffuse microsurface runs the capped walk.
"""

import drjit as dr
import mitsuba as mi

from . import walk
from .microfacet import BECKMANN, dot, half_vector
from .posfree import CORRELATED, sample_vertex
from .rng import Stream, clean_uniform


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


class SidedRule:
    """A dielectric's two rules, one per side of ω_i (the relative IOR seen from it: η outside, 1/η inside),
    read as one: ``order_one_suffices(α, cos θ_i)`` takes the signed cosine."""

    def __init__(self, distribution, tolerance, eta):
        self.outside = OrderOneRule("dielectric", distribution, tolerance, eta)
        self.inside = OrderOneRule("dielectric", distribution, tolerance, 1.0 / eta)

    def order_one_suffices(self, alpha, cos_i):
        return dr.select(cos_i > 0.0, self.outside.order_one_suffices(alpha, cos_i),
                         self.inside.order_one_suffices(alpha, -cos_i))


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


# benches/auto_packets.py's records of auto's calls in execution order while recording (``record_calls``):
# [size, [(site, records, counter) per traced call]].
_RECORD = [None]


def record_calls(size=0):
    """Starts recording each lane of ``auto``'s calls in the kernels traced from now on, in the order the
    kernel executes them (``size`` records per traced call at most; 0 stops). Each traced call gets its own
    buffer (drjit cannot ``scatter_inc`` one counter from two places of a kernel): a record is the lane's
    index · 2 + whether it walks, at the slot an atomic counter hands out, so with one thread
    (dr.set_thread_count(1)) a SIMD packet's call is a run of records of one packet's lanes (the lanes'
    index // the vector width). For measurement only (benches/auto_packets.py). Returns the list that
    receives (site, records, counter) per traced call (site 0: ``eval``/``pdf``/``eval_pdf``, 1: ``sample``,
    2: ``eval``'s branch, ``record_branch``)."""
    _RECORD[0] = [size, []] if size else None
    return _RECORD[0][1] if size else None


def _record(one, site):
    size, calls = _RECORD[0]
    records, counter = dr.zeros(mi.UInt32, size), dr.zeros(mi.UInt32, 1)
    dr.make_opaque(records, counter)
    calls.append((site, records, counter))
    slot = dr.scatter_inc(counter, mi.UInt32(0))
    value = dr.arange(mi.UInt32, dr.width(one)) * 2 + dr.select(one, 0, 1)
    dr.scatter(records, mi.UInt32(value), slot, active=slot < size)


def record_branch(one):
    """Records the lanes of ``eval``'s branch (site 2: the closed form where ``one``) while ``record_calls``
    records."""
    if _RECORD[0] is not None:
        _record(one, 2)


def order_one(rule, mf, mu, full=True, site=0, lanes=None):
    """Per lane: whether the call is reduced to order 1 (the rule, where ``full`` allows it), counted while
    ``count_calls`` counts (and recorded as call ``site`` while ``record_calls`` records).

    ``lanes``: a value as wide as the call (its lane key), whose width the mask takes where it is narrower — in a
    direct call from evaluated code α, ω_i and ω_o may be single values beside per-lane keys, and drjit 1.5's
    evaluated ``dr.if_stmt`` on a one-lane mask whose branches read per-lane values aborts the process
    ("jit_assemble(): schedule contains variable … with incompatible size"; python_tests/test_auto_order_one.py).
    In a render every value has the call's width and nothing changes."""
    one = rule.order_one_suffices(dr.maximum(mf.alpha_u, mf.alpha_v), mu) & full
    if lanes is not None and dr.width(one) < dr.width(lanes):
        one = one | dr.zeros(mi.Bool, dr.width(lanes))
    counter = _COUNTER[0]
    if counter is not None:
        # One per lane: a literal value and index would make a scatter of width 1 outside a loop.
        dr.scatter_reduce(dr.ReduceOp.Add, counter, dr.full(mi.UInt32, 1, dr.width(one)), mi.UInt32(0))
        dr.scatter_reduce(dr.ReduceOp.Add, counter, mi.UInt32(1), mi.UInt32(1), active=~one)
    if _RECORD[0] is not None:
        _record(one, site)
    return one


def cap(rule, mf, mu, max_bounces, full=True):
    """The bounce cap of each lane: 1 where order 1 suffices (and ``full`` allows the rule), else
    ``max_bounces``."""
    return dr.select(order_one(rule, mf, mu, full), mi.UInt32(1), mi.UInt32(max_bounces))


def eval_pdf(one, closed, full, want_value, want_pdf, label):
    """(value, pdf) (either None where not wanted) of ``closed()`` on the lanes ``one`` and of ``full()``
    elsewhere — each a (value thunk, pdf thunk) pair — behind a symbolic ``dr.if_stmt``, so that a packet
    whose lanes all reduce runs no walk (and one with no reduced lane no closed form)."""
    def pick(pair):
        return lambda: ((pair[0](),) if want_value else ()) + ((pair[1](),) if want_pdf else ())

    out = list(dr.if_stmt((), one, pick(closed), pick(full), label=label))
    return (out.pop(0) if want_value else None), (out.pop(0) if want_pdf else None)


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


def order_one_pdf(mf, wi, wo, l0=None):
    """The density of order 1's sample (``sample``): the visible-normal reflection density
    D_ωi(h)/(4 ω_i·h) = D(h)/(4 cos θ_i L_0) (``Microfacet.reflect_pdf`` with A(ω_i) = cos θ_i·L_0, sharing
    D and L_0 with ``order_one_eval``; ``l0``: L_0 where the caller has it)."""
    _, d, l0_, ok = _order_one_terms(mf, wi, wo)
    return dr.select(ok, d / (4.0 * wi[2] * (l0_ if l0 is None else l0)), 0.0)


def sample(mf, fresnel, wi, sample1, u1, u2, one, max_bounces, key, walk_pdf):
    """``auto``'s sample on a conductor: (ω_o, pdf, weight, valid), the values of ``correlated``'s walk sampler
    (``posfree.sample_walk``) capped at one vertex on the lanes ``one`` and their order 1's weight and density
    (twin of ``order_one_sample`` in src/models/auto/mod.rs), the full walk and ``walk_pdf(ω_o)`` elsewhere.

    The walk's first vertex (the visible normal drawn with (u1, u2), the reflection, F and Λ of the reflected
    direction, the exit decision with ``sample1``) is computed here once for every lane; the order-1 lanes
    finish in closed form from it, the walking lanes take the walk up at vertex 1 (``walk.sample_walk`` with its
    stream's counter where the first vertex leaves it) behind a symbolic ``dr.if_stmt``, so that a packet with
    no walking lane runs no loop, no stream and no MIS density; a packet of both kinds draws the first normal
    once. Bit-identical to running the capped walk on every lane (python_tests/test_auto_order_one.py)."""
    vertex = sample_vertex(CORRELATED, mf, fresnel)
    start = wi[2] != 0.0
    ones = dr.full(mi.Spectrum, 1.0, dr.width(wi))
    l0 = mf.abs_lambda(-wi)
    u = tuple(clean_uniform(mi.Float(x)) for x in (sample1, u1, u2))
    d, weight, done, active, lam = vertex(mi.Vector3f(wi), ones, u, l0, None, start)
    # A lane that does not start keeps the walk's initial state (the loop never runs it).
    d = dr.select(start, d, -wi)
    weight = dr.select(start, weight, ones)
    done &= start
    active &= start & (1 < max_bounces)

    def reduced(d, weight, done, active, lam):
        pdf = order_one_pdf(mf, wi, d, l0)
        valid = (pdf > 0.0) & dr.isfinite(pdf) & dr.all(dr.isfinite(d))
        # Λ(ω_o) = lam wherever ω_o points up; below, pdf = 0 and the weight is 0.
        return d, pdf, dr.select(valid, weight * (l0 / (l0 + lam)), 0.0), valid

    def walking(d, weight, done, active, lam):
        rng = Stream(key, mi.UInt32(0))
        numbers = walk.vertex_numbers(rng)  # the stream as the walk's loop leaves it after vertex 0
        wo, weight, valid = walk.sample_walk(-d, numbers, active, lam, vertex, max_bounces, key, weight,
                                             "msx_posfree_conductor_sample", start=(1, rng.counter), done=done)
        return wo, walk_pdf(wo), weight, valid

    return dr.if_stmt((d, weight, done, active, lam), one, reduced, walking, label="msx_auto_order_one_sample")
