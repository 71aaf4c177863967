"""The invariance principle on Lambertian facets (Cui et al. 2023) in the Dr.Jit engine: twin of
``src/models/invariance/general.rs``. Their paths are not monotone in z, so the exit probabilities need the
whole triangle p(i, j) of ``ExitTable`` (O(m²) per lane): it lives in a ``dr.alloc_local`` buffer of
(m+1)(m+2)/2 entries for m = the bounce cap (at most ``LOCAL_CAPACITY``; a walk whose table is full ends
there, only with a larger cap), and a new column is two nested ``dr.while_loop``s.

drjit 1.5's LLVM backend cannot compile a local array inside a symbolic call, and Mitsuba calls every BSDF
through one (docs/engines.md): jit/bsdf.py refuses these walks in scenes. They run, and are tested against
the core, when called directly (python_tests/).
"""

import drjit as dr
import mitsuba as mi

from . import walk
from .invariance_conductor import valid_direction
from .microfacet import INV_PI, dot, max_channel
from .rng import Stream

# Largest table of the Lambertian walk's local buffers (their size is the bounce cap when that is smaller).
LOCAL_CAPACITY = 64


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


def scatter(mf, table, m, active, rng):
    """The phase function's new direction d about the visible normal ``m`` (a cosine lobe, two numbers of the
    lane's stream), appended to the exit table where ``active`` (and usable): (d, d points down,
    H_{m+1}/H_m, pushed, active)."""
    u3, u4 = rng.next2()
    d = walk.cosine_about(m, u3, u4)
    l, down, ok = diffuse_direction(mf, d)
    active &= ok
    cont, pushed = table.push(l, down, active)
    return d, down, cont, pushed, active


def eval(mf, albedo, wi, wo, max_bounces, key):
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
        thr, alive = walk.roulette_from(j >= walk.RR_START, thr, u_rr)
        active &= alive
        d, down, cont, pushed, active = scatter(mf, table, m, active, rng)
        thr = thr * albedo
        thr = dr.select(active, thr * cont, thr)
        active &= pushed & (cont > 0.0) & (max_channel(thr) > 0.0)
        return dict(j=j + 1, w=-d, thr=thr, result=result, active=active, counter=rng.counter,
                    table_state=table.state())

    state = dict(j=mi.UInt32(0), w=mi.Vector3f(wi), thr=mi.Spectrum(1.0), result=dr.zeros(mi.Spectrum),
                 active=mi.Bool(start), counter=mi.UInt32(0), table_state=table0.state())
    return walk.while_loop(state, body, label="msx_invariance_diffuse_eval")["result"]


def sample(mf, albedo, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling on Lambertian facets (Rust ``general::sample``): phase-function directions,
    and at each upward d_{m+1} exit with probability 1 − H_{m+1}/H_m. (sample1, u1, u2) drive the first
    vertex's exit decision and visible normal, the lane's stream the cosine lobes and the rest. Returns
    (ω_o, weight = Π albedo, valid); more than max_bounces vertices is invalid."""
    capacity = table_capacity(max_bounces)
    l0 = mf.abs_lambda(-wi)
    start = valid_direction(wi) & dr.isfinite(l0) & (max_bounces > 0)

    def vertex(w, weight, u, table_state, rng, active):
        u_exit, u1, u2 = u
        table = ExitTable.from_state(table_state, capacity)
        m, valid = mf.sample_visible(w, u1, u2)
        active &= valid
        d, down, cont, pushed, active = scatter(mf, table, m, active, rng)
        weight = weight * albedo
        active &= pushed
        leaves = active & ~down & (u_exit >= cont)
        active &= ~leaves & (cont > 0.0)
        return d, weight, leaves, active, table.state()

    table0 = ExitTable.new(l0, capacity)
    return walk.sample_walk(wi, (sample1, u1, u2), start, table0.state(), vertex, max_bounces, key, mi.Spectrum(1.0),
                            label="msx_invariance_diffuse_sample")
