"""Heitz et al. 2016, the stochastic random walk on the Smith microsurface with explicit heights, in the
Dr.Jit engine: twin of the conductor part of ``src/models/heitz/mod.rs`` (dielectric and diffuse
microsurfaces are not ported yet).

Heights as in the core: Heitz's uniform height distribution, carried as t = ln C¹(h) ≤ 0 (t = 0 at the
top of the microsurface). In that variable a ray's free flight is an exponential optical depth
E = −ln(1 − U): an upward ray (Λ ≥ 0) reaches t + E/Λ and leaves when that is ≥ 0 (probability
e^{Λt} = G1(ω, h)); a downward ray reaches t − E/|Λ| and always hits; Λ = 0 leaves, Λ = ∞ (horizontal)
hits at its height. The masking of ω_o at height t is e^{Λ(ω_o)·t}.

``eval`` (twin of ``eval`` / ``eval_from``) is the supplement's Algorithm 2, PT with next-event
estimation towards ω_o at every vertex, with the core's one change: every height step is conditioned on
hitting and the throughput carries the hit probability 1 − G1(ω, h) (``sample_height_hit``); Russian
roulette (``walk::russian_roulette``, keep = 1) ends the walk. ``sample`` (twin of ``sample`` /
``sample_from``) is Algorithm 3: the walk without NEE, returning the exit direction with the product of
the Fresnel terms divided by the roulette's survival probabilities.

As in the core (``valid_incidence``), a conductor needs ω_i (and, for eval, ω_o) strictly above the macro
surface: the walk does not start below (``below=False``; the MIS density is 0 there).

Everything is float32 on arrays of lanes; ``expm1``/``log1p`` (not in drjit) are written below with
Kahan's correction so that the hit probability of a near-vertical ray keeps its relative precision.
"""

import drjit as dr
import mitsuba as mi

from . import mis, walk
from .microfacet import dot, reflect
from .model import ConductorWalk
from .rng import Stream

# The largest float32 below 1: uniform numbers are clamped to [0, ONE_MINUS] (the core clamps to 1 − ε).
ONE_MINUS = 0.99999994


def expm1(x):
    """e^x − 1 for x ≤ 0 without cancellation near 0 (Kahan: (u − 1)·x / ln u with u = e^x)."""
    u = dr.exp(x)
    um1 = u - 1.0
    v = um1 * x / dr.log(u)
    return dr.select(u == 1.0, x, dr.select(um1 == -1.0, -1.0, v))


def log1p(x):
    """ln(1 + x) for x > −1 without cancellation near 0 (Kahan: ln u · x / (u − 1) with u = 1 + x)."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * x / (u - 1.0))


def optical_depth(u):
    """E = −ln(1 − U), an Exp(1) depth (finite: U is clamped below 1)."""
    u = dr.clip(u, 0.0, ONE_MINUS)
    return -dr.log(1.0 - u)


# ------------------------------------------------------------------ height machinery


def sample_height(mf, w, t, u):
    """Next intersection of a ray along ``w`` from height t with U = ``u`` (Rust ``sample_height``):
    (t', hit); hit False when the ray leaves the microsurface."""
    e = optical_depth(u)
    up = w[2] > 0.0
    lam_up = mf.lambda_(w)  # ≥ 0 for an upward w
    lam_abs = mf.abs_lambda(w)  # ≥ 1 downward, ∞ horizontal
    t_up = t + e / lam_up
    t_down = t - e / lam_abs
    hit_up = (lam_up > 0.0) & (t_up < 0.0)
    hit_down = ~dr.isnan(t_down)
    return dr.select(up, t_up, t_down), dr.select(up, hit_up, hit_down)


def sample_height_hit(mf, w, t, u):
    """Next intersection conditioned on hitting (Rust ``sample_height_hit``): (t', P_hit) with
    P_hit = 1 − G1(ω, h) (1 downward, 0 when the ray surely leaves)."""
    up = w[2] > 0.0
    lam = mf.lambda_(w)
    # Upward: Exp(1) truncated to [0, −Λt), E = −ln(1 − U·P_hit).
    p_hit = -expm1(lam * t)
    u = dr.clip(u, 0.0, ONE_MINUS)
    t_up = t - log1p(-u * p_hit) / lam
    leaves = ~(lam > 0.0) | (t >= 0.0)
    horizontal = lam == dr.inf
    bad = ~(p_hit > 0.0) | dr.isnan(t_up)
    t_up_res = dr.select(leaves | bad, t, dr.select(horizontal, t, dr.minimum(t_up, 0.0)))
    p_up = dr.select(leaves, 0.0, dr.select(horizontal, 1.0, dr.select(bad, 0.0, dr.minimum(p_hit, 1.0))))
    # Downward: always hits (unless the height is NaN).
    t_down, hit_down = sample_height(mf, w, t, u)
    t_res = dr.select(up, t_up_res, dr.select(hit_down, t_down, t))
    p_res = dr.select(up, p_up, dr.select(hit_down, 1.0, 0.0))
    return t_res, p_res


def masking_at(lambda_w, t):
    """G1(ω, h) = e^{Λ(ω)·t} of an upward direction with Λ(ω) = ``lambda_w`` at height t (Rust
    ``masking_at``; the caller checks that ω points up)."""
    g = dr.exp(lambda_w * t)
    g = dr.select(dr.isfinite(g), g, 0.0)
    return dr.select(~(lambda_w > 0.0) | (t >= 0.0), 1.0, g)


# ------------------------------------------------------------------ phase function


def conductor_phase(mf, wi, wo):
    """The conductor phase function without Fresnel, D_ωi(h)/(4 ωi·h), and ωi·h (Rust
    ``conductor_phase``): (p, c, valid)."""
    h = wi + wo
    length = dr.norm(h)
    h = h / length
    c = dot(wi, h)
    p = mf.d_visible(wi, h) / (4.0 * c)
    valid = (length > 1e-12) & (c > 0.0) & (h[2] > 0.0) & dr.isfinite(p) & (p > 0.0)
    return dr.select(valid, p, 0.0), c, valid


def visible_normal(mf, wi, u1, u2):
    """A visible normal of ``wi`` (Rust ``visible_normal``): (m, ωi·m, valid)."""
    m, valid = mf.sample_visible(wi, u1, u2)
    c = dot(wi, m)
    return m, c, valid & dr.all(dr.isfinite(m)) & (c > 0.0)


def valid_incidence(w):
    """A conductor's direction must be finite and strictly above the macro surface."""
    return dr.all(dr.isfinite(w)) & (w[2] > 0.0)


# ------------------------------------------------------------------ the walks


def eval(mf, fresnel, wi, wo, max_bounces, key):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o, orders 1..max_bounces (Rust ``eval`` with
    ``eval_from``): the walk enters from ω_i at t = 0; at each vertex the height step is conditioned on
    hitting (the throughput carries P_hit), the path is closed towards ω_o (F · phase · G1(ω_o, h)), then
    the walk reflects about a visible normal and plays Russian roulette."""
    last = max_bounces  # a Python int, or a UInt32 per lane (model 'auto' style caps)
    lambda_o = mf.lambda_(wo)
    start = valid_incidence(wi) & valid_incidence(wo) & (last > 0)

    def body(order, wr, t, thr, result, active, counter):
        rng = Stream(key, counter)
        u_h, u_rr = rng.next2()
        tn, p_hit = sample_height_hit(mf, wr, t, u_h)
        active &= p_hit > 0.0
        t = tn
        thr = thr * p_hit
        wi_l = -wr
        # Next-event estimation towards ω_o: F · phase · G1(ω_o, h).
        p, c, ok = conductor_phase(mf, wi_l, wo)
        contrib = fresnel.eval(c) * (p * masking_at(lambda_o, t))
        result = dr.select(active & ok, result + thr * contrib, result)
        active &= order < last
        # Continue: reflect about a visible normal of wi_l, then the roulette.
        u1, u2 = rng.next2()
        m, cos_wm, valid = visible_normal(mf, wi_l, u1, u2)
        thr = thr * fresnel.eval(cos_wm)
        wr = dr.normalize(reflect(wi_l, m))
        thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0)
        active &= valid & survived & dr.all(dr.isfinite(wr))
        return order + 1, wr, t, thr, result, active, rng.counter

    state = (mi.UInt32(1), -mi.Vector3f(wi), mi.Float(0.0), mi.Spectrum(1.0), dr.zeros(mi.Spectrum),
             mi.Bool(start), mi.UInt32(0))
    state = dr.while_loop(state, lambda *s: s[5], body, label="msx_heitz_conductor_eval")
    return state[4]


def sample(mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling (supplement Algorithm 3; Rust ``sample`` with ``sample_from``): ``sample1``
    drives the first height, (u1, u2) the first visible normal, the lane's stream the rest. The walk exits
    when a height step leaves the microsurface; more than ``max_bounces`` vertices is invalid (the same
    truncation as ``eval``). Returns (ω_o, weight, valid), weight = the product of the Fresnel terms
    divided by the roulette's survival probabilities."""
    last = max_bounces  # a Python int, or a UInt32 per lane (model 'auto' style caps)
    start = valid_incidence(wi) & (last > 0)
    # The first height: the entering ray −ω_i points down and always hits.
    w0 = -mi.Vector3f(wi)
    t0, hit0 = sample_height(mf, w0, mi.Float(0.0), dr.select(dr.isfinite(sample1), sample1, 0.5))
    u1 = dr.clip(dr.select(dr.isfinite(u1), u1, 0.5), 0.0, ONE_MINUS)
    u2 = dr.clip(dr.select(dr.isfinite(u2), u2, 0.5), 0.0, ONE_MINUS)

    def body(order, wr, t, thr, done, active, counter, u1, u2):
        rng = Stream(key, counter)
        order = order + 1  # the vertex at height t
        wi_l = -wr
        m, cos_wm, valid = visible_normal(mf, wi_l, u1, u2)
        thr = thr * fresnel.eval(cos_wm)
        wr = dr.normalize(reflect(wi_l, m))
        u_rr, u_h = rng.next2()
        thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0)
        active &= valid & survived & dr.all(dr.isfinite(wr))
        # The next height: leaving ends the walk with ω_o = wr.
        tn, hit = sample_height(mf, wr, t, u_h)
        leaves = active & ~hit
        done = leaves & (wr[2] > 0.0) & dr.all(dr.isfinite(thr))
        active &= hit & (order < last)
        t = tn
        a, b = rng.next2()
        return order, wr, t, thr, done, active, rng.counter, a, b

    state = (mi.UInt32(0), w0, t0, mi.Spectrum(1.0), mi.Bool(False), mi.Bool(start & hit0), mi.UInt32(0),
             mi.Float(u1), mi.Float(u2))
    state = dr.while_loop(state, lambda *s: s[5], body, label="msx_heitz_conductor_sample")
    return state[1], state[3], state[4]


# The conductor walk this module provides (jit/bsdf.py collects it): height-correlated order-1 exit in
# the MIS density, and no walk from below the macro surface.
CONDUCTOR_WALKS = {"heitz": ConductorWalk(eval, sample, mis.HEIGHT_CORRELATED, below=False)}
