"""The invariance principle (Cui et al. 2023, with Bitterli & d'Eon 2022's exit probability) on conductor
facets in the Dr.Jit engine: twin of ``src/models/invariance/conductor.rs`` (``eval``, ``sample``) with the
incremental exit table ``MonotoneExit`` of ``recursion.rs``. The BDPT estimator and the dielectric and
diffuse microsurfaces are not ported.

Heitz's walk with the heights integrated out: a conductor path is a run of a ≥ 1 downward directions
d_0..d_{a−1} followed by upward ones, and the probability that it hits at every vertex and leaves along an
upward x is a column recursion over the downward run (``recursion.rs``, "Monotone paths"). Its state is
the |Λ| of the downward directions and one value g_i per downward direction: a per-path array whose length
is the length of the downward run. Here it lives in two ``dr.alloc_local`` buffers of ``capacity``
entries (the walk's bounce cap, at most ``LOCAL_CAPACITY``) plus the run length a; the O(a) column passes
are inner ``dr.while_loop``s. Up to that capacity the state is the core's, exactly; a path whose downward
run would exceed it ends there (only with max_bounces > LOCAL_CAPACITY, and such a run of downward
reflections has a negligible probability).

The normalisation of g by the hit probability (the core's ``g ← g/cont`` after each upward direction) is
carried as one scale factor instead of a second pass over the buffer.

``eval``: visible-normal walk with NEE towards ω_o weighed by the exit probability given the hits, the
connection strategy (a one-vertex light subpath y from the side of ω_o) for orders 2 and 3 with the
balance heuristic, Russian roulette with sure survival above ``RR_KEEP``, and the exact stop once an
upward direction is at least as steep as ω_o. ``sample``: the same walk leaving at each upward direction
with probability 1 − H_m/H_{m−1}; the weight is the product of the Fresnel terms.
"""

import drjit as dr
import mitsuba as mi

from . import mis, walk
from .microfacet import dot, max_channel, reflect
from .model import ConductorWalk
from .rng import Stream

# src/models/invariance/conductor.rs: where roulette starts, its sure-survival level, and the highest
# order the connection strategy serves.
RR_START = 1
RR_KEEP = 0.5
CONNECT_MAX_ORDER = 3

# Largest downward run the local buffers hold (their size is the bounce cap when that is smaller).
LOCAL_CAPACITY = 64

ONE_MINUS = 0.99999994  # largest float32 below 1


# ------------------------------------------------------------------ the exit table (recursion.rs)


class MonotoneExit:
    """Incremental exit probabilities of a monotone path d_0..d_m (twin of ``MonotoneExit``), per lane:
    ``down`` (Local, |Λ| of the downward directions), ``g`` (Local, the column's second term up to the
    factor ``scale``), ``a`` (the number of downward directions), ``has_up`` (an upward direction was
    pushed). Pass :meth:`state` through the walk's loop and rebuild with :meth:`from_state`."""

    def __init__(self, down, g, a, has_up, scale, capacity):
        self.down, self.g, self.a, self.has_up, self.scale, self.capacity = down, g, a, has_up, scale, capacity

    @staticmethod
    def new(l0, capacity):
        """A path starting with d_0 (downward) of |Λ(d_0)| = ``l0``."""
        down = dr.alloc_local(mi.Float, capacity, mi.Float(0.0))
        g = dr.alloc_local(mi.Float, capacity, mi.Float(0.0))
        down.write(mi.Float(l0), mi.UInt32(0))
        return MonotoneExit(down, g, mi.UInt32(1), mi.Bool(False), mi.Float(1.0), capacity)

    def state(self):
        return (self.down, self.g, self.a, self.has_up, self.scale)

    @staticmethod
    def from_state(s, capacity):
        return MonotoneExit(*s, capacity)

    def push_down(self, l, active):
        """Appends a downward direction of |Λ| = ``l`` where ``active``; False on a non-monotone path (or
        a full buffer), which ends the walk."""
        ok = active & ~self.has_up & (self.a < self.capacity)
        self.down.write(mi.Float(l), dr.select(ok, self.a, 0), ok)
        self.a = dr.select(ok, self.a + 1, self.a)
        return ok

    def columns(self, lambda_x, lambda_y, active):
        """One pass over the downward run: (column(Λ_x), exit_via_up(Λ_y, Λ_x)), i.e. p_exit(d_0..d_m, x)/H_m
        and p_exit(d_0..d_m, y, x)/H_m for virtual upward x, y (``exit_given_hits``, ``exit_via_up``)."""
        has_up, scale, down, g = self.has_up, self.scale, self.down, self.g
        init_c = dr.select(has_up, 0.0, 1.0)

        # Every access to the local buffers names its lanes: a lane whose pass is over would otherwise go
        # on to index 2^32 − 1 while the others finish theirs (it corrupted the buffers in symbolic loops).
        def body(i, c, c_y, c_x):
            on = active & (i > 0)
            i = dr.select(on, i - 1, 0)
            li = down.read(i, on)
            gi = dr.select(has_up, g.read(i, on) * scale, 0.0)
            c = (li * c + gi) / (li + lambda_x)
            c_y = (li * c_y + gi) / (li + lambda_y)
            c_x = (li * c_x + lambda_y * c_y) / (li + lambda_x)
            return i, c, c_y, c_x

        state = (mi.UInt32(self.a), mi.Float(init_c), mi.Float(init_c), mi.Float(0.0))
        _, c, _, c_x = dr.while_loop(state, lambda i, *_: active & (i > 0), body, label="msx_invariance_columns")
        return c, c_x

    def push_up(self, lam, active):
        """Appends an upward direction with Λ = ``lam`` where ``active``; returns H_{m+1}/H_m, the
        probability that it hits the surface again (0 where not active)."""
        has_up, scale, down, g = self.has_up, self.scale, self.down, self.g

        def body(i, c, cont):  # masked accesses: see ``columns``
            on = active & (i > 0)
            i = dr.select(on, i - 1, 0)
            li = down.read(i, on)
            gi = dr.select(has_up, g.read(i, on) * scale, 0.0)
            c = (li * c + gi) / (li + lam)
            g_new = lam * c
            g.write(g_new, i, on)
            return i, c, cont + g_new / li

        state = (mi.UInt32(self.a), mi.Float(dr.select(has_up, 0.0, 1.0)), mi.Float(0.0))
        _, _, cont = dr.while_loop(state, lambda i, *_: active & (i > 0), body, label="msx_invariance_push_up")
        good = (cont > 0.0) & dr.isfinite(cont)
        self.scale = dr.select(active, dr.select(good, 1.0 / cont, 0.0), self.scale)
        self.has_up = self.has_up | active
        return dr.select(active, cont, 0.0)


# ------------------------------------------------------------------ helpers


def half_vector_d(mf, w, x):
    """(D(h), w·h) for the half vector h of w and x; (0, 0) where w does not see h."""
    h = w + x
    length = dr.norm(h)
    h = h / length
    c = dot(w, h)
    ok = (length > 0.0) & (c > 0.0)
    return dr.select(ok, mf.d(h), 0.0), dr.select(ok, c, 0.0)


def valid_direction(w):
    return dr.all(dr.isfinite(w)) & (w[2] > 0.0)


def capacity_of(max_bounces):
    """The size of the local buffers: the bounce cap (a path has at most that many downward directions),
    at most LOCAL_CAPACITY; LOCAL_CAPACITY when the cap is per lane."""
    if isinstance(max_bounces, int):
        return max(1, min(max_bounces, LOCAL_CAPACITY))
    return LOCAL_CAPACITY


class LightVertex:
    """The connection's one-vertex light subpath: y = −(ω_o reflected about a visible normal of ω_o)
    (twin of ``LightVertex``)."""

    def __init__(self, mf, fresnel, wo, pdf_scale_o, u1, u2):
        m, valid = mf.sample_visible(wo, u1, u2)
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

    def connect(self, mf, fresnel, has_up, w, pdf_scale, via_up, column_ly_o):
        """The connection estimate at the vertex (w = −d_m): ``via_up`` = p_exit(.., y, ω_o)/H_m for an
        upward y, ``column_ly_o`` = column(Λ_o) for the downward case (the caller's one pass)."""
        d_h, cos0 = half_vector_d(mf, w, self.y)
        p_fwd = d_h * pdf_scale
        ok = self.valid & (p_fwd > 0.0) & dr.isfinite(p_fwd)
        via_down = dr.select(has_up, 0.0, self.l_y / (self.l_y + self.lambda_o) * column_ly_o)
        exit = dr.select(self.up, via_up, via_down)
        value = p_fwd * self.phase * exit / (p_fwd + self.pdf)
        ok &= (value > 0.0) & dr.isfinite(value)
        return dr.select(ok, fresnel.eval(cos0) * self.fresnel * value, 0.0)


# ------------------------------------------------------------------ the walks


def eval(mf, fresnel, wi, wo, max_bounces, key):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o, orders 1..max_bounces (Rust ``eval`` and
    ``Walk::from``)."""
    last = max_bounces  # a Python int, or a UInt32 per lane
    capacity = capacity_of(last)
    lambda_o = mf.lambda_(wo)
    start = valid_direction(wi) & valid_direction(wo) & dr.isfinite(lambda_o) & (last > 0)
    pdf_scale_o = 0.25 / (wo[2] * (1.0 + lambda_o))
    connects = not isinstance(last, int) or last >= 2  # per lane: masked by order < last below
    rng0 = Stream(key)
    if connects:
        u1, u2 = rng0.next2()
        light = LightVertex(mf, fresnel, wo, pdf_scale_o, u1, u2)
        light.lambda_o = lambda_o
    l0 = mf.abs_lambda(-wi)
    dp0 = MonotoneExit.new(l0, capacity)

    def body(j, w, pdf_scale, pdf_walk, thr, result, active, counter, dp_state):
        rng = Stream(key, counter)
        dp = MonotoneExit.from_state(dp_state, capacity)
        order = j + 1
        # NEE: D(h)/(4 A(w)) · F · p_exit(d_0..d_m, ω_o)/H_m, with the balance heuristic against the
        # connection for orders 2..CONNECT_MAX_ORDER.
        d_h, cos_wh = half_vector_d(mf, w, wo)
        value = d_h * pdf_scale
        lambda_y = light.l_y if connects else mi.Float(0.0)
        col_o, via_up = dp.columns(lambda_o, lambda_y, active)
        mis_w = (j > 0) & (order <= CONNECT_MAX_ORDER) & (value > 0.0)
        p_rev = d_h * pdf_scale_o
        value = dr.select(mis_w, value * (pdf_walk / (pdf_walk + p_rev)), value)
        ok = (value > 0.0) & dr.isfinite(value)
        result = dr.select(active & ok, result + thr * fresnel.eval(cos_wh) * (value * col_o), result)
        active &= order < last
        # The connection for order + 1: d_{m+1} = y from the side of ω_o.
        if connects:
            conn = light.connect(mf, fresnel, dp.has_up, w, pdf_scale, via_up, col_o)
            conn_on = active & (order < CONNECT_MAX_ORDER)
            result = dr.select(conn_on, result + thr * conn, result)
        # Russian roulette on Π F · H_m, after the vertex's estimates.
        u_rr, _ = rng.next2()
        kept, survived = walk.russian_roulette_keep(thr, u_rr, RR_KEEP)
        play = j >= RR_START
        thr = dr.select(play, kept, thr)
        active &= ~play | survived
        # The next direction.
        u1, u2 = rng.next2()
        m, valid = mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        active &= valid & (cos_wm > 0.0)
        d_next = reflect(w, m)
        up = d_next[2] > 0.0
        # Along the upward run z only grows: once an upward d.z ≥ ω_o.z no later vertex reaches ω_o.
        active &= ~(up & (d_next[2] >= wo[2]))
        thr = thr * fresnel.eval(cos_wm)
        pdf_walk = dr.select(order < CONNECT_MAX_ORDER, mf.d(m) * pdf_scale, pdf_walk)
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
        return j + 1, w, pdf_scale, pdf_walk, thr, result, active, rng.counter, dp.state()

    state = (mi.UInt32(0), mi.Vector3f(wi), 0.25 / (wi[2] * l0), mi.Float(0.0), mi.Spectrum(1.0),
             dr.zeros(mi.Spectrum), mi.Bool(start), mi.UInt32(rng0.counter), dp0.state())
    state = dr.while_loop(state, lambda *s: s[6], body, label="msx_invariance_conductor_eval")
    return state[5]


def sample(mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling (Rust ``sample``): reflect about visible normals and, at each upward
    direction, leave with probability 1 − H_m/H_{m−1}. (sample1, u1, u2) drive the first vertex, the
    lane's stream the rest. Returns (ω_o, weight = Π F, valid); more than max_bounces vertices is invalid."""
    last = max_bounces  # a Python int, or a UInt32 per lane
    capacity = capacity_of(last)
    start = valid_direction(wi) & (last > 0)

    def clean(u):
        return dr.clip(dr.select(dr.isfinite(u), u, 0.5), 0.0, ONE_MINUS)

    dp0 = MonotoneExit.new(mf.abs_lambda(-wi), capacity)

    def body(j, w, weight, done, active, counter, u_exit, u1, u2, dp_state):
        rng = Stream(key, counter)
        dp = MonotoneExit.from_state(dp_state, capacity)
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
             clean(mi.Float(sample1)), clean(mi.Float(u1)), clean(mi.Float(u2)), dp0.state())
    state = dr.while_loop(state, lambda *s: s[4], body, label="msx_invariance_conductor_sample")
    return -state[1], state[2], state[3]


# The conductor walk this module provides (jit/bsdf.py collects it): height-correlated order-1 exit in
# the MIS density, and no walk from below the macro surface (the core's eval and sample need ω_i up).
CONDUCTOR_WALKS = {"invariance": ConductorWalk(eval, sample, mis.HEIGHT_CORRELATED, below=False)}
