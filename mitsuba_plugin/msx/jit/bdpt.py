"""The bidirectional estimator of a position-free path integral (Wang et al. 2022 §4.2, eqs. 27–29) in the
Dr.Jit engine: twin of ``src/walk/bdpt.rs``, written once for every surface; a surface supplies its vertex
terms (the Rust ``BdptSurface``), this module the subpaths, the strategies, the balance heuristic and the
hand-over to path tracing.

Paths, strategies, densities and the balance heuristic are those of the Rust module (its doc has the
derivation): a path of order k is d_0 = −ω_i, d_1, …, d_k = ω_o; strategy s ∈ {0, …, k−1} takes d_1..d_s
from the camera subpath and d_{s+1}..d_{k−1} (t = k−1−s directions) from the light subpath and evaluates
vertex s deterministically; its weight is p_s / Σ p_{s'} from the ratio chains ``Mis``.

In the engine the number of bidirectional orders K_b = min(max_bounces, ``DEFAULT_BDPT_ORDERS``) is a
Python int known at trace time (``max_bounces`` is a Python int for these estimators), so the subpaths
(at most K_b + 1 vertices each) are Python lists of per-lane arrays and the loops over vertices, orders and
strategies are unrolled when the kernel is traced: no ``dr.alloc_local``. What the Rust decides per call
(a subpath that stops early: ``camera_ready`` false, a step that returns None) is a per-lane mask: vertex
``s`` of a subpath exists on the lanes of ``ok[s]``. The subpaths have fixed length and no roulette
(the balance heuristic needs every strategy's density as written); orders above K_b are the surface's
path tracer continuing the camera subpath (``pt_tail``, a ``dr.while_loop``).

Random numbers: one counter-based stream per lane (jit/rng.py); the camera steps draw first, then the light
steps, then the PT tail continues the same stream. A lane whose subpath stopped draws (and ignores) the
same numbers as the others, so the counters are trace-time constants.

A surface object provides (per-lane arrays; ``valid`` masks where the Rust returns None or false):

- ``camera_start()`` → vertex; ``camera_ready(v)`` → Bool;
  ``camera_step(v, s, rng)`` → (vertex, p_in, p_rev, valid); ``camera_last(v, rng)`` → vertex;
- ``light_start()`` → vertex; ``light_ready(v)`` → Bool; ``light_step(v, t, rng)`` → (vertex, p_in, p_rev,
  valid);
- ``connect(cam, light)`` (vertices 0..=s and 0..=t) → (pr, pf, data, valid);
- ``weighted(data, cv, lv, denom)`` → (value, valid);
- ``pt_tail(cam, ready, kb, orders, rng)`` → value (the orders above K_b from the end of ``cam`` on the
  lanes ``ready``);
- ``zero()`` → the value 0 of the lanes' width;
- ``active``: the lanes on which the estimator runs at all.
"""

import drjit as dr
import mitsuba as mi

from .rng import Stream

# src/walk/bdpt.rs: the default number of orders handled bidirectionally (higher orders: PT), and the
# largest K_b (the Rust's stack arrays; here the unrolled lists).
DEFAULT_BDPT_ORDERS = 3
MAX_BDPT_ORDERS = 32


class Mis:
    """What the balance heuristic keeps of a subpath vertex (twin of ``Mis``): the density with which the
    subpath sampled it (``p_in``) and the accumulated ratio chain (``chain``; 0 for s, t ≤ 1)."""

    def __init__(self, p_in, chain):
        self.p_in, self.chain = p_in, chain

    def extend(self, p_rev):
        """The ratio chain extended by one step: p_rev / p_in · (1 + chain)."""
        return p_rev / self.p_in * (1.0 + self.chain)


def bdpt_orders(max_bounces, bdpt_orders=DEFAULT_BDPT_ORDERS):
    """K_b = min(max_bounces, bdpt_orders clamped to 1..=MAX_BDPT_ORDERS), a Python int."""
    if not isinstance(max_bounces, int):
        raise TypeError("the BDPT estimator needs a bounce cap known at trace time (a Python int), got %r"
                        % type(max_bounces).__name__)
    return min(max_bounces, min(max(bdpt_orders, 1), MAX_BDPT_ORDERS))


def subpath(start, ready, step, n, active, rng):
    """A subpath of ``n`` sampled vertices after ``start`` (the camera's or the light's: the Rust's
    ``camera_step``/``light_step`` loops of ``estimate_on``): the vertices, their ``Mis`` records and the
    per-lane masks ``ok[i]`` of the lanes on which vertex i exists (the previous one existed, was ``ready``
    and its step was valid). ``step(v, i, rng)`` → (vertex, p_in, p_rev, valid)."""
    verts = [start]
    records = [Mis(mi.Float(1.0), mi.Float(0.0))]
    ok = [mi.Bool(active)]
    for i in range(n):
        go = ok[i] & ready(verts[i])
        v, p_in, p_rev, valid = step(verts[i], i, rng)
        chain = records[i].extend(p_rev) if i >= 1 else mi.Float(0.0)
        verts.append(v)
        records.append(Mis(p_in, chain))
        ok.append(go & valid)
    return verts, records, ok


def estimate(surface, orders, bdpt_orders_=DEFAULT_BDPT_ORDERS, key=None, rng=None):
    """The BDPT estimate of f(ω_i, ω_o)·|cos θ_o| over the orders ``orders`` = (lo, hi) (Python ints,
    1 ≤ lo ≤ hi within the bounce cap): orders up to K_b bidirectionally, the rest by the surface's path
    tracer (twin of ``estimate`` / ``estimate_on``). ``rng``: the lane's stream (a new one from ``key``
    when None)."""
    o_lo, o_hi = orders
    result = surface.zero()
    if o_lo > o_hi:
        return result
    kb = bdpt_orders(o_hi, bdpt_orders_)
    rng = Stream(key) if rng is None else rng
    pt_tail = o_hi > kb  # orders ≤ kb: bidirectional

    # ---- camera subpath d_0..d_{n_c} (n_c = kb − 1, or kb if the PT tail needs d_kb)
    n_c_target = kb if pt_tail else kb - 1
    cam, cam_mis, cam_ok = subpath(surface.camera_start(), surface.camera_ready, surface.camera_step, n_c_target,
                                   surface.active, rng)
    if not pt_tail:
        # The last camera vertex, used only by connections (a no-op for the conductor).
        ready = cam_ok[n_c_target] & surface.camera_ready(cam[n_c_target])
        cam[n_c_target] = surface.camera_last(cam[n_c_target], ready, rng)

    if o_lo <= kb:
        # ---- light subpath e_0 = ω_o, e_1 = d_{k−1}, … (kb − 1 sampled)
        lig, lig_mis, lig_ok = subpath(surface.light_start(), surface.light_ready, surface.light_step, kb - 1,
                                       surface.active, rng)

        # ---- connections: order k, strategy s, t = k − 1 − s
        for k in range(o_lo, kb + 1):
            for s in range(k):
                t = k - 1 - s
                if s >= len(cam) or t >= len(lig):
                    continue
                pr, pf, data, valid = surface.connect(cam[: s + 1], lig[: t + 1])
                denom = mi.Float(1.0)
                if s >= 1:
                    denom += cam_mis[s].extend(pr)
                if t >= 1:
                    denom += lig_mis[t].extend(pf)
                value, finite = surface.weighted(data, cam[s], lig[t], denom)
                ok = cam_ok[s] & lig_ok[t] & valid & finite
                result = dr.select(ok, result + value, result)

    # ---- orders kb+1 ..= o_hi: the camera subpath continues as PT with NEE.
    if pt_tail:
        result += surface.pt_tail(cam, cam_ok[kb], kb, (o_lo, o_hi), rng)
    return result
