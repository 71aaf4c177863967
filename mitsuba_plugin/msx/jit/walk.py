"""What every random walk of the Dr.Jit engine shares: twin of ``src/walk/mod.rs``."""

import math

import drjit as dr
import mitsuba as mi

from .microfacet import max_channel
from .rng import Stream, clean_uniform

# src/walk/mod.rs: the first vertex (0-based) at which a walk plays Russian roulette.
RR_START = 1


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


def carries_gradients(mf, *values):
    """Whether the statistics ``mf`` or one of ``values`` carries derivatives (a Python bool of the trace):
    a walk's loop then takes them through its state. Read from outside the loop inside a symbolic call,
    drjit 1.5 refuses them (``ad_traverse … isolate_grad``) or drops their derivative (measured: the traced
    ``sample`` weight's derivative in a conductor's η was 0 on every lane)."""
    return any(dr.grad_enabled(v) for v in (mf.alpha_u, mf.alpha_v) + values)


def while_loop(state, body, label, cond="active"):
    """``dr.while_loop`` over named state, the role of Mitsuba's ``DRJIT_STRUCT`` loop records: ``state``
    maps names to values (arrays, or lists and tuples of them); ``body`` is called with them as keyword
    arguments and returns the next state as a dict of the same names; the loop runs on the lanes where the
    entry ``cond`` is True. Returns the final state as a dict. An entry that is added, dropped or misspelt
    on one side fails when the kernel is traced, instead of shifting the positions of the others."""
    names = list(state)

    def step(s):
        new = body(**s)
        if set(new) != set(names):
            raise KeyError("%s: the loop body returns %s, the state is %s" % (label, sorted(new), sorted(names)))
        return ({k: new[k] for k in names},)

    return dr.while_loop(({k: state[k] for k in names},), lambda s: s[cond], step, label=label)[0]


def vertex_numbers(rng):
    """The (u_choice, u1, u2) of the next vertex of a sampled walk from the lane's stream (twin of
    ``vertex_numbers`` after the first vertex, whose numbers are the caller's): two numbers for (u1, u2),
    then one for the choice (the exit decision, or a dielectric's reflect-or-refract)."""
    a, b = rng.next2()
    c, _ = rng.next2()
    return c, a, b


def sample_walk(wi, first, active, exit_state, vertex, max_bounces, key, weight, label, start=(0, 0), done=False):
    """The loop of a sampling walk that leaves the microsurface by an exit probability, one vertex per
    iteration (the loop of ``sample_conductor`` with ``vertex_numbers``; the invariance model's walks on
    conductor and Lambertian facets): the walk arrives along −``wi`` with the lane's ``weight`` and the
    walk's exit bookkeeping ``exit_state`` (loop state: arrays, lists or tuples of them). Vertex j uses the
    numbers (u_exit, u1, u2): ``first`` at j = 0, the lane's stream after it.
    ``vertex(w, weight, u, exit_state, rng, active)`` → (d, weight, leaves, active, exit_state) scatters the
    arriving w = −d_j into d = d_{j+1} (drawing any further numbers from ``rng``) and says where the walk
    leaves along d. More than ``max_bounces`` vertices is invalid. ``start`` = (j, counter), ``done``: a walk
    taken up at vertex j > 0 (jit/auto.py runs vertex 0 itself), its stream's counter and whether it has already
    left (the lanes not ``active``). Returns (ω_o, weight, valid)."""

    def body(j, w, weight, done, active, counter, u, exit_state):
        rng = Stream(key, counter)
        d, weight, done, active, exit_state = vertex(w, weight, u, exit_state, rng, active)
        active &= j + 1 < max_bounces
        u = vertex_numbers(rng)  # before the counter is read
        return dict(j=j + 1, w=-d, weight=weight, done=done, active=active, counter=rng.counter, u=u,
                    exit_state=exit_state)

    state = dict(j=mi.UInt32(start[0]), w=mi.Vector3f(wi), weight=weight, done=mi.Bool(done), active=mi.Bool(active),
                 counter=mi.UInt32(start[1]), u=tuple(clean_uniform(mi.Float(x)) for x in first), exit_state=exit_state)
    out = while_loop(state, body, label=label)
    return -out["w"], out["weight"], out["done"]
