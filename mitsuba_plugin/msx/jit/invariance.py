"""The invariance principle (Cui et al. 2023, with Bitterli & d'Eon 2022's exit probability) in the Dr.Jit
engine, PT estimators on the three microsurfaces: conductor facets (twin of
``src/models/invariance/conductor.rs``, ``eval``/``sample``, with the incremental exit table
``MonotoneExit`` of ``recursion.rs``), Lambertian facets (``general.rs``: the complete recursion
``ExitTable``) and the rough dielectric (``dielectric.rs``: the exact depth law ``PieceChain`` of the first
run, Heitz's walk of jit/heitz.py after the first refraction). On conductor facets also the BDPT estimator
(``eval_bdpt``: the position-free conductor's of jit/posfree.py with the whole path's exit probability,
``WholePath``; the other microsurfaces have none in the core either).

Lambertian facets: their paths are not monotone in z, so the exit probabilities need the whole triangle
p(i, j) of ``ExitTable`` (O(m²) per lane): it lives in a ``dr.alloc_local`` buffer of (m+1)(m+2)/2 entries
for m = the bounce cap (at most ``LOCAL_CAPACITY``; a walk whose table is full ends there, only with a
larger cap), and a new column is two nested ``dr.while_loop``s.

Dielectric: until the first refraction the path reflects in ω_i's medium, a monotone run whose vertex
depth has the exact law of ``PieceChain`` (pieces of rates L_i, π over the piece index); the next events
use its exact exit probability (reflection) or the top piece's Beta term plus one sampled depth
(transmission); at the first refraction the depth is drawn from that law, flipped, and
``heitz.dielectric_eval_from`` / ``sample_from`` continue the path. The pieces live in
``DIELECTRIC_RUN_SLOTS`` registers (below).

The conductor walk:

Heitz's walk with the heights integrated out: a conductor path is a run of a ≥ 1 downward directions
d_0..d_{a−1} followed by upward ones, and the probability that it hits at every vertex and leaves along an
upward x is a column recursion over the downward run (``recursion.rs``, "Monotone paths"). Its state is
the |Λ| of the downward directions and one value g_i per downward direction: a per-path array whose length
is the length of the downward run.

Registers, not arrays. A local array (``dr.alloc_local``) cannot be compiled inside a symbolic call by
drjit 1.5's LLVM backend, and Mitsuba calls every BSDF through one; so the run lives in K per-lane
registers, Python lists of mi.Float carried through the walk's ``dr.while_loop`` (``MonotoneExit``:
K = ``CONDUCTOR_RUN_SLOTS`` = 20 slots of |Λ| and of g; ``PieceChain``: K = ``DIELECTRIC_RUN_SLOTS`` = 18
slots of L_i and π), plus the run length a. An indexed write is a select over the K slots, the O(a) passes
over the run are unrolled over the K slots and masked by i < a; the slots from ``RUN_SLOTS_ALWAYS`` = 4 on
sit in a ``dr.if_stmt`` that a packet of lanes whose runs are all shorter skips (``over_run``; the same bits
as without it, a test). Up to K the state is the core's, exactly;
a path whose downward run would be longer than K (or than the bounce cap, when that is smaller) **ends
there**: the push of its (K+1)-th downward direction fails, the walk stops, and what it would still have
added (its higher orders, or a sampled direction: the sample is invalid) is lost — a bias of at most the
fractions below. The BDPT's connections use the same class with one slot per direction of their path.

K is measured, not guessed: the run length a (conductor) / piece count (dielectric) at the end of each
lane of the former ``dr.alloc_local`` walks (capacity 64, default max_bounces 64), eval (ω_o uniform on
the hemisphere / sphere) and sample, Cu / η = 1.5168, GGX and Beckmann, α ∈ {1, 2, 4}, θ_i ∈ {0, 0.4, 0.8,
1.3, 1.5, 1.55} (dielectric: from both sides). Grazing incidence gives *short* runs (P(a > 4) ≤ 2e-6 at
θ_i = 1.55); the longest come at normal incidence with α = 4, GGX (Beckmann's are shorter). The tail is
faster than geometric (each further step ×0.2–0.3 at a ≈ 15–20). Worst cases, fraction of lanes with
a > K (paths) and of the estimate's sum they carry (energy; their whole estimates, a bound on what the
walk ending at K loses), eval / sample:

- conductor, GGX α = 4, θ_i = 0 (8.4e7 lanes): K = 17: 5.0e-6 / 5.7e-6 paths, 2.3e-6 / 2.5e-6 energy;
  K = 18: 1.0e-6 / 1.5e-6, 5.6e-7 / 6.2e-7; K = 19: 3.3e-7 / 3.3e-7, 1.0e-7 / 1.3e-7; **K = 20**: 4.8e-8 /
  6.0e-8 (4 / 5 lanes), 3.7e-9 / 2.3e-8; K = 21: 1.2e-8 / 2.4e-8; no run longer than 22. Other cases are
  shorter: α = 4, θ_i = 0.4: a > 18 in 3e-8; α = 2, θ_i = 0: a > 13 in 6e-8; α = 4, θ_i = 0.8: a > 16 in
  6e-8 (3.4e7 lanes each).
- dielectric from below (total internal reflection lengthens the run), GGX α = 4, θ_i = 0 (5.5e7 lanes):
  K = 15: 1.6e-6 / 2.2e-6 paths, 7.1e-6 / 2.1e-6 energy; K = 16: 5.1e-7 / 4.6e-7, 1.2e-6 / 3.7e-7; K = 17:
  3.7e-8 / 1.1e-7, 1.6e-7 / 5.9e-8; **K = 18**: 0 / 1.8e-8 (0 / 1 lane), 0 / 9.8e-9; no run longer than
  20. θ_i = 0.4 from below: a > 15 in 2.4e-7 / 3.6e-7 of 1.7e7 lanes, none above 17; from above: a > 8 in
  ≤ 1.2e-7.

A larger α than 4 (outside the measured range) gives longer runs, so more paths end at K.

``eval``: visible-normal walk with NEE towards ω_o weighed by the exit probability given the hits, the
connection strategy (a one-vertex light subpath y from the side of ω_o) for orders 2 and 3 with the
balance heuristic, Russian roulette with sure survival above ``RR_KEEP``, and the exact stop once an
upward direction is at least as steep as ω_o. ``sample``: the same walk leaving at each upward direction
with probability 1 − H_m/H_{m−1}; the weight is the product of the Fresnel terms.
"""

import copy
import math

import drjit as dr
import mitsuba as mi

from . import mis, walk
from .gradients import LoopValues
from .microfacet import INV_PI, ConductorFresnel, dot, half_vector, max_channel, reflect
from . import heitz
from .dielectric import eta_seen, radiance_scale, reflect_or_refract_unit
from .glass_traced import RR_TRACED_FLOOR, edge_point, eta_tangent_step, scatter_traced
from .model import ConductorWalk, DielectricWalk, DiffuseWalk
from .rng import Stream, clean_uniform
from .special import expm1, l_beta, optical_depth

# src/models/invariance/conductor.rs: where roulette starts, its sure-survival level, and the highest
# order the connection strategy serves.
RR_START = 1
RR_KEEP = 0.5
CONNECT_MAX_ORDER = 3

# Largest table of the Lambertian walk's local buffers (their size is the bounce cap when that is smaller).
LOCAL_CAPACITY = 64
# Registers of a downward run (conductor ``MonotoneExit``, dielectric ``PieceChain``), chosen by
# measurement (the module docstring): a path whose run would be longer ends there.
CONDUCTOR_RUN_SLOTS = 20
DIELECTRIC_RUN_SLOTS = 18
# Slots every pass visits; the others only under ``dr.if_stmt(a > RUN_SLOTS_ALWAYS)``, which the LLVM backend
# compiles to a branch that a packet of lanes skips when none of them has a run that long (most runs are
# 1–3 directions: the passes over all the slots cost 30 % of the invariance walk's render time, measured).
RUN_SLOTS_ALWAYS = 4


# ------------------------------------------------------------------ the exit table (recursion.rs)


def over_run(n, a, step, carry, reverse=True, unrolled=False):
    """``carry = step(i, carry)`` for the slots i of a run held in ``n`` registers, n−1 … 0 (``reverse``) or
    0 … n−1; the slots from ``RUN_SLOTS_ALWAYS`` on inside ``dr.if_stmt(a > RUN_SLOTS_ALWAYS)``, a branch that
    lanes with shorter runs skip. ``step`` must leave the carry unchanged for the slots i ≥ ``a`` (``a``: the
    slots in use, a UInt32 per lane).

    ``unrolled``: every slot without the branch (the same bits), for a walk whose derivative is propagated
    in forward mode through its loop (``mf_sample`` given): drjit 1.5's forward mode fails on the branch (it
    tries to evaluate a symbolic variable). The run's owner (``MonotoneExit``, ``PieceChain``) carries it."""
    lo = min(RUN_SLOTS_ALWAYS, n)
    head, tail_slots = list(range(lo)), list(range(lo, n))
    if reverse:
        head.reverse()
        tail_slots.reverse()

    def tail(*c):
        for i in tail_slots:
            c = step(i, c)
        return c

    if not reverse:
        for i in head:
            carry = step(i, carry)
    if tail_slots and unrolled:
        carry = tail(*carry)
    elif tail_slots:
        carry = dr.if_stmt(args=tuple(carry), cond=a > lo, true_fn=tail, false_fn=lambda *c: c, label="msx_run_tail")
    if reverse:
        for i in head:
            carry = step(i, carry)
    return carry


class MonotoneExit:
    """Incremental exit probabilities of a monotone path d_0..d_m (twin of ``MonotoneExit``), per lane in
    ``n`` registers, unrolled at trace time: Python lists ``down`` (|Λ| of the downward run; slot i < a holds
    its i-th direction) and ``g`` (the column's second term, normalised by the hit probability as the
    Rust's), the run length ``a`` (UInt32), ``has_up`` (an upward direction was pushed) and the hit
    probability ``hit`` = H_m. Every indexed access is a select over the slots, every pass over the run
    is masked by i < a. Pass :meth:`state` through the walk's loop and rebuild with :meth:`from_state`."""

    def __init__(self, down, g, a, has_up, hit, unrolled=False):
        self.down, self.g = list(down), list(g)
        self.a, self.has_up, self.hit = a, has_up, hit
        self.n = len(self.down)
        # How its passes are traced (``over_run``): a Python bool of the trace, not loop state.
        self.unrolled = unrolled

    @staticmethod
    def new(l0, n, unrolled=False):
        """A path starting with d_0 (downward) of |Λ(d_0)| = ``l0``, room for ``n`` downward directions."""
        return MonotoneExit([mi.Float(l0)] + [mi.Float(1.0) for _ in range(n - 1)], [mi.Float(0.0) for _ in range(n)],
                            mi.UInt32(1), mi.Bool(False), mi.Float(1.0), unrolled)

    def state(self):
        return (self.down, self.g, self.a, self.has_up, self.hit)

    @staticmethod
    def from_state(s, unrolled=False):
        return MonotoneExit(*s, unrolled=unrolled)

    def push_down(self, l, active):
        """Appends a downward direction of |Λ| = ``l`` where ``active``; False on a non-monotone path or a
        full run (a = n), which ends the walk."""
        ok = active & ~self.has_up & (self.a < self.n)
        a = self.a

        def step(i, down):
            if i == 0:
                return down
            return down[:i] + (dr.select(ok & (a == i), l, down[i]),) + down[i + 1:]

        self.down = list(over_run(self.n, a + 1, step, tuple(self.down), unrolled=self.unrolled))
        self.a = dr.select(ok, self.a + 1, self.a)
        return ok

    def columns(self, lambda_x, lambda_y):
        """One pass over the downward run: (column(Λ_x), exit_via_up(Λ_y, Λ_x)), i.e. p_exit(d_0..d_m, x)/H_m
        and p_exit(d_0..d_m, y, x)/H_m for virtual upward x, y (``exit_given_hits``, ``exit_via_up``)."""
        has_up = self.has_up
        c0 = dr.select(has_up, 0.0, 1.0)

        def step(i, carry):
            c, c_x, c_y = carry
            run = self.a > i
            li = self.down[i]
            gi = dr.select(has_up, self.g[i], 0.0)
            r_x = 1.0 / (li + lambda_x)
            c_y_new = (li * c_y + gi) / (li + lambda_y)
            return (dr.select(run, (li * c + gi) * r_x, c), dr.select(run, (li * c_x + lambda_y * c_y_new) * r_x, c_x),
                    dr.select(run, c_y_new, c_y))

        c, c_x, _ = over_run(self.n, self.a, step, (c0, mi.Float(0.0), c0), unrolled=self.unrolled)
        return c, c_x

    def push_up(self, lam, active):
        """Appends an upward direction with Λ = ``lam`` where ``active``; returns H_{m+1}/H_m, the
        probability that it hits the surface again (0 where not active)."""
        was_up = self.has_up

        def step(i, carry):
            c, cont, g = carry[0], carry[1], carry[2:]
            run = self.a > i
            li = self.down[i]
            gi = dr.select(was_up, self.g[i], 0.0)
            c = dr.select(run, (li * c + gi) / (li + lam), c)
            g_i = lam * c
            return (c, dr.select(run, cont + g_i / li, cont)) + g[:i] + (g_i,) + g[i + 1:]

        out = over_run(self.n, self.a, step, (dr.select(was_up, 0.0, 1.0), mi.Float(0.0)) + tuple(self.g),
                       unrolled=self.unrolled)
        cont, g_new = out[1], out[2:]
        good = (cont > 0.0) & dr.isfinite(cont)
        inv = dr.select(good, 1.0 / cont, 0.0)

        def scale(i, g):  # the slots i ≥ a are never read
            return g[:i] + (dr.select(active, g_new[i] * inv, g[i]),) + g[i + 1:]

        self.g = list(over_run(self.n, self.a, scale, tuple(self.g), unrolled=self.unrolled))
        self.hit = dr.select(active, self.hit * dr.select(good, cont, 0.0), self.hit)
        self.has_up = self.has_up | active
        return dr.select(active, cont, 0.0)

    def exit_probability(self, lam):
        """p_exit(d_0..d_m, x) for an upward x with Λ(x) = ``lam``: H_m times the column."""
        return self.hit * self.columns(lam, mi.Float(0.0))[0]


# ------------------------------------------------------------------ helpers


def half_vector_d(mf, w, x):
    """(D(h), w·h) for the half vector h of w and x; (0, 0) where w does not see h."""
    h, length = half_vector(w, x)
    c = dot(w, h)
    ok = (length > 0.0) & (c > 0.0)
    return dr.select(ok, mf.d(h), 0.0), dr.select(ok, c, 0.0)


def valid_direction(w):
    return dr.all(dr.isfinite(w)) & (w[2] > 0.0)


def run_slots(max_bounces, slots=None):
    """The registers of a downward run: ``slots`` (default ``CONDUCTOR_RUN_SLOTS``), fewer when the bounce
    cap is smaller (a path has at most that many downward directions), all of them when the cap is per
    lane."""
    slots = CONDUCTOR_RUN_SLOTS if slots is None else slots
    if isinstance(max_bounces, int):
        return max(1, min(max_bounces, slots))
    return slots


class LightVertex:
    """The connection's one-vertex light subpath: y = −(ω_o reflected about a visible normal of ω_o)
    (twin of ``LightVertex``)."""

    def __init__(self, mf, fresnel, wo, pdf_scale_o, u1, u2, mf_sample=None):
        m, valid = (mf if mf_sample is None else mf_sample).sample_visible(wo, u1, u2)
        cos1 = dot(wo, m)
        y = -reflect(wo, m)
        up = y[2] > 0.0
        l_y = dr.select(up, mf.lambda_(y), mf.abs_lambda(y))
        area_y = dr.abs(y[2]) * l_y
        d_m = mf.d(m)
        self.pdf = d_m * pdf_scale_o
        self.phase = 0.25 * d_m / area_y
        self.valid = (valid & (cos1 > 0.0) & (self.pdf > 0.0) & (self.phase > 0.0) & dr.isfinite(self.pdf)
                      & dr.isfinite(self.phase) & dr.isfinite(l_y))
        self.y, self.l_y, self.up = y, l_y, up
        self.fresnel = fresnel.eval(dr.select(cos1 > 0.0, cos1, 1.0))

    def connect(self, mf, fresnel, has_up, w, pdf_scale, via_up, column_ly_o, traced=False):
        """The connection estimate at the vertex (w = −d_m): ``via_up`` = p_exit(.., y, ω_o)/H_m for an
        upward y, ``column_ly_o`` = column(Λ_o) for the downward case (the caller's one pass). ``traced``
        (y drawn with the parameters detached, docs/gradients.md): the balance weight detached, the
        integrand over y's detached density."""
        d_h, cos0 = half_vector_d(mf, w, self.y)
        p_fwd = d_h * pdf_scale
        ok = self.valid & (p_fwd > 0.0) & dr.isfinite(p_fwd)
        via_down = dr.select(has_up, 0.0, self.l_y / (self.l_y + self.lambda_o) * column_ly_o)
        exit = dr.select(self.up, via_up, via_down)
        if traced:
            value = dr.detach(self.pdf / (p_fwd + self.pdf)) * (p_fwd * self.phase * exit) / dr.detach(self.pdf)
        else:
            value = p_fwd * self.phase * exit / (p_fwd + self.pdf)
        ok &= (value > 0.0) & dr.isfinite(value)
        return dr.select(ok, fresnel.eval(cos0) * self.fresnel * value, 0.0)


# ------------------------------------------------------------------ the walks


def eval(mf, fresnel, wi, wo, max_bounces, key, mf_sample=None):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o, orders 1..max_bounces (Rust ``eval`` and
    ``Walk::from``). ``mf_sample``: the statistics directions are drawn from when they are not ``mf`` (the
    parameters detached; the estimate's derivative is then unbiased: docs/gradients.md)."""
    last = max_bounces  # a Python int, or a UInt32 per lane
    slots = run_slots(last)
    lambda_o = mf.lambda_(wo)
    start = valid_direction(wi) & valid_direction(wo) & dr.isfinite(lambda_o) & (last > 0)
    pdf_scale_o = 0.25 / (wo[2] * (1.0 + lambda_o))
    connects = not isinstance(last, int) or last >= 2  # per lane: masked by order < last below
    rng0 = Stream(key)
    light = None
    if connects:
        u1, u2 = rng0.next2()
        light = LightVertex(mf, fresnel, wo, pdf_scale_o, u1, u2, mf_sample)
        light.lambda_o = lambda_o
    l0 = mf.abs_lambda(-wi)
    dp0 = MonotoneExit.new(l0, slots, unrolled=mf_sample is not None)
    return walk_from(mf, fresnel, wo, lambda_o, light, CONNECT_MAX_ORDER, mi.Vector3f(wi), 0.25 / (wi[2] * l0),
                     mi.Spectrum(1.0), dp0, start, 0, last, key, rng0.counter, mf_sample=mf_sample)


def walk_from(mf, fresnel, wo, lambda_o, light, connect_max, w, pdf_scale, thr, dp0, active, first_vertex, last,
              key, counter, label="msx_invariance_conductor_eval", mf_sample=None):
    """The walk of ``eval`` from vertex ``first_vertex`` on (twin of ``Walk::from``), arriving there with
    w = −d_m, ``pdf_scale`` = 1/(4 A(w)), the throughput Π F · H_m and the exit table ``dp0`` of d_0..d_m,
    on the lanes ``active``; orders up to ``last``. ``light`` (a ``LightVertex`` with ``lambda_o`` set, or
    None) and ``connect_max``: the connection strategy for orders 2..connect_max (none with None and 0: the
    BDPT's tail). The lane's stream is (``key``, ``counter``). ``mf_sample``: as ``eval``'s; the
    differentiated values (α, η, k, Λ(ω_o), the light vertex's) then travel in the loop's state (drjit 1.5
    rejects differentiable reads of wide values from outside a loop inside a symbolic call)."""
    connects = light is not None
    traced = mf_sample is not None

    def body(j, w, pdf_scale, pdf_walk, thr, result, active, counter, dp_state, *piped):
        mf, fresnel, lambda_o, light, mf_s = outer_mf, outer_fresnel, outer_lambda_o, outer_light, outer_mf
        if traced:
            lv = LoopValues(outer_mf.dist, piped)
            mf, mf_s, lambda_o, rest = lv.mf, lv.mf_sample, lv.lambda_o, lv.rest
            if connects:
                light = copy.copy(outer_light)
                light.l_y, light.pdf, light.phase, light.fresnel = rest[:4]
                light.lambda_o = lambda_o
                rest = rest[4:]
            if not outer_fresnel.mirror:
                fresnel = ConductorFresnel(rest[0], rest[1])
        rng = Stream(key, counter)
        dp = MonotoneExit.from_state(dp_state, dp0.unrolled)
        order = j + 1
        # NEE: D(h)/(4 A(w)) · F · p_exit(d_0..d_m, ω_o)/H_m, with the balance heuristic against the
        # connection for orders 2..connect_max.
        d_h, cos_wh = half_vector_d(mf, w, wo)
        value = d_h * pdf_scale
        lambda_y = light.l_y if connects else mi.Float(0.0)
        col_o, via_up = dp.columns(lambda_o, lambda_y)
        if connects:
            mis_w = (j > 0) & (order <= connect_max) & (value > 0.0)
            p_rev = d_h * (0.25 / (wo[2] * (1.0 + lambda_o)))
            balance = pdf_walk / (pdf_walk + p_rev)
            value = dr.select(mis_w, value * (dr.detach(balance) if traced else balance), value)
        ok = (value > 0.0) & dr.isfinite(value)
        result = dr.select(active & ok, result + thr * fresnel.eval(cos_wh) * (value * col_o), result)
        active &= order < last
        # The connection for order + 1: d_{m+1} = y from the side of ω_o.
        if connects:
            conn = light.connect(mf, fresnel, dp.has_up, w, pdf_scale, via_up, col_o, traced)
            conn_on = active & (order < connect_max)
            result = dr.select(conn_on, result + thr * conn, result)
        # Russian roulette on Π F · H_m, after the vertex's estimates.
        u_rr, _ = rng.next2()
        thr, alive = walk.roulette_from(j >= RR_START, thr, u_rr, RR_KEEP)
        active &= alive
        # The next direction.
        u1, u2 = rng.next2()
        m, valid = mf_s.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        active &= valid & (cos_wm > 0.0)
        d_next = reflect(w, m)
        up = d_next[2] > 0.0
        # Along the upward run z only grows: once an upward d.z ≥ ω_o.z no later vertex reaches ω_o.
        active &= ~(up & (d_next[2] >= wo[2]))
        thr = thr * fresnel.eval(cos_wm)
        if traced:  # the step's density D(m)/(4 A(w)) over its detached value
            thr = thr * ((mf.d(m) * pdf_scale) / (mf_s.d(m) * dr.detach(pdf_scale)))
        if connects:
            pdf_walk = dr.select(order < connect_max, mf.d(m) * pdf_scale, pdf_walk)
        l_up = mf.lambda_(d_next)
        l_down = mf.abs_lambda(d_next)
        l_next = dr.select(up, l_up, l_down)
        active &= dr.isfinite(l_next)
        cont = dp.push_up(l_up, active & up)
        thr = dr.select(up, thr * cont, thr)
        active &= ~up | ((cont > 0.0) & (max_channel(thr) > 0.0))
        pushed = dp.push_down(l_down, active & ~up)
        active &= up | pushed
        w = -d_next
        pdf_scale = 0.25 / (dr.abs(d_next[2]) * l_next)
        return (j + 1, w, pdf_scale, pdf_walk, thr, result, active, rng.counter, dp.state()) + piped

    outer_mf, outer_fresnel, outer_lambda_o, outer_light = mf, fresnel, lambda_o, light
    width = dr.width(w)
    state = (mi.UInt32(first_vertex), mi.Vector3f(w), mi.Float(pdf_scale), mi.Float(0.0), mi.Spectrum(thr),
             dr.zeros(mi.Spectrum, width), mi.Bool(active), mi.UInt32(counter), dp0.state())
    if traced:
        state += (mi.Float(mf.alpha_u), mi.Float(mf.alpha_v), mi.Float(lambda_o))
        if connects:
            state += (mi.Float(light.l_y), mi.Float(light.pdf), mi.Float(light.phase), mi.Spectrum(light.fresnel))
        if not fresnel.mirror:
            state += (mi.Spectrum(fresnel.eta), mi.Spectrum(fresnel.k))
    state = dr.while_loop(state, lambda *s: s[6], body, label=label)
    return state[5]


# ------------------------------------------------------------------ the bidirectional estimator
# Cui 2023: "the bidirectional estimator is the same as Wang et al. except for the segment term" — the
# position-free conductor's (jit/posfree.py ``Bidirectional`` on jit/bdpt.py) with ``WholePath`` as its
# segment term (twin of ``WholePath`` in conductor.rs): bare pair factors 1/L_j, the exit probability of the
# whole path d_0..d_s, e_t..e_1, ω_o at each connection, this model's walk above K_b.


class WholePath:
    """The segment term of the invariance model for jit/posfree.py's ``Bidirectional``."""

    def cont(self, l, nxt, l_next):
        return mi.Float(1.0)

    def last(self, l, lambda_o):
        return 1.0 / l

    def whole_path(self, surface, cam, light):
        """(p_exit of d_0..d_s, e_t, …, e_1, ω_o, monotone) (``exit_table`` + ``exit_probability``)."""
        dirs = [(c.l, c.d) for c in cam] + [(v.l, v.e) for v in reversed(light[1:])]
        dp = MonotoneExit.new(dirs[0][0], len(dirs))
        ok = mi.Bool(True)
        for l, d in dirs[1:]:
            up = d[2] > 0.0
            dp.push_up(l, up)
            ok &= up | dp.push_down(l, ~up)
        return dp.exit_probability(surface.lambda_o), ok

    def pt_tail(self, surface, cam, ready, kb, orders, rng):
        """Orders above K_b: the walk of ``eval`` without its connection strategy from camera vertex K_b,
        with the exit table of d_0..d_{K_b} and the throughput Π F · H_{K_b}."""
        last = orders[1]
        dp = MonotoneExit.new(cam[0].l, run_slots(last))
        hit, ok = mi.Float(1.0), mi.Bool(ready)
        for c in cam[1 : kb + 1]:
            up = c.d[2] > 0.0
            cont = dp.push_up(c.l, ok & up)
            hit = dr.select(up, hit * cont, hit)
            ok &= up | dp.push_down(c.l, ok & ~up)
        cv = cam[kb]
        return walk_from(surface.mf, surface.fresnel, surface.wo, surface.lambda_o, None, 0, -cv.d,
                         0.25 / cv.area_back, cv.thr * hit, dp, ok, kb, last, rng.key, rng.counter,
                         label="msx_invariance_conductor_bdpt_tail")


def eval_bdpt(mf, fresnel, wi, wo, max_bounces, key):
    """BDPT estimate of f(ω_i, ω_o)·cos θ_o of the invariance model (twin of ``eval_bdpt``): orders up to
    K_b = ``bdpt.DEFAULT_BDPT_ORDERS`` bidirectionally, higher ones by the walk of ``eval`` (without its
    connection strategy). ``max_bounces``: a Python int."""
    from .posfree import estimate_bdpt_above

    active = valid_direction(wi) & valid_direction(wo) & dr.isfinite(mf.lambda_(wo))
    return estimate_bdpt_above(mf, fresnel, WholePath(), wi, wo, active, max_bounces, key)


def sample(mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling (Rust ``sample``): reflect about visible normals and, at each upward
    direction, leave with probability 1 − H_m/H_{m−1}. (sample1, u1, u2) drive the first vertex, the
    lane's stream the rest. Returns (ω_o, weight = Π F, valid); more than max_bounces vertices is invalid."""
    last = max_bounces  # a Python int, or a UInt32 per lane
    slots = run_slots(last)
    start = valid_direction(wi) & (last > 0)

    dp0 = MonotoneExit.new(mf.abs_lambda(-wi), slots)

    def body(j, w, weight, done, active, counter, u_exit, u1, u2, dp_state):
        rng = Stream(key, counter)
        dp = MonotoneExit.from_state(dp_state)
        m, valid = mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        active &= valid & (cos_wm > 0.0)
        d_next = reflect(w, m)
        weight = weight * fresnel.eval(cos_wm)
        up = d_next[2] > 0.0
        l_up = mf.lambda_(d_next)
        l_down = mf.abs_lambda(d_next)
        active &= dr.isfinite(dr.select(up, l_up, l_down))
        cont = dp.push_up(l_up, active & up)
        leaves = active & up & (u_exit >= cont)
        done = leaves & dr.all(dr.isfinite(d_next))
        pushed = dp.push_down(l_down, active & ~up)
        active &= (up & ~leaves) | pushed
        active &= j + 1 < last
        a, b = rng.next2()
        c, _ = rng.next2()
        return j + 1, -d_next, weight, done, active, rng.counter, c, a, b, dp.state()

    state = (mi.UInt32(0), mi.Vector3f(wi), mi.Spectrum(1.0), mi.Bool(False), mi.Bool(start), mi.UInt32(0),
             clean_uniform(mi.Float(sample1)), clean_uniform(mi.Float(u1)), clean_uniform(mi.Float(u2)),
             dp0.state())
    state = dr.while_loop(state, lambda *s: s[4], body, label="msx_invariance_conductor_sample")
    return -state[1], state[2], state[3]


# ------------------------------------------------------------------ Lambertian facets (general.rs)


class ExitTable:
    """Incremental exit probabilities of an arbitrary direction sequence d_0..d_m (twin of ``ExitTable``
    in ``general.rs``): the complete invariance recursion in scaled form,
    p(i,j) = S_1(d_i,d_j)·Σ_{l=i}^{j−1} L_l·p(i,l)·p(l+1,j), p(i,i) = 1, S_1(a,b) = 1/(|Λ(a)| + Λ(b)) for a
    down and b up, 0 otherwise. Per lane: ``l`` (Local, L_i), ``down`` (Local, 1 for a downward d_i),
    ``p`` (Local, the triangle: column j, p(0,j)..p(j,j), starts at j(j+1)/2), ``scratch`` (Local, the
    column of a virtual direction), ``n`` (directions pushed) and ``hit`` (H_m). Pass :meth:`state`
    through the walk's loop and rebuild with :meth:`from_state`. Every buffer access names its lanes (see
    ``MonotoneExit.columns``)."""

    def __init__(self, l, down, p, scratch, n, hit, capacity):
        self.l, self.down, self.p, self.scratch, self.n, self.hit = l, down, p, scratch, n, hit
        self.capacity = capacity

    @staticmethod
    def new(l0, capacity):
        """A path starting with the downward d_0 of |Λ(d_0)| = ``l0``; room for ``capacity`` directions."""
        l = dr.alloc_local(mi.Float, capacity, mi.Float(0.0))
        down = dr.alloc_local(mi.Float, capacity, mi.Float(0.0))
        p = dr.alloc_local(mi.Float, capacity * (capacity + 1) // 2, mi.Float(0.0))
        scratch = dr.alloc_local(mi.Float, capacity + 1, mi.Float(0.0))
        zero = mi.UInt32(0)
        l.write(mi.Float(l0), zero)
        down.write(mi.Float(1.0), zero)
        p.write(mi.Float(1.0), zero)
        return ExitTable(l, down, p, scratch, mi.UInt32(1), mi.Float(1.0), capacity)

    def state(self):
        return (self.l, self.down, self.p, self.scratch, self.n, self.hit)

    @staticmethod
    def from_state(s, capacity):
        return ExitTable(*s, capacity)

    def _column(self, out, base, lx, x_down, active, own=False):
        """out[base + i] = p(i, x) for i = 0..n, x a direction appended after d_{n−1} with |Λ(x)| = ``lx``,
        pointing down where ``x_down`` (then p(i, x) = 0 for i < n). Returns (p(0, x), out): the buffer
        is the column loop's state (a loop whose only effect were the writes would be optimised away)."""
        l, down, n = self.l, self.down, self.n
        p = None if own else self.p  # writing the triangle itself: read it through the loop's state
        out.write(mi.Float(1.0), dr.select(active, base + n, 0), active)

        def outer(i, value, out):
            on = active & (i > 0)
            i = dr.select(on, i - 1, 0)
            li = l.read(i, on)
            di = down.read(i, on) > 0.0
            run = on & di & ~x_down
            pp = out if p is None else p

            def inner(k, total):
                on2 = run & (k < n)
                kk = dr.select(on2, k, 0)
                c = out.read(dr.select(on2, base + kk + 1, 0), on2)
                pik = pp.read(dr.select(on2, kk * (kk + 1) // 2 + i, 0), on2)
                lk = l.read(kk, on2)
                return k + 1, total + dr.select(on2, lk * pik * c, 0.0)

            _, total = dr.while_loop((mi.UInt32(i), mi.Float(0.0)), lambda k, _t: run & (k < n), inner,
                                     label="msx_invariance_exit_row")
            value = dr.select(run, total / (li + lx), 0.0)
            out.write(value, dr.select(on, base + i, 0), on)
            return i, value, out

        first = dr.select(n > 0, 0.0, 1.0)
        _, value, out = dr.while_loop((mi.UInt32(n), mi.Float(first), out), lambda i, _v, _o: active & (i > 0),
                                      outer, label="msx_invariance_exit_column")
        return dr.select(active, value, 0.0), out

    def exit_given_hits(self, lam, active):
        """p_exit(d_0..d_m, x)/H_m for an upward x with Λ(x) = ``lam`` (0 where not active)."""
        e, self.scratch = self._column(self.scratch, mi.UInt32(0), lam, mi.Bool(False), active)
        return dr.select(active & (self.hit > 0.0), e / self.hit, 0.0)

    def push(self, lx, x_down, active):
        """Appends d_{m+1} (|Λ| = ``lx``, pointing down where ``x_down``) where ``active``: returns
        (H_{m+1}/H_m, pushed); not pushed when the buffers are full (the walk ends there)."""
        ok = active & (self.n < self.capacity)
        n = self.n
        _, self.p = self._column(self.p, n * (n + 1) // 2, lx, x_down, ok, own=True)
        idx = dr.select(ok, n, 0)
        self.l.write(mi.Float(lx), idx, ok)
        self.down.write(dr.select(x_down, 1.0, 0.0), idx, ok)
        self.n = dr.select(ok, n + 1, n)
        h, self.scratch = self._column(self.scratch, mi.UInt32(0), mi.Float(0.0), mi.Bool(False), ok)
        cont = dr.select(self.hit > 0.0, h / self.hit, 0.0)
        self.hit = dr.select(ok, h, self.hit)
        return dr.select(ok, cont, 0.0), ok


def table_capacity(max_bounces):
    """Directions an ``ExitTable`` holds: d_0 and one per vertex (the sampler pushes the direction that
    leaves at the last vertex too), so max_bounces + 1, at most LOCAL_CAPACITY + 1 (the default cap is
    LOCAL_CAPACITY). A longer walk ends where the table is full (only with a larger cap)."""
    if isinstance(max_bounces, int):
        return max(2, min(max_bounces, LOCAL_CAPACITY) + 1)
    return LOCAL_CAPACITY + 1


def diffuse_direction(mf, d):
    """(|Λ(d)|, d points down, usable) of a new direction (Rust ``lam``: not horizontal, finite Λ)."""
    l = mf.abs_lambda(d)
    ok = dr.all(dr.isfinite(d)) & (d[2] != 0.0) & dr.isfinite(l)
    return l, d[2] < 0.0, ok


def diffuse_eval(mf, albedo, wi, wo, max_bounces, key):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o on Lambertian facets (Rust ``general::eval``): the
    phase-function walk (visible normal m of −d_m, cosine lobe about m); at each vertex the next event
    (a/π)⟨ω_o, m⟩⁺ with the same m times the exact conditional exit probability p_exit(d_0..d_m, ω_o)/H_m;
    the throughput carries Π a · H_m/H_0 and Russian roulette from the second vertex on."""
    last = max_bounces
    capacity = table_capacity(last)
    lambda_o = mf.lambda_(wo)
    l0 = mf.abs_lambda(-wi)
    start = (valid_direction(wi) & valid_direction(wo) & dr.isfinite(lambda_o) & dr.isfinite(l0)
             & (last > 0))
    table0 = ExitTable.new(l0, capacity)

    def body(j, w, thr, result, active, counter, table_state):
        rng = Stream(key, counter)
        table = ExitTable.from_state(table_state, capacity)
        order = j + 1
        u1, u2 = rng.next2()
        m, valid = mf.sample_visible(w, u1, u2)
        active &= valid
        c = dot(wo, m)
        nee = active & (c > 0.0)
        exit = table.exit_given_hits(lambda_o, nee)
        result = dr.select(nee & (exit > 0.0), result + thr * albedo * (c * INV_PI * exit), result)
        active &= order < last
        u_rr, _ = rng.next2()
        thr, alive = walk.roulette_from(j >= RR_START, thr, u_rr)
        active &= alive
        u3, u4 = rng.next2()
        d = walk.cosine_about(m, u3, u4)
        l, down, ok = diffuse_direction(mf, d)
        active &= ok
        thr = thr * albedo
        cont, pushed = table.push(l, down, active)
        thr = dr.select(active, thr * cont, thr)
        active &= pushed & (cont > 0.0) & (max_channel(thr) > 0.0)
        return j + 1, -d, thr, result, active, rng.counter, table.state()

    state = (mi.UInt32(0), mi.Vector3f(wi), mi.Spectrum(1.0), dr.zeros(mi.Spectrum), mi.Bool(start),
             mi.UInt32(0), table0.state())
    state = dr.while_loop(state, lambda *s: s[4], body, label="msx_invariance_diffuse_eval")
    return state[3]


def diffuse_sample(mf, albedo, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling on Lambertian facets (Rust ``general::sample``): phase-function directions,
    and at each upward d_{m+1} exit with probability 1 − H_{m+1}/H_m. (sample1, u1, u2) drive the first
    vertex's exit decision and visible normal, the lane's stream the cosine lobes and the rest. Returns
    (ω_o, weight = Π albedo, valid); more than max_bounces vertices is invalid."""
    last = max_bounces
    capacity = table_capacity(last)
    l0 = mf.abs_lambda(-wi)
    start = valid_direction(wi) & dr.isfinite(l0) & (last > 0)

    table0 = ExitTable.new(l0, capacity)

    def body(j, w, weight, done, active, counter, u_exit, u1, u2, table_state):
        rng = Stream(key, counter)
        table = ExitTable.from_state(table_state, capacity)
        m, valid = mf.sample_visible(w, u1, u2)
        active &= valid
        u3, u4 = rng.next2()
        d = walk.cosine_about(m, u3, u4)
        l, down, ok = diffuse_direction(mf, d)
        active &= ok
        weight = weight * albedo
        cont, pushed = table.push(l, down, active)
        active &= pushed
        leaves = active & ~down & (u_exit >= cont)
        done = leaves
        active &= ~leaves & (cont > 0.0) & (j + 1 < last)
        a, b = rng.next2()
        c, _ = rng.next2()
        return j + 1, -d, weight, done, active, rng.counter, c, a, b, table.state()

    state = (mi.UInt32(0), mi.Vector3f(wi), mi.Spectrum(1.0), mi.Bool(False), mi.Bool(start), mi.UInt32(0),
             clean_uniform(mi.Float(sample1)), clean_uniform(mi.Float(u1)), clean_uniform(mi.Float(u2)),
             table0.state())
    state = dr.while_loop(state, lambda *s: s[4], body, label="msx_invariance_diffuse_sample")
    return -state[1], state[2], state[3]


# ------------------------------------------------------------------ dielectric (dielectric.rs)


class PieceChain:
    """The exact depth law of the current vertex of a monotone one-sided run entered from above (twin of
    ``PieceChain`` in ``dielectric.rs``), per lane in ``n`` registers unrolled at trace time (as
    ``MonotoneExit``): Python lists ``rates`` (L_i of the downward directions, slot i < a) and ``pi`` (π(c)
    up to the factor ``scale``; before the first upward direction π is the point mass on the bottom piece,
    not materialised), ``a`` (pieces), ``has_up``, ``hit`` (H_m). Pass :meth:`state` through the walk's
    loop and rebuild with :meth:`from_state`."""

    def __init__(self, rates, pi, a, has_up, scale, hit, unrolled=False):
        self.rates, self.pi = list(rates), list(pi)
        self.a, self.has_up, self.scale, self.hit = a, has_up, scale, hit
        self.n = len(self.rates)
        # How its passes are traced (``over_run``): a Python bool of the trace, not loop state.
        self.unrolled = unrolled

    @staticmethod
    def new(l0, n, unrolled=False):
        return PieceChain([mi.Float(l0)] + [mi.Float(1.0) for _ in range(n - 1)], [mi.Float(0.0) for _ in range(n)],
                          mi.UInt32(1), mi.Bool(False), mi.Float(1.0), mi.Float(1.0), unrolled)

    def state(self):
        return (self.rates, self.pi, self.a, self.has_up, self.scale, self.hit)

    @staticmethod
    def from_state(s, unrolled=False):
        return PieceChain(*s, unrolled=unrolled)

    def pi_at(self, c, on):
        """π(c) (normalised) of the slot c (a Python int) where ``on``."""
        point = dr.select(self.a == c + 1, 1.0, 0.0)
        return dr.select(on, dr.select(self.has_up, self.pi[c] * self.scale, point), 0.0)

    def push_down(self, l, active):
        """Appends a downward direction (|Λ| = ``l``) where ``active``; False on a non-monotone run or a
        full run (a = n): the walk ends there."""
        ok = active & ~self.has_up & (self.a < self.n)
        a = self.a

        def step(i, rates):
            if i == 0:
                return rates
            return rates[:i] + (dr.select(ok & (a == i), l, rates[i]),) + rates[i + 1:]

        self.rates = list(over_run(self.n, a + 1, step, tuple(self.rates), unrolled=self.unrolled))
        self.a = dr.select(ok, self.a + 1, self.a)
        return ok

    def push_up(self, lam, active):
        """Appends an upward direction with Λ = ``lam`` where ``active``; returns H_{m+1}/H_m (0 where not
        active). carry(c) = Σ_{c'' ≥ c} π(c'') Π_{i=c+1}^{c''} L_i/(L_i+Λ) is the mass whose jump reaches
        piece c; a fraction Λ/(L_c+Λ) lands there (Λ = ∞: everything lands where it is)."""
        inf = dr.isinf(lam)
        run = active & (lam > 0.0)

        def step(c, state):
            carry, cont, pi = state[0], state[1], state[2:]
            on = run & (self.a > c)
            if c + 1 < self.n:
                ln = self.rates[c + 1]
                carry = dr.select(on & (self.a > c + 1), carry * dr.select(inf, 0.0, ln / (ln + lam)), carry)
            carry = carry + self.pi_at(c, on)
            land = carry * dr.select(inf, 1.0, lam / (self.rates[c] + lam))
            return (carry, cont + dr.select(on, land, 0.0)) + pi[:c] + (dr.select(on, land, pi[c]),) + pi[c + 1:]

        out = over_run(self.n, self.a, step, (mi.Float(0.0), mi.Float(0.0)) + tuple(self.pi), unrolled=self.unrolled)
        cont, self.pi = out[1], list(out[2:])
        good = run & (cont > 0.0) & dr.isfinite(cont)
        self.scale = dr.select(good, 1.0 / cont, self.scale)
        self.has_up = self.has_up | active
        cont = dr.select(good, dr.minimum(cont, 1.0), 0.0)
        self.hit = dr.select(active, self.hit * cont, self.hit)
        return dr.select(active, cont, 0.0)

    def exit_given_hits(self, lam, active):
        """E[e^{−Λ τ}] given the hits: the probability of leaving along an upward direction with
        Λ = ``lam`` from the current vertex (0 where not active, Λ < 0 or ∞)."""
        run = active & (lam >= 0.0) & ~dr.isinf(lam)

        def step(c, carry):
            prod, total = carry
            on = run & (self.a > c)
            l = self.rates[c]
            prod = dr.select(on, prod * (l / (l + lam)), prod)
            return prod, total + self.pi_at(c, on) * prod

        _, total = over_run(self.n, self.a, step, (mi.Float(1.0), mi.Float(0.0)), reverse=False,
                            unrolled=self.unrolled)
        return dr.select(run, total, 0.0)


def draw_depth(chain, c_min, key, counter, active, traced=False):
    """τ of ``PieceChain.sample_depth``: the piece c ≥ c_min from π (one number), then τ = X_0 + … + X_c
    with fresh X_i ~ Exp(L_i) (one number each; L = ∞ adds no depth). Returns (τ, mass Σ_{c ≥ c_min} π(c),
    counter, ratio). ``traced`` (docs/gradients.md): the draw is made with the chain's values detached and
    ``ratio`` is the density of the drawn (c, X_0..X_c) under the attached values over the detached one,
    (π(c)/π̄(c))·Π (L_i/L̄_i)·e^{−(L_i − L̄_i) X_i} — value 1, derivative the score (1 when not traced)."""

    def add_mass(c, carry):
        return (carry[0] + chain.pi_at(c, active & (chain.a > c)),) if c >= c_min else carry

    total, = over_run(chain.n, chain.a, add_mass, (mi.Float(0.0),), reverse=False, unrolled=chain.unrolled)
    rng = Stream(key, counter)
    u_pick, _ = rng.next2()

    def pick(c, carry):
        rest, tau, picking, counter, ratio, pi_picked = carry
        on = picking & (chain.a > c)
        rng = Stream(key, counter)
        u, _ = rng.next2()
        rate = chain.rates[c]
        if traced:
            drawn = dr.detach(rate)
            x = optical_depth(u) / drawn
            ok = on & dr.isfinite(drawn) & (drawn > 0.0)
            ratio = dr.select(ok, ratio * (rate / drawn) * dr.exp(-(rate - drawn) * x), ratio)
            tau = dr.select(on, tau + x, tau)
        else:
            tau = dr.select(on, tau + optical_depth(u) / rate, tau)
        if c >= c_min:
            pi_c = chain.pi_at(c, on)
            pi_picked = dr.select(on, pi_c, pi_picked)
            rest = dr.select(on, rest - dr.detach(pi_c), rest)
            picking &= ~(on & (rest < 0.0))
        return rest, tau, picking, dr.select(on, rng.counter, counter), ratio, pi_picked

    carry = (dr.detach(u_pick * total), mi.Float(0.0), mi.Bool(active), mi.UInt32(rng.counter), mi.Float(1.0),
             mi.Float(0.0))
    _, tau, _, counter, ratio, pi_picked = over_run(chain.n, chain.a, pick, carry, reverse=False,
                                                    unrolled=chain.unrolled)
    if traced:
        drawn = dr.detach(pi_picked)
        ratio = dr.select(drawn > 0.0, ratio * pi_picked / dr.select(drawn > 0.0, drawn, 1.0), ratio)
    return tau, total, counter, ratio


def transmit_exit(chain, lambda_t, key, counter, active, traced=False):
    """Unbiased estimate of E[(1 − e^{−τ})^{Λ'}] given the hits (Rust ``transmit_exit``): the top piece's
    mass exactly, π(0)·L_0·B(L_0, 1+Λ'), one depth drawn from the deeper pieces for the rest. Returns
    (estimate in [0, 1], counter). ``traced``: the deeper depth is drawn detached and weighed by its density
    ratio (``draw_depth``), so the estimate's derivative is unbiased."""
    run = active & (lambda_t >= 0.0) & ~dr.isinf(lambda_t)
    p0 = chain.pi_at(0, run)
    l0 = chain.rates[0]
    e = p0 * l_beta(l0, lambda_t)
    deeper = run & (chain.a > 1)
    tau, rest, counter, ratio = draw_depth(chain, 1, key, counter, deeper, traced)
    above = -expm1(-tau)  # 1 − e^{−τ}
    # Drawn from π restricted to c ≥ 1 (mass ``rest``): rest·g(τ); traced, r̄est·(π(c)/π̄(c))·…·g(τ).
    weight = dr.detach(rest) * ratio if traced else rest
    e = dr.select(deeper & (rest > 0.0), e + weight * dr.exp(lambda_t * dr.log(above)), e)
    e = dr.select(dr.isfinite(e), dr.clip(e, 0.0, 1.0), 0.0)
    return dr.select(run, e, 0.0), counter


def dielectric_valid(w, eta):
    return dr.all(dr.isfinite(w)) & (w[2] != 0.0) & dr.isfinite(eta) & (eta > 0.0)


# First counter of the numbers a differentiated first run's edge terms draw (``first_run_edge_terms``): far
# above any counter the walk's own stream reaches, so that the edge terms — computed only while η is
# differentiated — leave the walk's own numbers (and so its value) as they are without them.
EDGE_COUNTER_BASE = 1 << 24
EDGE_COUNTERS_PER_VERTEX = 128


def detached_chain(chain):
    """A detached copy of a ``PieceChain`` (its pushes leave ``chain`` as it is)."""
    rates, pi, a, has_up, scale, hit = chain.state()
    return PieceChain([dr.detach(r) for r in rates], [dr.detach(x) for x in pi], a, has_up, dr.detach(scale),
                      dr.detach(hit), chain.unrolled)


def first_run_edge_terms(mf, chain, w, eta_f, teta_f, outside, wo, lambda_o, key, j, active):
    """∂/∂η of the first run's next-event values along their moving edges (docs/gradients.md, "The IOR of
    the glass walks"), for both events of the vertex at w, with ``glass_traced.edge_point``: in the
    space of normals the one discontinuity that moves with η is the next vertex's value towards ω_o, which
    jumps to 0 on the circle w'_z = z*. A reflection keeps the first run's directions fixed in η (its tangent
    is 0), so only the circle moves, and only where ω_o is across (z* = −η_f o_z); its next vertex carries
    the run's hit probability of the new direction (``push_up``) and ω_o's exit probability given the hits
    (``transmit_exit``, one depth drawn) on a copy of the chain. A refraction's next vertex is the first of
    Heitz's walk, from the depth drawn from the chain's law (``draw_depth``): ``heitz.dielectric_edge_term``
    there. One uniform azimuth per event; its numbers come from counters of their own (EDGE_COUNTER_BASE).
    Everything is detached: the sum enters as (η − η̄)·terms."""
    base = mi.UInt32(EDGE_COUNTER_BASE) + j * EDGE_COUNTERS_PER_VERTEX
    rng = Stream(key, base)
    u_phi_r, u_phi_t = rng.next2()
    u_h, _ = rng.next2()
    chain = detached_chain(chain)
    # The refraction: the next vertex is Heitz's, from the depth drawn from the chain's law (flipped there).
    tau, _, counter, _ = draw_depth(chain, 0, key, rng.counter, active)
    tw0 = mi.Vector3f(0.0)
    refracted = heitz.dielectric_edge_term(mf, w, tw0, -tau, outside, eta_f, teta_f, wo, lambda_o, True,
                                           u_phi_t, u_h)
    # The reflection: its direction has no tangent, so only where ω_o is across does its circle move.
    o = dr.select(outside, wo, -wo)
    w_next, transmit, density, value, speed, ok = edge_point(mf, w, tw0, o, eta_f, teta_f, False, u_phi_r)
    ok &= active & transmit
    d = -w_next
    up = d[2] > 0.0
    copy_ = detached_chain(chain)
    cont = copy_.push_up(mf.lambda_(d), ok & up)
    pushed = copy_.push_down(mf.abs_lambda(d), ok & ~up)
    ok &= dr.select(up, cont > 0.0, pushed)
    exit_t, _ = transmit_exit(copy_, lambda_o, key, counter, ok)
    area = mf.projected_area(w_next)
    value = value * dr.abs(w_next[2]) / dr.select(area > 0.0, area, 1.0)
    reflected = 2.0 * math.pi * density * dr.select(up, cont, 1.0) * exit_t * value * speed
    reflected = dr.select(ok & (area > 0.0) & dr.isfinite(reflected), reflected, 0.0)
    return dr.select(active, refracted + reflected, 0.0)


def dielectric_eval(mf, eta, radiance, wi, wo, max_bounces, key, mf_sample=None):
    """One unbiased estimate of f(ω_i, ω_o)·|cos θ_o| of the rough dielectric with the heights of the
    first run integrated out (Rust ``dielectric::eval``), one channel. The first run (reflections in ω_i's
    medium) draws visible normals, reflects with probability F, carries the exact hit probabilities and
    estimates towards ω_o at every vertex with the phase function × the exact exit probability
    (``exit_given_hits`` on ω_i's side, ``transmit_exit`` across); at the first refraction the vertex
    depth is drawn from its exact law, flipped, and Heitz's walk (``heitz.dielectric_eval_from``) carries
    the rest of the path. Radiance mode: × 1/η_r² when ω_o is across.

    ``mf_sample`` (docs/gradients.md, "The IOR of the glass walks"): the statistics with their derivatives
    detached (η too). The normals and the reflect-or-refract choices are then drawn from them in the space of
    normals (``glass_traced.scatter_traced``: their density ratios in the weight; a refracted direction moves
    with η and hands its tangent to Heitz's walk), the depth at the refraction from the run's detached law
    with its ``draw_depth`` ratio, the next event's sampled depth likewise; the exit and hit probabilities
    are attached, the roulette detached with a floor; while η is differentiated each vertex adds its edge
    terms (``first_run_edge_terms``). The differentiated values travel in the loop's state."""
    traced = mf_sample is not None
    last = max_bounces
    slots = run_slots(last, DIELECTRIC_RUN_SLOTS)
    eta = mi.Float(eta)
    eta_traced = traced and dr.grad_enabled(eta)  # the edge terms are derivatives in η only
    wi, wo = mi.Vector3f(wi), mi.Vector3f(wo)
    outside = wi[2] > 0.0
    same = (wo[2] > 0.0) == outside
    e = eta_seen(eta, outside)
    wo_l = dr.select(outside, wo, -wo)
    lambda_o = mf.lambda_(dr.select(same, wo_l, -wo_l))
    w0 = dr.select(outside, wi, -wi)
    l0 = mf.abs_lambda(-w0)
    start = (dielectric_valid(wi, eta) & dielectric_valid(wo, eta) & dr.isfinite(lambda_o) & dr.isfinite(l0)
             & (last > 0))
    chain0 = PieceChain.new(l0, slots, unrolled=traced)

    def body(j, w, thr, result, active, counter, refracted, h_dir, h_t, chain_state, *piped):
        mfa, mfs, lo, ea, es = mf, mf, lambda_o, e, e
        if traced:  # the differentiated values come through the state
            lv = LoopValues(mf.dist, piped)
            mfa, mfs, lo, (eta_a, h_tw) = lv.mf, lv.mf_sample, lv.lambda_o, lv.rest
            ea = eta_seen(eta_a, outside)
            es = dr.detach(ea)
        chain = PieceChain.from_state(chain_state, chain0.unrolled)
        order = j + 1
        # Next-event estimation: phase function × exact exit probability.
        phase = dr.select(same, heitz.dielectric_phase_reflect(mfa, w, wo_l, ea),
                          heitz.dielectric_phase_transmit(mfa, w, wo_l, ea))
        nee = active & (phase > 0.0)
        exit_r = chain.exit_given_hits(lo, nee & same)
        exit_t, counter = transmit_exit(chain, lo, key, counter, nee & ~same, traced)
        result = dr.select(nee, result + thr * phase * dr.select(same, exit_r, exit_t), result)
        active &= order < last
        rng = Stream(key, counter)
        u_rr, u_f = rng.next2()
        thr, alive = walk.roulette_from(j >= RR_START, thr, u_rr, 1.0, RR_TRACED_FLOOR if traced else 0.0)
        active &= alive
        # Scatter: visible normal, reflect with probability F.
        u1, u2 = rng.next2()
        if traced:
            # In the space of normals (glass_traced.scatter_traced): a reflection does not move with η, a
            # refraction's direction does (its tangent goes to Heitz's walk with it).
            u_mix, _ = rng.next2()
            d_new, refr, _, valid, weight, m = scatter_traced(mfa, mfs, w, mi.Float(1.0), ea, u_f, u1, u2, u_mix)
            active &= valid
            refr &= active
            teta = dr.select(outside, 1.0, -es * es)
            if eta_traced:
                edge = first_run_edge_terms(mfs, chain, w, es, teta, outside, wo, dr.detach(lo), key, j, active)
                result = dr.select(active, result + (eta_a - dr.detach(eta_a)) * dr.detach(thr) * edge, result)
            o = -d_new
            d = d_new
            h_tw = dr.select(refr, eta_tangent_step(w, mi.Vector3f(0.0), m, es, teta, refr), h_tw)
        else:
            m, cos_wm, valid = heitz.visible_normal(mfs, w, u1, u2)
            active &= valid
            o, d, crossed = reflect_or_refract_unit(w, m, cos_wm, es, u_f)
            refr = active & crossed
        tau, _, counter, depth_ratio = draw_depth(chain, 0, key, rng.counter, refr, traced)
        if traced:
            thr = dr.select(active, thr * weight * dr.select(refr, depth_ratio, 1.0), thr)
        refracted = refracted | refr
        h_dir = dr.select(refr, -o, h_dir)
        h_t = dr.select(refr, heitz.flip_height(-tau), h_t)
        active &= ~refr
        # Reflect, and extend the run's exit table.
        active &= dr.all(dr.isfinite(d)) & (d[2] != 0.0)
        up = d[2] > 0.0
        lam = mfa.lambda_(d)
        active &= ~(up & dr.isnan(lam))
        cont = chain.push_up(lam, active & up)
        thr = dr.select(active & up, thr * cont, thr)
        active &= ~up | (cont > 0.0)
        l = mfa.abs_lambda(d)
        pushed = chain.push_down(l, active & ~up & dr.isfinite(l))
        active &= up | pushed
        if traced:
            piped = lv.piped(eta_a, h_tw)
        return (j + 1, -d, thr, result, active, counter, refracted, h_dir, h_t, chain.state()) + piped

    state = (mi.UInt32(0), mi.Vector3f(w0), mi.Float(1.0), mi.Float(0.0), mi.Bool(start), mi.UInt32(0),
             mi.Bool(False), mi.Vector3f(0.0, 0.0, 1.0), mi.Float(0.0), chain0.state())
    if traced:
        state += (mi.Float(mf.alpha_u), mi.Float(mf.alpha_v), mi.Float(lambda_o), mi.Float(eta), mi.Vector3f(0.0))
    out = dr.while_loop(state, lambda *s: s[4], body, label="msx_invariance_dielectric_eval")
    j, _, thr, result, _, counter, refracted, h_dir, h_t, _ = out[:10]
    # The rest of the refracted paths: Heitz's walk from the vertex after the refraction (order j + 1), with
    # the refracted direction's tangent in η.
    rest = heitz.dielectric_eval_from(mf, eta, wo, h_dir, h_t, ~outside, j + 1, thr, refracted, last, key,
                                      counter, mf_sample=mf_sample, tw=out[14] if traced else None)
    v = (result + dr.select(refracted, rest, 0.0)) * radiance_scale(eta, radiance, outside, wo[2] > 0.0)
    return dr.select(dr.isfinite(v) & (v > 0.0), v, 0.0)


def dielectric_sample(mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling with the heights of the first run integrated out (Rust
    ``dielectric::sample``): leave along an upward direction with the exact conditional exit probability;
    at the first refraction draw the vertex depth from its exact law and continue with Heitz's walk
    (``heitz.sample_from``). (sample1, u1, u2) drive the first vertex (Fresnel choice, visible
    normal). Returns (ω_o, weight = 1, × 1/η_r² for a Radiance-mode transmission, valid)."""
    last = max_bounces
    slots = run_slots(last, DIELECTRIC_RUN_SLOTS)
    eta = mi.Float(eta)
    wi = mi.Vector3f(wi)
    outside = wi[2] > 0.0
    e = eta_seen(eta, outside)
    w0 = dr.select(outside, wi, -wi)
    l0 = mf.abs_lambda(-w0)
    start = dielectric_valid(wi, eta) & dr.isfinite(l0) & (last > 0)
    chain0 = PieceChain.new(l0, slots)

    def body(j, w, done, active, counter, ua, u1, u2, refracted, h_dir, h_t, chain_state):
        chain = PieceChain.from_state(chain_state)
        m, cos_wm, valid = heitz.visible_normal(mf, w, u1, u2)
        active &= valid
        o, d, crossed = reflect_or_refract_unit(w, m, cos_wm, e, ua)
        refr = active & crossed
        tau, _, counter, _ = draw_depth(chain, 0, key, counter, refr)
        refracted = refracted | refr
        h_dir = dr.select(refr, -o, h_dir)
        h_t = dr.select(refr, heitz.flip_height(-tau), h_t)
        active &= ~refr
        active &= dr.all(dr.isfinite(d)) & (d[2] != 0.0)
        up = d[2] > 0.0
        lam = mf.lambda_(d)
        active &= ~(up & dr.isnan(lam))
        cont = chain.push_up(lam, active & up)
        rng = Stream(key, counter)
        u_exit, c = rng.next2()
        leaves = active & up & (u_exit >= cont)
        done = leaves
        l = mf.abs_lambda(d)
        pushed = chain.push_down(l, active & ~up & dr.isfinite(l))
        active &= (up & ~leaves) | pushed
        active &= j + 1 < last
        a, b = rng.next2()
        return j + 1, -d, done, active, rng.counter, c, a, b, refracted, h_dir, h_t, chain.state()

    state = (mi.UInt32(0), mi.Vector3f(w0), mi.Bool(False), mi.Bool(start), mi.UInt32(0),
             clean_uniform(mi.Float(sample1)), clean_uniform(mi.Float(u1)), clean_uniform(mi.Float(u2)), mi.Bool(False),
             mi.Vector3f(0.0, 0.0, 1.0), mi.Float(0.0), chain0.state())
    j, w, done, _, counter, _, _, _, refracted, h_dir, h_t, _ = dr.while_loop(
        state, lambda *s: s[3], body, label="msx_invariance_dielectric_sample")
    wo_run = -dr.select(outside, w, -w)  # the run's exit direction d in the macro frame
    # Refracted paths: the next height from the flipped one, then Heitz's walk (the refraction was
    # vertex j; leaving at once exits along the refracted direction).
    rng = Stream(key, counter)
    u_h, u_a = rng.next2()
    a, b = rng.next2()
    t1, hit1 = heitz.sample_height(mf, h_dir, h_t, u_h)
    inside_now = ~outside
    leave_now = refracted & ~hit1
    wo_h, _, done_h = heitz.sample_from(mf, heitz.DielectricFacets(eta), h_dir, t1, inside_now, j, mi.Float(1.0),
                                        refracted & hit1, last, key, rng.counter, (u_a, a, b))
    wo_now = dr.select(inside_now, h_dir, -h_dir)
    wo = dr.select(refracted, dr.select(leave_now, wo_now, wo_h), wo_run)
    valid = dr.select(refracted, dr.select(leave_now, mi.Bool(True), done_h), done)
    valid &= dr.all(dr.isfinite(wo)) & (wo[2] != 0.0)
    return wo, radiance_scale(eta, radiance, outside, wo[2] > 0.0), valid


# The conductor walk this module provides (jit/bsdf.py collects it): height-correlated order-1 exit in
# the MIS density, and no walk from below the macro surface (the core's eval and sample need ω_i up).
CONDUCTOR_WALKS = {"invariance": ConductorWalk(eval, sample, mis.HEIGHT_CORRELATED, below=False,
                                              eval_bdpt=eval_bdpt, differentiable=True)}
# The walks on the other microsurfaces (MIS densities: ``mis.diffuse_pdf``, ``mis.dielectric_pdf``).
DIFFUSE_WALKS = {"invariance": DiffuseWalk(diffuse_eval, diffuse_sample)}
DIELECTRIC_WALKS = {"invariance": DielectricWalk(dielectric_eval, dielectric_sample, differentiable=True,
                                                 eta_differentiable=True)}

# The Lambertian walk keeps its O(m²) table in ``dr.alloc_local``, which drjit 1.5's LLVM backend cannot
# compile inside a symbolic call — and Mitsuba calls every BSDF through one (docs/engines.md): jit/bsdf.py
# refuses it in scenes. It runs, and is tested against the core, when called directly (python_tests/). The
# conductor and dielectric walks keep their run in registers and render.
for _walk in DIFFUSE_WALKS.values():
    _walk.needs_local_arrays = True
