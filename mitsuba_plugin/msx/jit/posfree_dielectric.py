"""Position-free multiple scattering through a rough dielectric interface, Wang et al. 2022, in the Dr.Jit
engine: twin of the PT part of ``src/models/posfree/dielectric.rs`` (the vertex terms, the segment terms with
refraction, ``scatter``, the PT estimator with next-event estimation and the random-walk sampler).

Sides and frames (docs/conventions.md, "Frames and directions"): ``eta`` = η_int/η_ext, the exterior above
the macro surface. The walk works in the frame of the medium the light travels in: the identity outside, the
point reflection x → −x inside (``side`` = +1 / −1); there every medium sees the standard microsurface from
above with relative IOR η_f = η_t/η_i (η outside, 1/η inside), and a refraction switches the frame, i.e.
negates the travel direction. With L = L_j = |Λ(d_j)| and Λ = Λ(d_{j+1}) in the new direction's frame, the
segment factors are (dielectric.rs has the table and its derivation):

| factor                              | uncorrelated   | correlated      |
|---|---|---|
| c, reflected, going up              | Λ/(1+Λ)        | Λ/(L+Λ)         |
| c, refracted, going up (new frame)  | Λ/(1+Λ)        | 1 − L·B(L, 1+Λ) |
| c, going down                       | 1              | 1               |
| last, reflection to ω_o             | 1/(L(1+Λ_o))   | 1/(L+Λ_o)       |
| last, transmission to ω_o           | 1/(L(1+Λ_o))   | B(L, 1+Λ_o)     |

L·B(L, 1+Λ) = Γ(L+1)Γ(Λ+1)/Γ(L+Λ+1): the core takes it from ln Γ in float64; in float32 the three ln Γ
cancel (for Λ → 0 the result is O(Λ) against terms O(L ln L)), so ``ln_l_beta`` is written as a sum of
terms that are each O(min(L, Λ)) (shifted Stirling differences and log1p sums), and for L + Λ ≤ ½, where
the value is second order, −(π²/6)·LΛ + …, as the Taylor series of ln Γ(1 + x) with the LΛ factored out:
relative error below 1e-6 everywhere (python_tests/test_jit_dielectric.py checks it against mpmath).

Radiance mode carries Mitsuba's 1/η_r² of the macro pair once at the end (``radiance_scale``): the
refractions' (η_i/η_t)² telescope to it.

The walks are ``dr.while_loop``s whose state is the vertex index, w = −d_j in the current frame, L_j, the
frame sign, η_f, the throughput, the estimate, the lane's activity and its random stream (key, counter).
"""

import math
from functools import partial

import drjit as dr
import mitsuba as mi

from . import walk
from .dielectric import eta_seen, radiance_scale, reflect_or_refract
from .glass_traced import RR_TRACED_FLOOR, edge_point, eta_tangent_step, scatter_traced
from .microfacet import Microfacet, dot
from .model import DielectricWalk
from .posfree import CORRELATED, RR_START, UNCORRELATED, roulette_importance
from .rng import Stream

# dielectric.rs: the gain of the next-event value in the roulette's importance (measured there for
# dielectrics; larger than the conductors' 30).
RR_NEE_GAIN = 100.0

# The largest float32 below 1 (the core clamps a reused uniform number to 1 − ε/2 in float64).
ONE_MINUS_EPS = 1.0 - 2.0 ** -24

# Shift of the arguments before Stirling's series in ``ln_l_beta``, and the series' coefficients
# B_2k/(2k(2k−1)) of 1/z^(2k−1), k = 1..5: truncated after 1/z⁹, its error is below 691/(360360 z¹¹) < 5e-10
# for z ≥ 4.
_STIRLING_SHIFT = 3
_STIRLING = (1.0 / 12.0, -1.0 / 360.0, 1.0 / 1260.0, -1.0 / 1680.0, 1.0 / 1188.0)


# ------------------------------------------------------------------ float32 special functions


def log1p(x):
    """ln(1 + x) for x > −1 without cancellation (Goldberg's correction of ln(1 + x) by x/((1 + x) − 1))."""
    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * (x / (u - 1.0)))


def expm1(x):
    """eˣ − 1 without cancellation (Kahan: (eˣ − 1)·x/ln eˣ)."""
    u = dr.exp(x)
    um1 = u - 1.0
    return dr.select(u == 1.0, x, dr.select(um1 == -1.0, -1.0, um1 * (x / dr.log(u))))


def _stirling_tail_diff(x, b):
    """s(x + b) − s(x) of ln Γ(z) = (z − ½) ln z − z + ½ ln 2π + s(z), s(z) = Σ_k c_k/z^(2k−1) (x ≥ 4), as
    b times a sum of positive terms (no cancellation as b → 0): with r = 1/x, t = 1/(x + b),
    t^m − r^m = (t − r)·S_m, S_m = Σ_{i<m} t^i r^(m−1−i) (S_1 = 1, S_{m+1} = t·S_m + r^m), t − r = −b·r·t."""
    r = 1.0 / x
    t = 1.0 / (x + b)
    acc = _STIRLING[0] * 1.0
    s_m, r_m = mi.Float(1.0), r  # S_1, r^1
    for k in range(1, len(_STIRLING)):
        for _ in range(2):  # S_m → S_{m+2}
            s_m = t * s_m + r_m
            r_m = r_m * r
        acc = acc + _STIRLING[k] * s_m
    return -b * r * t * acc


# ζ(k), k = 2, 3, …: the Taylor coefficients of ln Γ(1 + x) = −γx + Σ_{k≥2} (−1)^k ζ(k) x^k / k.
_ZETA = (1.6449340668482264, 1.2020569031595942, 1.0823232337111381, 1.03692775514337, 1.0173430619844492,
         1.008349277381923, 1.0040773561979444, 1.0020083928260821, 1.000994575127818, 1.0004941886041194,
         1.000246086553308, 1.0001227133475785, 1.0000612481350588, 1.000030588236307, 1.0000152822594086,
         1.0000076371976379, 1.000003817293265, 1.0000019082127165, 1.0000009539620338, 1.0000004769329869,
         1.0000002384505027, 1.000000119219926, 1.000000059608189)
# a + b below which ``ln_l_beta`` takes the series (its truncation after the last ζ is < s^22 ≈ 2e-7 of the
# value at s = 1/2).
_SERIES_MAX = 0.5


def _ln_l_beta_series(a, b):
    """ln Γ(a+1) + ln Γ(b+1) − ln Γ(a+b+1) for a + b ≤ ½ from the Taylor series of ln Γ(1 + x): the −γ
    terms cancel exactly and the rest is −ab·Σ_{k≥2} (−1)^k ζ(k)/k·q_k with q_k = (s^k − a^k − b^k)/(ab),
    s = a + b, by the recurrences e_k = a^k + b^k = s·e_{k−1} − p·e_{k−2} and q_k = s·q_{k−1} + e_{k−2}
    (p = ab; every q_k a sum of positive terms)."""
    s, p = a + b, a * b
    e_prev, e = mi.Float(2.0), s  # e_0, e_1
    q = mi.Float(0.0)  # q_1
    total = mi.Float(0.0)
    for i, z in enumerate(_ZETA):
        k = i + 2
        q = s * q + e_prev  # q_k (uses e_{k−2})
        e_prev, e = e, s * e - p * e_prev  # e_{k−1}, e_k
        term = (z / k) * q
        total += term if k % 2 == 0 else -term
    return -p * total


def ln_l_beta(l, lam):
    """ln(L·B(L, 1+Λ)) = ln Γ(L+1) + ln Γ(Λ+1) − ln Γ(L+Λ+1) (≤ 0 for L, Λ ≥ 0); 0 when L or Λ is 0,
    −∞ when one is infinite (dielectric.rs ``ln_l_beta``).

    The value is symmetric in (L, Λ); let b = min, a = max. For a + b ≤ ½, ``_ln_l_beta_series`` (the
    value is −(π²/6)·ab + …, second order). Otherwise, with n = ``_STIRLING_SHIFT``, shifting every
    argument by n (Γ(x+1) = Γ(x+1+n)/∏_{k=1..n}(x+k)) and writing the differences of ln Γ of Stirling's
    series as D(x, b) = ln Γ(x+b) − ln Γ(x) = (x − ½) log1p(b/x) + b ln(x+b) − b + s(x+b) − s(x) gives

        D(n+1, b) − D(a+n+1, b) + Σ_{k=1..n} log1p(−ab/((a+k)(k+b)))

    (the sum is Σ [log1p(b/(a+k)) − log1p(b/k)]), whose terms are each O(b) (the −b and the b ln terms
    combine into −b·log1p(a/(n+1+b))): float32 keeps its relative precision as b → 0, where the core's
    three ln Γ would cancel."""
    l, lam = mi.Float(l), mi.Float(lam)
    a, b = dr.maximum(l, lam), dr.minimum(l, lam)
    n = float(_STIRLING_SHIFT)
    x0, x1 = n + 1.0, a + n + 1.0
    v = ((n + 0.5) * log1p(b / x0) - (a + n + 0.5) * log1p(b / x1) - b * log1p(a / (x0 + b))
         + _stirling_tail_diff(x0, b) - _stirling_tail_diff(x1, b))
    for k in range(1, _STIRLING_SHIFT + 1):
        # log1p(b/(a+k)) − log1p(b/k) = log1p(−ab/((a+k)(k+b))), the argument in (−1, 0].
        v += log1p(-(a / (a + k)) * (b / (b + k)))
    v = dr.select(a + b <= _SERIES_MAX, _ln_l_beta_series(a, b), v)
    v = dr.minimum(v, 0.0)
    v = dr.select(dr.isfinite(l) & dr.isfinite(lam), v, -dr.inf)
    return dr.select((lam == 0.0) | (l == 0.0), 0.0, v)


def l_beta(l, lam):
    """L·B(L, 1+Λ) = Γ(L+1)Γ(Λ+1)/Γ(L+Λ+1) ∈ [0, 1] (dielectric.rs ``l_beta``)."""
    return dr.exp(ln_l_beta(l, lam))


def beta(a, b):
    """The Beta function B(a, b) for a, b > 0 (dielectric.rs ``beta``, which the PT does not use): B(a, b) =
    exp(ln_l_beta(a, b − 1))/a for b ≥ 1, and B(a, b) = B(a, b + 1)·(a + b)/b below."""
    a, b = mi.Float(a), mi.Float(b)
    small = b < 1.0
    bb = dr.select(small, b + 1.0, b)
    v = dr.exp(ln_l_beta(a, bb - 1.0)) / a
    return dr.select(small, v * (a + b) / b, v)


# ------------------------------------------------------------------ segment and vertex terms


def continue_up(segments, refracted, l, lam):
    """Continue factor c of the table for an upward new direction with Λ (``refracted`` a mask)."""
    if segments == UNCORRELATED:
        c = lam / (1.0 + lam)
    else:
        c = dr.select(refracted, -expm1(ln_l_beta(l, lam)), lam / (l + lam))
    c = dr.select(dr.isfinite(c), dr.clip(c, 0.0, 1.0), dr.select(refracted, 0.0, 1.0))
    return dr.select(dr.isinf(lam), 1.0, c)


def last(segments, refracted, l, lambda_o):
    """Last-segment factor p_j·e_k for an exiting ω_o with Λ_o (in its medium's frame)."""
    if segments == UNCORRELATED:
        v = 1.0 / (l * (1.0 + lambda_o))
    else:
        v = dr.select(refracted, l_beta(l, lambda_o) / l, 1.0 / (l + lambda_o))
    return dr.select(dr.isfinite(v), dr.maximum(v, 0.0), 0.0)


def vertex_reflect(mf, eta_f, w, o):
    """Reflection vertex term F·D(h)/(4|w_z|) towards o (current frame, o.z > 0)."""
    h = w + o
    length = dr.norm(h)
    h = h / length
    cw = dot(w, h)
    ok = (length > 0.0) & (cw > 0.0) & (dot(o, h) > 0.0)
    f = mi.fresnel(cw, eta_f)[0]
    v = f * mf.d(h) / (4.0 * dr.abs(w[2]))
    return dr.select(ok & dr.isfinite(v), v, 0.0)


def vertex_transmit(mf, eta_f, w, o):
    """Transmission vertex term (Wang eq. 3, Walter's half vector) towards o (current frame, o.z < 0):
    |w·h||o·h|·η_f²(1−F)·D(h)/(|w_z|(w·h + η_f o·h)²), h = −(w + η_f o) oriented upward."""
    h = -(w + eta_f * o)
    length = dr.norm(h)
    h = h / length
    h = dr.select(h[2] < 0.0, -h, h)
    cw, co = dot(w, h), dot(o, h)
    f = mi.fresnel(cw, eta_f)[0]
    ok = (length > 0.0) & dr.isfinite(length) & (cw > 0.0) & (co < 0.0) & (f < 1.0)
    denom = cw + eta_f * co
    v = cw * (-co) * eta_f * eta_f * (1.0 - f) * mf.d(h) / (dr.abs(w[2]) * denom * denom)
    return dr.select(ok & dr.isfinite(v), dr.maximum(v, 0.0), 0.0)


def initial_state(mf, eta, wi):
    """(w, L, side, η_f) of a walk entering from ω_i (dielectric.rs ``State::new``)."""
    side = dr.select(wi[2] > 0.0, mi.Float(1.0), mi.Float(-1.0))
    w = side * wi
    return w, mf.abs_lambda(-w), side, eta_seen(eta, side > 0.0)


def scatter(mf, w, side, eta_f, u_choice, u1, u2):
    """One vertex: m ~ D_w, reflect with probability F or refract (the frame switched on a refraction).
    Returns (d in the new frame, refracted, F, side, η_f, valid)."""
    m, valid = mf.sample_visible(w, u1, u2)
    cos_wm = dot(w, m)
    valid &= cos_wm > 0.0
    d, refracted, f = reflect_or_refract(w, m, cos_wm, eta_f, u_choice)
    d = dr.select(refracted, -d, d)
    side = dr.select(refracted, -side, side)
    eta_f = dr.select(refracted, 1.0 / eta_f, eta_f)
    return d, refracted, f, side, eta_f, valid


def eta_edge_term(segments, mf, w, tw, l, side, eta_f, teta_f, wo, lambda_o, refracted, u):
    """The term of ∂/∂η a next-event value misses at the vertex after this one, for the branch ``refracted``
    (a Python bool) of this vertex's event (docs/gradients.md, "The IOR of the glass walks"). In the space of
    normals the walk's only moving discontinuity is the next vertex's value towards ω_o, which jumps to 0 on
    the circle w'_z = z* where its half-vector turns horizontal (z* = −o_z for a reflection, −η_f·o_z for a
    transmission): the term is ∫ over that circle of the next direction's density (this event's phase
    function, its continue factor), the next value's limit and the relative speed ±(u_z − ∂z*/∂η), dφ —
    estimated with one uniform azimuth (``u``). u_z is ∂w'_z/∂η at the fixed normal that maps w to w'."""
    side_b = -side if refracted else side
    w_next, transmit, density, value, speed, ok = edge_point(mf, w, tw, side_b * wo, eta_f, teta_f, refracted, u)
    d_new = -w_next
    up = d_new[2] > 0.0
    lam = mf.abs_lambda(d_new)
    c = dr.select(up, continue_up(segments, mi.Bool(refracted), l, lam), 1.0)
    term = 2.0 * math.pi * density * c * value * last(segments, transmit, lam, lambda_o) * speed
    return dr.select(ok & dr.isfinite(term), term, 0.0)


def valid_inputs(eta, wi):
    return dr.isfinite(eta) & (eta > 0.0) & (wi[2] != 0.0) & dr.all(dr.isfinite(wi))


# ------------------------------------------------------------------ the estimators


def eval_pt(segments, mf, eta, radiance, wi, wo, max_bounces, key, mf_sample=None):
    """One PT estimate of f(ω_i, ω_o)·|cos θ_o| (orders 1..max_bounces) with next-event estimation to ω_o
    at every vertex (by reflection on ω_o's side, by transmission across), Russian roulette from vertex
    ``RR_START`` on; Radiance mode's 1/η_r² applied once (dielectric.rs ``eval_pt`` and ``pt_walk``).

    ``mf_sample`` (docs/gradients.md, "The IOR of the glass walks"): the statistics with their derivatives
    detached (the IOR too). Each vertex then draws its normal and its reflect-or-refract choice with the
    detached parameters (``scatter_traced``), computes the new direction from them with the attached ones,
    and the throughput carries the ratio of the normal's and the choice's density under the attached
    parameters to the detached draw's; the roulette is detached and keeps a floor (RR_TRACED_FLOOR); each
    vertex adds, as a derivative only, the term of the next vertex's moving edge (``eta_edge_term``) for
    both of its events, with the tangent of w in η carried in the state. The estimate's derivative in α and
    in η is then unbiased."""
    eta = mi.Float(eta)
    wi, wo = mi.Vector3f(wi), mi.Vector3f(wo)
    start = valid_inputs(eta, wi) & (wo[2] != 0.0) & dr.all(dr.isfinite(wo))
    # ω_o's Λ in the frame of the medium it exits into (upward there).
    lambda_o = mf.lambda_(dr.select(wo[2] > 0.0, wo, -wo))
    w0, l0, side0, eta_f0 = initial_state(mf, eta, wi)
    traced = mf_sample is not None
    eta_traced = traced and dr.grad_enabled(eta)  # the edge terms are derivatives in η only

    def body(j, w, l, side, eta_f, thr, result, active, counter, *piped):
        mfa, mfs, lo, efa, efs = mf, mf, lambda_o, eta_f, eta_f
        if traced:  # the differentiated values come through the state (drjit rejects implicit wide reads)
            au, av, lo, eta_a, tw = piped
            mfa = Microfacet(mf.dist, au, av)
            mfs = Microfacet(mf.dist, dr.detach(au), dr.detach(av))
            efa = eta_seen(eta_a, side > 0.0)
            efs = dr.detach(efa)
        rng = Stream(key, counter)
        o = side * wo  # ω_o in the current frame
        transmit = o[2] < 0.0
        lst = last(segments, transmit, l, lo)
        v = lst * dr.select(transmit, vertex_transmit(mfa, efa, w, o), vertex_reflect(mfa, efa, w, o))
        u_rr, u_choice = rng.next2()
        kept, survived = walk.russian_roulette_keep(thr, u_rr, 1.0 / roulette_importance(v, lst, RR_NEE_GAIN),
                                                    RR_TRACED_FLOOR if traced else 0.0)
        play = j >= RR_START
        thr = dr.select(play, kept, thr)
        active &= ~play | survived
        result = dr.select(active, result + thr * v, result)
        active &= j + 1 < max_bounces
        u1, u2 = rng.next2()
        if traced:
            # ∂/∂η of the next vertex's value along its moving edge, for either event here (detached: it
            # enters as (η − η̄)·term, a derivative only).
            ws, teta = dr.detach(w), dr.select(side > 0.0, 1.0, -efs * efs)
            u_e1, u_e2 = rng.next2()  # drawn in every traced call: the same stream with η differentiated or not
            u_mix = rng.next()
            if eta_traced:
                edge = sum(eta_edge_term(segments, mfs, ws, tw, dr.detach(l), side, efs, teta, wo, dr.detach(lo),
                                         b, u_e) for b, u_e in ((False, u_e1), (True, u_e2)))
                result = dr.select(active, result + (eta_a - dr.detach(eta_a)) * dr.detach(thr) * edge, result)
            d, refracted, side, valid, weight, m = scatter_traced(mfa, mfs, w, side, efa, u_choice, u1, u2, u_mix)
            tw = eta_tangent_step(ws, tw, m, efs, teta, refracted)
            piped = (au, av, lo, eta_a, tw)
            eta_f = dr.select(refracted, 1.0 / eta_f, eta_f)
            thr = thr * weight
        else:
            d, refracted, _, side, eta_f, valid = scatter(mfs, w, side, efs, u_choice, u1, u2)
        active &= valid
        up = d[2] > 0.0
        lam = mfa.abs_lambda(d)
        thr = dr.select(up, thr * continue_up(segments, refracted, l, lam), thr)
        active &= ~up | ((lam > 0.0) & (thr > 0.0))
        return (j + 1, -d, lam, side, eta_f, thr, result, active, rng.counter) + piped

    state = (mi.UInt32(0), w0, l0, side0, eta_f0, mi.Float(1.0), mi.Float(0.0), mi.Bool(start), mi.UInt32(0))
    if traced:
        state += (mf.alpha_u, mf.alpha_v, mi.Float(lambda_o), mi.Float(eta), mi.Vector3f(0.0))
    state = dr.while_loop(state, lambda *s: s[7], body, label="msx_posfree_dielectric_pt")
    return state[6] * radiance_scale(eta, radiance, wi[2] > 0.0, wo[2] > 0.0)


def sample_walk(segments, mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampler: at each vertex m ~ D_w, reflect with probability F or refract, and an upward
    direction (in its medium's frame) leaves with probability 1 − c, so the weight is 1 (× Mitsuba's 1/η_r²
    for a transmission in Radiance mode). The first vertex uses (sample1, u1, u2); sample1, rescaled to
    [0, 1) within the chosen branch, also decides the first exit; later vertices use the lane's stream.
    Returns (ω_o, weight, valid); invalid when no visible normal or the bounce cap is reached."""
    eta = mi.Float(eta)
    wi = mi.Vector3f(wi)
    w0, l0, side0, eta_f0 = initial_state(mf, eta, wi)
    s1, v1, v2 = mi.Float(sample1), mi.Float(u1), mi.Float(u2)

    def body(j, w, l, side, eta_f, done, active, counter):
        rng = Stream(key, counter)
        c_r, e_r = rng.next2()
        a_r, b_r = rng.next2()
        first = j == 0
        u_choice = dr.select(first, s1, c_r)
        d, refracted, f, side, eta_f, valid = scatter(mf, w, side, eta_f, u_choice,
                                                      dr.select(first, v1, a_r), dr.select(first, v2, b_r))
        up = d[2] > 0.0
        lam = mf.abs_lambda(d)
        c = continue_up(segments, refracted, l, lam)
        u = dr.select(refracted, (u_choice - f) / (1.0 - f), u_choice / f)
        u = dr.select(dr.isfinite(u), dr.clip(u, 0.0, ONE_MINUS_EPS), e_r)
        u_exit = dr.select(first, u, e_r)
        leaves = up & (u_exit >= c)
        done = valid & leaves
        active = valid & ~leaves & (j + 1 < max_bounces)
        return j + 1, -d, lam, side, eta_f, done, active, rng.counter

    state = (mi.UInt32(0), w0, l0, side0, eta_f0, mi.Bool(False), mi.Bool(valid_inputs(eta, wi)), mi.UInt32(0))
    state = dr.while_loop(state, lambda *s: s[6], body, label="msx_posfree_dielectric_sample")
    _, w, _, side, _, done, _, _ = state
    wo = -side * w
    return wo, radiance_scale(eta, radiance, wi[2] > 0.0, wo[2] > 0.0), done


# The dielectric walks this module provides, by model name (jit/bsdf.py collects them).
DIELECTRIC_WALKS = {
    name: DielectricWalk(partial(eval_pt, name), partial(sample_walk, name), differentiable=True,
                         eta_differentiable=True)
    for name in (UNCORRELATED, CORRELATED)
}
