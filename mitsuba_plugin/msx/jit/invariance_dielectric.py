"""The invariance principle through a rough dielectric (Cui et al. 2023) in the Dr.Jit engine: twin of
``src/models/invariance/dielectric.rs``. Until the first refraction the path reflects in ω_i's medium, a
monotone run whose vertex depth has the exact law of ``PieceChain`` (pieces of rates L_i, π over the piece
index); the next events use its exact exit probability (reflection) or the top piece's Beta term plus one
sampled depth (transmission); at the first refraction the depth is drawn from that law, flipped, and
Heitz's walk (jit/heitz.py ``dielectric_eval_from`` / ``sample_from``) continues the path. The pieces live in
``DIELECTRIC_RUN_SLOTS`` registers (jit/invariance_recursion.py has why, and how many).
"""

import math

import drjit as dr
import mitsuba as mi

from . import heitz, invariance_recursion, walk
from .dielectric import eta_seen, radiance_scale, reflect_or_refract_unit
from .glass_traced import RR_TRACED_FLOOR, edge_point, eta_tangent_step, scatter_traced
from .gradients import LoopValues
from .microfacet import BECKMANN
from .invariance_recursion import over_run, push_down, run_slots
from .posfree_dielectric import vertex_reflect, vertex_transmit
from .rng import Stream, clean_uniform
from .special import expm1, l_beta, optical_depth


class PieceChain:
    """The exact depth law of the current vertex of a monotone one-sided run entered from above (twin of
    ``PieceChain`` in ``dielectric.rs``), per lane in ``n`` registers unrolled at trace time (as
    ``MonotoneExit``): Python lists ``rates`` (L_i of the downward directions, slot i < a) and ``pi`` (π(c)
    up to the factor ``scale``; before the first upward direction π is the point mass on the bottom piece,
    not materialised), ``a`` (pieces), ``has_up``, ``hit`` (H_m). Pass :meth:`state` through the walk's
    loop and rebuild with :meth:`from_state`."""

    def __init__(self, rates, pi, a, has_up, scale, hit, unrolled=False, packets=True):
        self.rates, self.pi = list(rates), list(pi)
        self.a, self.has_up, self.scale, self.hit = a, has_up, scale, hit
        self.n = len(self.rates)
        # How its passes are traced (``over_run``): a Python bool of the trace, not loop state.
        self.unrolled = unrolled
        # Whether its pushes, draws and the first run's steps on it (``refraction``, ``extend_run_packets``) run
        # in per-packet branches (``branched``): the eval walk's do (−8 % per call, benches/README.md, "The
        # invariance walk through glass"); the sample walk's do not (its first vertex, where every lane is,
        # dominates it, and the branches cost it 2–4 %). The same bits either way.
        self.packets = packets

    @property
    def branched(self):
        return self.packets and not self.unrolled

    @staticmethod
    def new(l0, n, unrolled=False, packets=True):
        return PieceChain([mi.Float(l0)] + [mi.Float(1.0) for _ in range(n - 1)], [mi.Float(0.0) for _ in range(n)],
                          mi.UInt32(1), mi.Bool(False), mi.Float(1.0), mi.Float(1.0), unrolled, packets)

    def state(self):
        return (self.rates, self.pi, self.a, self.has_up, self.scale, self.hit)

    @staticmethod
    def from_state(s, unrolled=False, packets=True):
        return PieceChain(*s, unrolled=unrolled, packets=packets)

    def pi_at(self, c, on):
        """π(c) (normalised) of the slot c (a Python int) where ``on``."""
        point = dr.select(self.a == c + 1, 1.0, 0.0)
        return dr.select(on, dr.select(self.has_up, self.pi[c] * self.scale, point), 0.0)

    def push_down(self, l, active):
        """Appends a downward direction (|Λ| = ``l``) where ``active``; False on a non-monotone run or a
        full run (a = n): the walk ends there."""
        self.rates, self.a, ok = push_down(self.rates, self.a, self.has_up, l, active, self.unrolled)
        return ok

    def push_up(self, lam, active, over_lambda=False):
        """Appends an upward direction with Λ = ``lam`` where ``active``; returns H_{m+1}/H_m (0 where not
        active). carry(c) = Σ_{c'' ≥ c} π(c'') Π_{i=c+1}^{c''} L_i/(L_i+Λ) is the mass whose jump reaches
        piece c; a fraction Λ/(L_c+Λ) lands there (Λ = ∞: everything lands where it is).

        ``over_lambda`` (a walk along moving directions, docs/gradients.md): returns H_{m+1}/(H_m·Λ) instead,
        and keeps π up to the factor 1/Λ, so that no quotient divides by a tiny Λ (after a step going up near
        the normal Beckmann's Λ is below 10⁻¹⁹, and the derivatives of 1/H_{m+1} and of the next vertex's
        1/A(w) ~ 1/Λ overflow in float32 although their products are O(1)); the normalised π is the same.
        Λ = ∞ (a horizontal direction) returns 0 there."""
        inf = dr.isinf(lam)
        run = active & (lam > 0.0)

        def step(c, state):
            carry, cont, pi = state[0], state[1], state[2:]
            on = run & (self.a > c)
            if c + 1 < self.n:
                ln = self.rates[c + 1]
                carry = dr.select(on & (self.a > c + 1), carry * dr.select(inf, 0.0, ln / (ln + lam)), carry)
            carry = carry + self.pi_at(c, on)
            if over_lambda:
                land = carry * dr.select(inf, 0.0, 1.0 / (self.rates[c] + lam))
            else:
                land = carry * dr.select(inf, 1.0, lam / (self.rates[c] + lam))
            return (carry, cont + dr.select(on, land, 0.0)) + pi[:c] + (dr.select(on, land, pi[c]),) + pi[c + 1:]

        out = over_run(self.n, self.a, step, (mi.Float(0.0), mi.Float(0.0)) + tuple(self.pi), unrolled=self.unrolled)
        cont, self.pi = out[1], list(out[2:])
        good = run & (cont > 0.0) & dr.isfinite(cont)
        self.scale = dr.select(good, 1.0 / cont, self.scale)
        self.has_up = self.has_up | active
        if over_lambda:
            cont = dr.select(good, cont, 0.0)
            self.hit = dr.select(active, self.hit * dr.minimum(cont * lam, 1.0), self.hit)
            return dr.select(active, cont, 0.0)
        cont = dr.select(good, dr.minimum(cont, 1.0), 0.0)
        self.hit = dr.select(active, self.hit * cont, self.hit)
        return dr.select(active, cont, 0.0)

    def push_up_packets(self, lam, active):
        """``push_up`` only in the packets that have a lane of ``active`` (a symbolic ``dr.if_stmt``; the
        other lanes keep the chain and get 0, as ``push_up`` leaves and gives them: the same bits). A chain
        that is not ``branched`` (unrolled: forward mode fails on a branch; the sample walk's) pushes everywhere."""
        if not self.branched:
            return self.push_up(lam, active)
        n = self.n

        def run(lam, *s):
            chain = PieceChain(self.rates, s[:n], self.a, s[n + 1], s[n], s[n + 2])
            cont = chain.push_up(lam, active)
            return (cont,) + tuple(chain.pi) + (chain.scale, chain.has_up, chain.hit)

        def kept(lam, *s):
            return (dr.zeros(mi.Float, dr.width(lam)),) + s

        out = dr.if_stmt((lam,) + tuple(self.pi) + (self.scale, self.has_up, self.hit), active, run, kept,
                         label="msx_invariance_push_up")
        self.pi, (self.scale, self.has_up, self.hit) = list(out[1:n + 1]), out[n + 1:]
        return out[0]

    def push_down_packets(self, l, active):
        """``push_down`` only in the packets that have a lane of ``active`` (as ``push_up_packets``)."""
        if not self.branched:
            return self.push_down(l, active)

        # Slot 0 (L_0) is never written: it stays out of the branch, as it was out of the loop's changes.
        def run(l, a, *rates):
            rates, a, ok = push_down([self.rates[0]] + list(rates), a, self.has_up, l, active, False)
            return (ok, a) + tuple(rates[1:])

        def kept(l, a, *rates):
            return (dr.zeros(mi.Bool, dr.width(l)), a) + rates

        out = dr.if_stmt((l, self.a) + tuple(self.rates[1:]), active, run, kept, label="msx_invariance_push_down")
        self.a, self.rates = out[1], [self.rates[0]] + list(out[2:])
        return out[0]

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


def draw_depth(chain, c_min, key, counter, active, traced=False, reparam=False):
    """``draw_depth_all`` only in the packets that have a lane of ``active`` (a symbolic ``dr.if_stmt``
    branches per packet); the other lanes get what ``draw_depth_all`` gives them there, (0, 0, counter + 1,
    1): the same bits. A chain that is not ``branched`` (unrolled: a walk differentiated in forward mode, which
    fails on a branch; the sample walk's) and the traced draws take ``draw_depth_all`` itself."""
    if traced or not chain.branched:
        return draw_depth_all(chain, c_min, key, counter, active, traced, reparam)

    def skipped(counter):
        zero = dr.zeros(mi.Float, dr.width(counter))
        return zero, zero, counter + 1, zero + 1.0

    return dr.if_stmt((counter,), active, lambda c: draw_depth_all(chain, c_min, key, c, active), skipped,
                      label="msx_invariance_draw_depth")


def draw_depth_all(chain, c_min, key, counter, active, traced=False, reparam=False):
    """τ of ``PieceChain.sample_depth``: the piece c ≥ c_min from π (one number), then τ = X_0 + … + X_c
    with fresh X_i ~ Exp(L_i) (one number each; L = ∞ adds no depth). Returns (τ, mass Σ_{c ≥ c_min} π(c),
    counter, ratio). ``traced`` (docs/gradients.md): the draw is made with the chain's values detached and
    ``ratio`` is the density of the drawn (c, X_0..X_c) under the attached values over the detached one,
    (π(c)/π̄(c))·Π (L_i/L̄_i)·e^{−(L_i − L̄_i) X_i} — value 1, derivative the score (1 when not traced).
    ``reparam`` (traced, along moving directions): each X_i = E_i/L_i keeps its Exp(1) number E_i and moves
    with the attached L_i (support [0, ∞) fixed), and ``ratio`` is π(c)/π̄(c) alone: the score of X_i,
    L_i′(1/L_i − X_i), has infinite variance where a direction turns horizontal (L_i ~ 1/|w_z|)."""

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
        if traced and reparam:
            ok = on & dr.isfinite(rate) & (rate > 0.0)
            tau = dr.select(ok, tau + optical_depth(u) / dr.select(ok, rate, 1.0), tau)
        elif traced:
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


def transmit_exit(chain, lambda_t, key, counter, active, traced=False, reparam=False, lb=None):
    """Unbiased estimate of E[(1 − e^{−τ})^{Λ'}] given the hits (Rust ``transmit_exit``): the top piece's
    mass exactly, π(0)·L_0·B(L_0, 1+Λ'), one depth drawn from the deeper pieces for the rest. Returns
    (estimate in [0, 1], counter). ``traced``: the deeper depth is drawn detached and weighed by its density
    ratio (``draw_depth``), so the estimate's derivative is unbiased."""
    run = active & (lambda_t >= 0.0) & ~dr.isinf(lambda_t)
    p0 = chain.pi_at(0, run)
    l0 = chain.rates[0]
    # L_0 ≥ 1: the series form is never needed. ``lb``: that factor when the caller has it (a plain walk
    # computes it once per lane, before its loop: L_0 and Λ' do not change along the run).
    e = p0 * (l_beta(l0, lambda_t, branch=not traced) if lb is None else lb)
    deeper = run & (chain.a > 1)
    tau, rest, counter, ratio = draw_depth(chain, 1, key, counter, deeper, traced, reparam)
    above = -expm1(-tau)  # 1 − e^{−τ}
    # Drawn from π restricted to c ≥ 1 (mass ``rest``): rest·g(τ); traced, r̄est·(π(c)/π̄(c))·…·g(τ).
    weight = dr.detach(rest) * ratio if traced else rest
    e = dr.select(deeper & (rest > 0.0), e + weight * dr.exp(lambda_t * dr.log(above)), e)
    e = dr.select(dr.isfinite(e), dr.clip(e, 0.0, 1.0), 0.0)
    return dr.select(run, e, 0.0), counter


def next_event_exits(chain, lambda_o, key, counter, nee, same, lb=None):
    """(``exit_given_hits`` where ``nee & same``, ``transmit_exit`` where ``nee & ~same``, counter) of a plain
    walk, each inside a symbolic ``dr.if_stmt`` that a packet without a lane of it skips: its other lanes get
    what the function gives them there (0, and the counter one pair on: ``draw_depth``), the same bits.
    ``lb``: ``transmit_exit``'s."""

    def reflected(lo):
        return chain.exit_given_hits(lo, nee & same)

    def across(lo, counter):
        return transmit_exit(chain, lo, key, counter, nee & ~same, lb=lb)

    def zero(lo, *counter):
        z = dr.zeros(mi.Float, dr.width(lo))
        return (z, counter[0] + 1) if counter else z

    exit_r = dr.if_stmt((lambda_o,), nee & same, reflected, zero, label="msx_invariance_exit_reflected")
    exit_t, counter = dr.if_stmt((lambda_o, counter), nee & ~same, across, zero, label="msx_invariance_exit_across")
    return exit_r, exit_t, counter


def refraction(chain, o, refr, handed, key, counter, traced=False, reparam=False):
    """Where the first run refracts (``refr``): the vertex depth drawn from the chain's law (``draw_depth``),
    and what Heitz's walk continues from, ``handed`` = (refracted, its direction, its height): the refracted
    ray −``o`` and the flipped height. Returns (handed, counter, the draw's density ratio)."""
    if traced or not chain.branched:
        tau, _, counter, ratio = draw_depth(chain, 0, key, counter, refr, traced, reparam)
        refracted, h_dir, h_t = handed
        handed = (refracted | refr, dr.select(refr, -o, h_dir), dr.select(refr, heitz.flip_height(-tau), h_t))
        return handed, counter, ratio

    # A plain walk: the draw and the flip only in the packets that have a refracting lane (a symbolic
    # if_stmt); the other lanes keep what they hand over and move the counter one pair on (the same bits).
    def run(counter, refracted, h_dir, h_t):
        tau, _, counter, _ = draw_depth_all(chain, 0, key, counter, refr)
        return counter, refracted | refr, dr.select(refr, -o, h_dir), dr.select(refr, heitz.flip_height(-tau), h_t)

    def kept(counter, *handed):
        return (counter + 1,) + handed

    counter, *handed = dr.if_stmt((counter,) + tuple(handed), refr, run, kept, label="msx_invariance_refraction")
    return tuple(handed), counter, mi.Float(1.0)


def extend_run(mf, chain, d, active, over_lambda=False):
    """Appends the reflected direction ``d`` to the first run's chain where ``active`` (the walk ends on a
    degenerate direction): returns (active, d points up, H_{m+1}/H_m of an upward d, a downward d pushed).
    ``over_lambda``: H_{m+1}/(H_m·Λ) instead (``PieceChain.push_up``), and also returns |Λ(d)|."""
    active &= dr.all(dr.isfinite(d)) & (d[2] != 0.0)
    up = d[2] > 0.0
    lam = mf.lambda_(d)
    active &= ~(up & dr.isnan(lam))
    if over_lambda:
        cont = chain.push_up(lam, active & up, over_lambda)
    else:  # only in the packets with a lane of it (the same bits)
        cont = chain.push_up_packets(lam, active & up)
    l = mf.abs_lambda(d)
    pushed = chain.push_down_packets(l, active & ~up & dr.isfinite(l))
    if over_lambda:
        return active, up, cont, pushed, l
    return active, up, cont, pushed


def extend_run_packets(mf, chain, d, active, lam_up=False):
    """``extend_run`` of a plain walk only in the packets that have a lane of ``active`` (a symbolic
    ``dr.if_stmt``; the other lanes keep the chain, and get what ``extend_run`` gives them there: not active,
    0, not pushed; the same bits). A chain that is not ``branched`` extends everywhere. ``lam_up``: also
    returns ``Microfacet.lambda_up`` of d (which ``extend_run`` computes; 0 where not extended), the next
    vertex's Λ for its next event (``Microfacet.d_visible``)."""
    if not chain.branched:
        out = extend_run(mf, chain, d, active)
        return out + (mf.lambda_up(mf.alpha_tan2(d)),) if lam_up else out
    n = chain.n

    def flat(c):  # slot 0 (L_0) is never written: it stays out of the branch
        return tuple(c.rates[1:]) + tuple(c.pi) + (c.a, c.has_up, c.scale, c.hit)

    more = 1 if lam_up else 0

    def run(d, active, *s):
        c = PieceChain([chain.rates[0]] + list(s[:n - 1]), s[n - 1:2 * n - 1], *s[2 * n - 1:])
        active, _, cont, pushed = extend_run(mf, c, d, active)
        lam = (mf.lambda_up(mf.alpha_tan2(d)),) if lam_up else ()
        return (active, cont, pushed) + lam + flat(c)

    def kept(d, active, *s):
        zero = dr.zeros(mi.Float, dr.width(active))
        return (active, zero, dr.zeros(mi.Bool, dr.width(active))) + (zero,) * more + s

    out = dr.if_stmt((d, active) + flat(chain), active, run, kept, label="msx_invariance_extend_run")
    rest = out[3 + more:]
    chain.rates = [chain.rates[0]] + list(rest[:n - 1])
    chain.pi = list(rest[n - 1:2 * n - 1])
    chain.a, chain.has_up, chain.scale, chain.hit = rest[2 * n - 1:]
    return (out[0], d[2] > 0.0, out[1], out[2]) + tuple(out[3:3 + more])


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


def first_run_edge_terms(mf, chain, w, eta_f, teta_f, outside, wo, lambda_o, key, j, active, tw=None, two=None):
    """∂/∂η of the first run's next-event values along their moving edges (docs/gradients.md, "The IOR of
    the glass walks"), for both events of the vertex at w, with ``glass_traced.edge_point``: in the
    space of normals the one discontinuity that moves with η is the next vertex's value towards ω_o, which
    jumps to 0 on the circle w'_z = z*. A reflection keeps the first run's directions fixed in η (its tangent
    is 0), so only the circle moves, and only where ω_o is across (z* = −η_f o_z); its next vertex carries
    the run's hit probability of the new direction (``push_up``) and ω_o's exit probability given the hits
    (``transmit_exit``, one depth drawn) on a copy of the chain. A refraction's next vertex is the first of
    Heitz's walk, from the depth drawn from the chain's law (``draw_depth``): ``heitz.dielectric_edge_term``
    there. One uniform azimuth per event; its numbers come from counters of their own (EDGE_COUNTER_BASE).
    Everything is detached: the sum enters as (η − η̄)·terms.

    ``tw``, ``two`` (along moving directions, docs/gradients.md, "The invariance walk through glass along moving
    directions"): the tangents of w and of ω_o in the coordinate s (``teta_f`` 0). Both events' circles then
    move (with ω_o, and with w at the fixed normal), the reflection's whether ω_o is across or not (its next
    vertex's exit probability given the hits, ``exit_given_hits``, where ω_o is on its side); the sum enters as
    (s − s̄)·terms."""
    base = mi.UInt32(EDGE_COUNTER_BASE) + j * EDGE_COUNTERS_PER_VERTEX
    rng = Stream(key, base)
    u_phi_r, u_phi_t = rng.next2()
    u_h, _ = rng.next2()
    chain = detached_chain(chain)
    # The refraction: the next vertex is Heitz's, from the depth drawn from the chain's law (flipped there).
    tau, _, counter, _ = draw_depth(chain, 0, key, rng.counter, active)
    dirs = two is not None
    tw0 = tw if dirs else mi.Vector3f(0.0)
    refracted = heitz.dielectric_edge_term(mf, w, tw0, -tau, outside, eta_f, teta_f, wo, lambda_o, True,
                                           u_phi_t, u_h, *((two,) if dirs else ()))
    # The reflection: in η its direction has no tangent, so only where ω_o is across does its circle move;
    # along moving directions it moves with ω_o (and with w) on either side.
    o = dr.select(outside, wo, -wo)
    to = dr.select(outside, two, -two) if dirs else None
    w_next, transmit, density, value, speed, ok = edge_point(mf, w, tw0, o, eta_f, teta_f, False, u_phi_r, to)
    ok &= active if dirs else active & transmit
    d = -w_next
    up = d[2] > 0.0
    copy_ = detached_chain(chain)
    cont = copy_.push_up(mf.lambda_(d), ok & up)
    pushed = copy_.push_down(mf.abs_lambda(d), ok & ~up)
    ok &= dr.select(up, cont > 0.0, pushed)
    exit_t, _ = transmit_exit(copy_, lambda_o, key, counter, ok & transmit if dirs else ok)
    if dirs:
        exit_t = dr.select(transmit, exit_t, copy_.exit_given_hits(lambda_o, ok & ~transmit))
    area = mf.projected_area(w_next)
    value = value * dr.abs(w_next[2]) / dr.select(area > 0.0, area, 1.0)
    reflected = 2.0 * math.pi * density * dr.select(up, cont, 1.0) * exit_t * value * speed
    reflected = dr.select(ok & (area > 0.0) & dr.isfinite(reflected), reflected, 0.0)
    return dr.select(active, refracted + reflected, 0.0)


def eval(mf, eta, radiance, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
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
    terms (``first_run_edge_terms``), in every lane that reaches the scatter (as along directions, below). The
    differentiated values travel in the loop's state.

    ``direction_tangent`` (traced only; docs/gradients.md, "The invariance walk through glass along
    moving directions"): (s, t_i, t_o) while one coordinate s of ω_i, ω_o is differentiated. ω_i enters the
    first state attached; ω_o, its tangent, s and the tangent of w in s travel in the loop's state (the
    tangent goes to Heitz's walk with the refracted direction). As in Heitz's walk, the throughput is carried
    over L = |Λ(−w)| (the vertex's projected area over |w_z|): the next event is the position-free vertex
    value (Heitz's phase function × L), the draw's weight is ``scatter_traced(times_area=True)`` and an upward
    step's hit probability comes divided by its Λ (``extend_run(over_lambda=True)``), so that no derivative
    divides by a tiny Λ; the roulette sees the throughput itself. The depths (at the refraction and in the
    next event's ``transmit_exit``) are reparameterized (``draw_depth(reparam=True)``: each X_i = E_i/L_i
    moves with the attached L_i, the piece's π(c)/π̄(c) in the weight). On GGX each vertex adds its next
    vertex's edge terms along s (``first_run_edge_terms`` with the tangents), in every lane that reaches the
    scatter — whether or not the scatter's own draw is valid (the edge is an estimate of its own, independent of
    that draw); Beckmann has none (its D is 0 at a horizontal half vector)."""
    traced = mf_sample is not None
    dirs = traced and direction_tangent is not None  # a pass along one coordinate of the directions
    dir_edges = dirs and mf.dist != BECKMANN  # Beckmann's D vanishes at horizontal normals: no edge
    last = max_bounces
    slots = run_slots(last, invariance_recursion.DIELECTRIC_RUN_SLOTS)
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
    lb_across = None
    if not traced:  # the transmission's L_0·B(L_0, 1+Λ(ω_o)) (``transmit_exit``), once per lane where ω_o is across
        def across_factor(l0, lo):
            return l_beta(l0, lo, branch=True)

        def none(l0, lo):
            return dr.zeros(mi.Float, dr.width(l0))

        lb_across = dr.if_stmt((l0, lambda_o), start & ~same, across_factor, none, label="msx_invariance_across_factor")

    def body(j, w, thr, result, active, counter, refracted, h_dir, h_t, chain_state, piped, lam_w, packets=True):
        mfa, mfs, lo, ea, es, wo_l_ = mf, mf, lambda_o, e, e, wo_l
        if traced:  # the differentiated values come through the state
            lv = LoopValues(mf.dist, piped)
            mfa, mfs, lo = lv.mf, lv.mf_sample, lv.lambda_o
            if dirs:
                eta_a, h_tw, tw, wo_, s_dir, two = lv.rest
                wo_l_ = dr.select(outside, wo_, -wo_)
            else:
                eta_a, h_tw = lv.rest
            ea = eta_seen(eta_a, outside)
            es = dr.detach(ea)
        chain = PieceChain.from_state(chain_state, chain0.unrolled, packets)
        order = j + 1
        # Next-event estimation: phase function × exact exit probability (along moving directions thr is the
        # throughput over L, and the phase function is taken times L).
        if dirs:
            phase = dr.select(same, vertex_reflect(mfa, ea, w, wo_l_), vertex_transmit(mfa, ea, w, wo_l_))
            l_w = dr.detach(mfa.abs_lambda(-w))
            l_w = dr.select(dr.isfinite(l_w), l_w, 0.0)
        else:  # a plain walk's Λ of w comes from the previous vertex (``lam_w``)
            phase = heitz.phase_next_event(mfa, w, wo_l_, ea, ~same, None if traced else lam_w)
        nee = active & (phase > 0.0)
        if traced:
            exit_r = chain.exit_given_hits(lo, nee & same)
            exit_t, counter = transmit_exit(chain, lo, key, counter, nee & ~same, traced, dirs)
        else:  # each only in the packets that have a lane of it (a symbolic if_stmt; the same bits)
            exit_r, exit_t, counter = next_event_exits(chain, lo, key, counter, nee, same, lb_across)
        result = dr.select(nee, result + thr * phase * dr.select(same, exit_r, exit_t), result)
        active &= order < last
        rng = Stream(key, counter)
        u_rr, u_f = rng.next2()
        if dirs:  # the roulette's survival probability from the throughput itself, thr·L (detached)
            q = dr.detach(dr.maximum(dr.minimum(dr.detach(thr) * l_w, 1.0), RR_TRACED_FLOOR))
            play = j >= walk.RR_START
            survived = (q > 0.0) & ((q >= 1.0) | (u_rr < q))
            thr = dr.select(play, dr.select(survived, thr / q, 0.0), thr)
            alive = ~play | survived
        else:
            thr, alive = walk.roulette_from(j >= walk.RR_START, thr, u_rr, 1.0, RR_TRACED_FLOOR if traced else 0.0)
        active &= alive
        reached = mi.Bool(active)  # the lanes that scatter (a copy: &= updates in place); their edges below
        # Scatter: visible normal, reflect with probability F.
        u1, u2 = rng.next2()
        if traced:
            # In the space of normals (glass_traced.scatter_traced): a reflection does not move with η, a
            # refraction's direction does (its tangent goes to Heitz's walk with it).
            u_mix, _ = rng.next2()
            d_new, refr, _, valid, weight, m = scatter_traced(mfa, mfs, w, mi.Float(1.0), ea, u_f, u1, u2, u_mix,
                                                              times_area=dirs)
            active &= valid
            refr &= active
            if dirs:  # the tangents in s at the fixed normal (the IOR's tangent 0)
                zero = dr.zeros(mi.Float, dr.width(es))
                ws = dr.detach(w)
                if dir_edges:  # the next vertex's moving edges, for both events (as a derivative only)
                    edge = first_run_edge_terms(mfs, chain, ws, es, zero, outside, dr.detach(wo_), dr.detach(lo), key,
                                                j, reached, tw=tw, two=dr.detach(two))
                    result = dr.select(reached, result + (s_dir - dr.detach(s_dir)) * (dr.detach(thr) * l_w) * edge,
                                       result)
                h_tw = dr.select(refr, eta_tangent_step(ws, tw, m, es, zero, refr), h_tw)
                tw = eta_tangent_step(ws, tw, m, es, zero, mi.Bool(False))
            else:
                teta = dr.select(outside, 1.0, -es * es)
                if eta_traced:
                    edge = first_run_edge_terms(mfs, chain, w, es, teta, outside, wo, dr.detach(lo), key, j, reached)
                    result = dr.select(reached, result + (eta_a - dr.detach(eta_a)) * dr.detach(thr) * edge, result)
                h_tw = dr.select(refr, eta_tangent_step(w, mi.Vector3f(0.0), m, es, teta, refr), h_tw)
            o = -d_new
            d = d_new
        else:
            m, cos_wm, valid = heitz.visible_normal(mfs, w, u1, u2, where=active)  # only where the walk goes on
            active &= valid
            o, d, crossed = reflect_or_refract_unit(w, m, cos_wm, es, u_f)
            refr = active & crossed
        (refracted, h_dir, h_t), counter, depth_ratio = refraction(chain, o, refr, (refracted, h_dir, h_t), key,
                                                                   rng.counter, traced, dirs)
        if traced:
            thr = dr.select(active, thr * weight * dr.select(refr, depth_ratio, 1.0), thr)
        active &= ~refr
        # Reflect, and extend the run's exit table.
        if dirs:  # thr becomes the throughput over L of the next w = −d
            active, up, cont, pushed, l_d = extend_run(mfa, chain, d, active, over_lambda=True)
            thr = dr.select(active, dr.select(up, thr * cont, thr / dr.select(up, 1.0, l_d)), thr)
        elif traced:
            active, up, cont, pushed = extend_run_packets(mfa, chain, d, active)
            thr = dr.select(active & up, thr * cont, thr)
        else:
            active, up, cont, pushed, lam_w = extend_run_packets(mfa, chain, d, active, lam_up=True)
            thr = dr.select(active & up, thr * cont, thr)
        active &= (~up | (cont > 0.0)) & (up | pushed)
        if dirs:
            piped = lv.piped(eta_a, h_tw, tw, wo_, s_dir, two)
        elif traced:
            piped = lv.piped(eta_a, h_tw)
        return dict(j=j + 1, w=-d, thr=thr, result=result, active=active, counter=counter, refracted=refracted,
                    h_dir=h_dir, h_t=h_t, chain_state=chain.state(), piped=piped, lam_w=lam_w)

    thr0 = mi.Float(1.0)
    # A plain walk carries Λ of w (``Microfacet.lambda_up``; (α tan θ)² is even in w: of −w0, as l0's) for the
    # next event's visible-normal density: the same bits as computing it there, without a Λ per vertex.
    lam_w0 = () if traced else mf.lambda_up(mf.alpha_tan2(-w0))
    state = dict(j=mi.UInt32(0), w=mi.Vector3f(w0), thr=thr0, result=mi.Float(0.0), active=mi.Bool(start),
                 counter=mi.UInt32(0), refracted=mi.Bool(False), h_dir=mi.Vector3f(0.0, 0.0, 1.0), h_t=mi.Float(0.0),
                 chain_state=chain0.state(), piped=(), lam_w=lam_w0)
    direction = None
    if dirs:
        s_dir, t_i, t_o = direction_tangent
        t_i = mi.Vector3f(t_i)
        state["thr"] = 1.0 / mi.Float(l0)  # over L of w0 (≥ 1)
        direction = (s_dir, t_o)
        state["piped"] = LoopValues.state(mf, lambda_o, mi.Float(eta), mi.Vector3f(0.0),
                                          dr.select(outside, t_i, -t_i), mi.Vector3f(wo), mi.Float(s_dir),
                                          mi.Vector3f(t_o))
    elif traced:
        state["piped"] = LoopValues.state(mf, lambda_o, mi.Float(eta), mi.Vector3f(0.0))
    if not traced:  # the first vertex outside the loop, on the new chain (as ``sample``'s)
        state = body(**state, packets=False)
    out = walk.while_loop(state, body, label="msx_invariance_dielectric_eval")
    j, thr, result, counter, refracted, h_dir, h_t = (out[k] for k in ("j", "thr", "result", "counter", "refracted",
                                                                        "h_dir", "h_t"))
    # The rest of the refracted paths: Heitz's walk from the vertex after the refraction (order j + 1), with
    # the refracted direction's tangent in η (in s along moving directions).
    h_tw = (out["piped"][4] if dirs else out["piped"][-1]) if traced else None
    rest = heitz.dielectric_eval_from(mf, eta, wo, h_dir, h_t, ~outside, j + 1, thr, refracted, last, key,
                                      counter, mf_sample=mf_sample, tw=h_tw, direction=direction,
                                      lambda_o=lambda_o)  # Λ of the upward one of ±ω_o, as the walk's
    v = (result + dr.select(refracted, rest, 0.0)) * radiance_scale(eta, radiance, outside, wo[2] > 0.0)
    return dr.select(dr.isfinite(v) & (v > 0.0), v, 0.0)


def sample(mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling with the heights of the first run integrated out (Rust
    ``dielectric::sample``): leave along an upward direction with the exact conditional exit probability;
    at the first refraction draw the vertex depth from its exact law and continue with Heitz's walk
    (``heitz.sample_from``). (sample1, u1, u2) drive the first vertex (Fresnel choice, visible
    normal). Returns (ω_o, weight = 1, × 1/η_r² for a Radiance-mode transmission, valid)."""
    last = max_bounces
    slots = run_slots(last, invariance_recursion.DIELECTRIC_RUN_SLOTS)
    eta = mi.Float(eta)
    wi = mi.Vector3f(wi)
    outside = wi[2] > 0.0
    e = eta_seen(eta, outside)
    w0 = dr.select(outside, wi, -wi)
    l0 = mf.abs_lambda(-w0)
    start = dielectric_valid(wi, eta) & dr.isfinite(l0) & (last > 0)
    chain0 = PieceChain.new(l0, slots)

    def body(j, w, done, active, counter, u, refracted, h_dir, h_t, chain_state, packets=True):
        ua, u1, u2 = u
        chain = PieceChain.from_state(chain_state, packets=packets)
        m, cos_wm, valid = heitz.visible_normal(mf, w, u1, u2)
        active &= valid
        o, d, crossed = reflect_or_refract_unit(w, m, cos_wm, e, ua)
        refr = active & crossed
        (refracted, h_dir, h_t), counter, _ = refraction(chain, o, refr, (refracted, h_dir, h_t), key, counter)
        active &= ~refr
        active, up, cont, pushed = extend_run_packets(mf, chain, d, active)
        rng = Stream(key, counter)
        u_exit, c = rng.next2()
        leaves = active & up & (u_exit >= cont)
        done = leaves
        active &= (up & ~leaves) | pushed
        active &= j + 1 < last
        a, b = rng.next2()
        return dict(j=j + 1, w=-d, done=done, active=active, counter=rng.counter, u=(c, a, b), refracted=refracted,
                    h_dir=h_dir, h_t=h_t, chain_state=chain.state())

    state = dict(j=mi.UInt32(0), w=mi.Vector3f(w0), done=mi.Bool(False), active=mi.Bool(start), counter=mi.UInt32(0),
                 u=tuple(clean_uniform(mi.Float(x)) for x in (sample1, u1, u2)), refracted=mi.Bool(False),
                 h_dir=mi.Vector3f(0.0, 0.0, 1.0), h_t=mi.Float(0.0), chain_state=chain0.state())
    # The first vertex, where every lane is, outside the loop: on the new chain (literals but L_0) drjit folds
    # the passes over the run away; the loop takes the lanes that go on, its pieces in per-packet branches.
    state = body(**state, packets=False)
    out = walk.while_loop(state, body, label="msx_invariance_dielectric_sample")
    j, w, done, counter, refracted, h_dir, h_t = (out[k] for k in ("j", "w", "done", "counter", "refracted", "h_dir",
                                                                    "h_t"))
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
