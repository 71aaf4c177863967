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

L·B(L, 1+Λ) = Γ(L+1)Γ(Λ+1)/Γ(L+Λ+1) is ``special.l_beta`` (float32 without the cancellation of three ln Γ).

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
from .dielectric import eta_seen, radiance_scale, reflect_or_refract, transmit_half_vector
from .glass_traced import RR_TRACED_FLOOR, edge_point, eta_tangent_step, scatter_traced
from .gradients import LoopValues
from .microfacet import BECKMANN, GGX, dot, half_vector, normalized
from .model import DielectricWalk
from .posfree import CORRELATED, RR_LAST_WEIGHT, RR_START, UNCORRELATED, roulette_importance
from .rng import ONE_MINUS_EPS, Stream
from .special import erfcx_deficit, expm1_ratio, l_beta, ln_l_beta, log1p

# dielectric.rs: the gain of the next-event value in the roulette's importance (measured there for
# dielectrics; larger than the conductors' 30).
RR_NEE_GAIN = 100.0

# ------------------------------------------------------------------ segment and vertex terms


def continue_up(segments, refracted, l, lam, branch=False):
    """Continue factor c of the table for an upward new direction with Λ (``refracted`` a mask; ``branch``:
    ``special.ln_l_beta``'s per-packet forms, for the walks without derivatives)."""
    if segments == UNCORRELATED:
        c = lam / (1.0 + lam)
    else:
        if branch:  # only in packets with a refracted lane (same bits)
            x = dr.if_stmt((l, lam), refracted, lambda l, lam: ln_l_beta(l, lam, True),
                           lambda l, lam: dr.zeros(mi.Float, dr.width(l)), label="msx_posfree_continue_refracted")
        else:
            x = ln_l_beta(l, lam)
        c = dr.select(refracted, -expm1_ratio(x), lam / (l + lam))
    c = dr.select(dr.isfinite(c), dr.clip(c, 0.0, 1.0), dr.select(refracted, 0.0, 1.0))
    return dr.select(dr.isinf(lam), 1.0, c)


def last(segments, refracted, l, lambda_o, branch=False):
    """Last-segment factor p_j·e_k for an exiting ω_o with Λ_o (in its medium's frame; ``branch`` as in
    ``continue_up``)."""
    if segments == UNCORRELATED:
        v = 1.0 / (l * (1.0 + lambda_o))
    else:
        if branch:  # only in packets with a lane across (same bits)
            lb = dr.if_stmt((l, lambda_o), refracted, lambda l, lo: l_beta(l, lo, True),
                            lambda l, lo: dr.zeros(mi.Float, dr.width(l)), label="msx_posfree_last_across")
        else:
            lb = l_beta(l, lambda_o)
        v = dr.select(refracted, lb / l, 1.0 / (l + lambda_o))
    return dr.select(dr.isfinite(v), dr.maximum(v, 0.0), 0.0)


# The log domain of a traced walk along moving directions (``eval_pt`` with ``direction_tangent``). After a
# step going up near the normal, Λ is tiny (Beckmann α 0.5: below 10⁻¹⁵ within ~20° of the normal, subnormal
# near 11°); its continue factor c ~ Λ and the next vertex's last factor ~ 1/Λ make an O(1) product, but AD of
# 1/Λ forms −dΛ/Λ², which overflows in float32 (NaN lanes: docs/gradients.md). In logs every derivative is a
# relative one, d ln Λ = dΛ/Λ, finite as long as Λ is a normal float: ``log_abs_lambda`` writes Beckmann's
# ln Λ from its formula where Λ is below LOG_LAMBDA_FORMULA (its subnormals included).
LOG_LAMBDA_FORMULA = 1e-30
# Below this Λ, x/Λ (x = ln(L·B(L, 1+Λ)) = O(Λ)) of a correlated refraction's continue factor is taken at
# this Λ: x/Λ = −(ψ(L+1) − ψ(1))·(1 + O(Λ)), equal to float32's last bit, and its quotient's derivative,
# which divides by Λ², stays finite.
LAMBDA_RATIO_MIN = 1e-15
LOG_SQRT_PI_2 = math.log(0.5 / math.sqrt(math.pi))


def _log_pos(x):
    """(ln x, x > 0) with a finite derivative where x is not positive (those lanes are masked by the caller)."""
    ok = x > 0.0
    return dr.log(dr.select(ok, x, 1.0)), ok


def log_abs_lambda(mf, d, lam):
    """ln |Λ(d)| (``lam`` = ``mf.abs_lambda(d)``, its value): ln of it where it is ≥ LOG_LAMBDA_FORMULA or
    downward (1 + Λ ≥ 1); Beckmann's tiny upward Λ = e^{−a²}·(1 − a²ε)·d(a)/(2√π a) (beckmann.lambda_up,
    a = 1/(α tan θ)) in logs, −a² + ln(1 − a²ε) + ln d(a) − ln a + ln(1/(2√π)), whose derivative is finite
    where Λ itself is subnormal."""
    log_lam, _ = _log_pos(lam)
    if mf.dist != BECKMANN:
        return log_lam
    r = mf.alpha_tan2(d)
    tiny = (d[2] > 0.0) & (lam < LOG_LAMBDA_FORMULA) & (lam > 0.0)
    rs = dr.select(tiny & (r > 0.0), r, 1.0)
    a2 = 1.0 / rs
    e = dr.fma(-a2, rs, 1.0)
    a2c = dr.minimum(a2, 1000.0)
    a = dr.sqrt(a2c)
    formula = -a2c + dr.log(1.0 - a2c * e) + dr.log(erfcx_deficit(a)) + 0.5 * dr.log(rs) + LOG_SQRT_PI_2
    return dr.select(tiny, formula, log_lam)


def _log_add(x, y):
    """ln(e^x + e^y) without forming either exponential."""
    hi, lo = dr.maximum(x, y), dr.minimum(x, y)
    return hi + log1p(dr.exp(lo - hi))


def log_continue_up(segments, refracted, l, log_l, lam, log_lam):
    """(ln c, c > 0) of an upward new direction with Λ (``continue_up`` in logs, c ≤ 1): ln Λ − ln(1 + Λ)
    (uncorrelated), ln Λ − ln(L + Λ) (correlated reflection), and for a correlated refraction
    c = −expm1(x) = (expm1(x)/x)·(x/Λ)·(−Λ), x = ln(L·B(L, 1+Λ)), so ln c = ln(expm1(x)/x) + ln(−x/Λ) + ln Λ
    (x/Λ at Λ ≥ LAMBDA_RATIO_MIN)."""
    if segments == UNCORRELATED:
        v = log_lam - log1p(lam)
    else:
        lam_c = dr.maximum(lam, LAMBDA_RATIO_MIN)
        x = ln_l_beta(l, lam)
        e = expm1_ratio(x)
        # expm1(x)/x, by its series where the quotient's derivative would divide by x² (|x| < 10⁻⁴: the
        # series' error x³/24 is below float32's rounding).
        small = dr.abs(x) < 1e-4
        expm1_over_x = dr.select(small, 1.0 + x * (0.5 + x * (1.0 / 6.0)), e / dr.select(small, 1.0, x))
        log_ratio, _ = _log_pos(-ln_l_beta(l, lam_c) / lam_c)
        v_refracted = dr.log(expm1_over_x) + log_ratio + log_lam
        v = dr.select(refracted, v_refracted, log_lam - _log_add(log_l, log_lam))
    v = dr.minimum(v, 0.0)
    return v, (lam > 0.0) & dr.isfinite(lam) & dr.isfinite(v)


def log_last(segments, refracted, l, log_l, lambda_o):
    """(ln ``last``, finite): −ln L − ln(1 + Λ_o) (uncorrelated); −ln(L + Λ_o) and ln(L·B(L, 1+Λ_o)) − ln L
    (correlated, reflection and transmission)."""
    if segments == UNCORRELATED:
        v = -log_l - log1p(lambda_o)
    else:
        log_o, o_ok = _log_pos(lambda_o)
        v_reflect = -dr.select(o_ok, _log_add(log_l, log_o), log_l)
        v = dr.select(refracted, ln_l_beta(l, lambda_o) - log_l, v_reflect)
    return v, dr.isfinite(v) & (l > 0.0)


def vertex_reflect(mf, eta_f, w, o):
    """Reflection vertex term F·D(h)/(4|w_z|) towards o (current frame, o.z > 0)."""
    h, length = half_vector(w, o)
    cw = dot(w, h)
    ok = (length > 0.0) & (cw > 0.0) & (dot(o, h) > 0.0)
    f = mi.fresnel(cw, eta_f)[0]
    v = f * mf.d(h) / (4.0 * dr.abs(w[2]))
    return dr.select(ok & dr.isfinite(v), v, 0.0)


def vertex_transmit(mf, eta_f, w, o):
    """Transmission vertex term (Wang eq. 3, Walter's half vector) towards o (current frame, o.z < 0):
    |w·h||o·h|·η_f²(1−F)·D(h)/(|w_z|(w·h + η_f o·h)²), h = −(w + η_f o) oriented upward."""
    h, length = normalized(transmit_half_vector(w, o, eta_f))
    cw, co = dot(w, h), dot(o, h)
    f = mi.fresnel(cw, eta_f)[0]
    ok = (length > 0.0) & dr.isfinite(length) & (cw > 0.0) & (co < 0.0) & (f < 1.0)
    denom = cw + eta_f * co
    v = cw * (-co) * eta_f * eta_f * (1.0 - f) * mf.d(h) / (dr.abs(w[2]) * denom * denom)
    return dr.select(ok & dr.isfinite(v), dr.maximum(v, 0.0), 0.0)


def vertex_next_event(mf, eta_f, w, o, transmit):
    """``vertex_transmit`` where ``transmit`` (a mask), else ``vertex_reflect``, with one half vector, one
    Fresnel factor and one D: each lane rounds the same operations as the function of its branch (the same
    bits), at about half the cost of computing both and selecting."""
    h, length = normalized(dr.select(transmit, transmit_half_vector(w, o, eta_f), w + o))
    cw, co = dot(w, h), dot(o, h)
    f = mi.fresnel(cw, eta_f)[0]
    d = mf.d(h)
    v_r = f * d / (4.0 * dr.abs(w[2]))
    v_r = dr.select((length > 0.0) & (cw > 0.0) & (co > 0.0) & dr.isfinite(v_r), v_r, 0.0)
    denom = cw + eta_f * co
    v_t = cw * (-co) * eta_f * eta_f * (1.0 - f) * d / (dr.abs(w[2]) * denom * denom)
    ok_t = (length > 0.0) & dr.isfinite(length) & (cw > 0.0) & (co < 0.0) & (f < 1.0)
    v_t = dr.select(ok_t & dr.isfinite(v_t), dr.maximum(v_t, 0.0), 0.0)
    return dr.select(transmit, v_t, v_r)


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


def eta_edge_term(segments, mf, w, tw, l, side, eta_f, teta_f, wo, lambda_o, refracted, u, two=None):
    """The term of ∂/∂η a next-event value misses at the vertex after this one, for the branch ``refracted``
    (a Python bool) of this vertex's event (docs/gradients.md, "The IOR of the glass walks"). In the space of
    normals the walk's only moving discontinuity is the next vertex's value towards ω_o, which jumps to 0 on
    the circle w'_z = z* where its half-vector turns horizontal (z* = −o_z for a reflection, −η_f·o_z for a
    transmission): the term is ∫ over that circle of the next direction's density (this event's phase
    function, its continue factor), the next value's limit and the relative speed ±(u_z − ∂z*/∂η), dφ —
    estimated with one uniform azimuth (``u``). u_z is ∂w'_z/∂η at the fixed normal that maps w to w'.
    ``two``: along moving directions instead (docs/gradients.md, "Directions through the walks"), the tangent
    of ω_o, ``tw`` that of w and ``teta_f`` 0: the same circle moves with ω_o and with w."""
    side_b = -side if refracted else side
    to = None if two is None else side_b * two
    w_next, transmit, density, value, speed, ok = edge_point(mf, w, tw, side_b * wo, eta_f, teta_f, refracted, u,
                                                             to)
    d_new = -w_next
    up = d_new[2] > 0.0
    lam = mf.abs_lambda(d_new)
    c = dr.select(up, continue_up(segments, mi.Bool(refracted), l, lam), 1.0)
    term = 2.0 * math.pi * density * c * value * last(segments, transmit, lam, lambda_o) * speed
    return dr.select(ok & dr.isfinite(term), term, 0.0)


def valid_inputs(eta, wi):
    return dr.isfinite(eta) & (eta > 0.0) & (wi[2] != 0.0) & dr.all(dr.isfinite(wi))


def next_event(segments, mf, eta_f, w, l, o, lambda_o, traced=False):
    """(last·v, last): the next event towards o (ω_o in the current frame) at a vertex the walk reached along
    w with L = ``l``, without the throughput — by reflection where o is on the walk's side, by transmission
    across (dielectric.rs ``next_event``). ``traced``: both vertex terms selected (a differentiated walk)."""
    transmit = o[2] < 0.0
    lst = last(segments, transmit, l, lambda_o, branch=not traced)
    if traced:
        return lst * dr.select(transmit, vertex_transmit(mf, eta_f, w, o), vertex_reflect(mf, eta_f, w, o)), lst
    return lst * vertex_next_event(mf, eta_f, w, o, transmit), lst


def lambda_out(mf, wo):
    """ω_o's Λ in the frame of the medium it exits into (upward there)."""
    return mf.lambda_(dr.select(wo[2] > 0.0, wo, -wo))


# ------------------------------------------------------------------ order 1 in closed form
# (``auto``'s reduced calls; twins of ``order_one_eval``, ``order_one_pdf``, ``order_one_sample`` (here
# ``order_one_finish``, from ``sample_first_vertex``) in
# src/models/posfree/dielectric.rs)


# Λ_o below which order 1's transmission factor L·B(L, 1+Λ_o) is 1 in float32: ln(L·B(L, 1+Λ)) =
# −Λ·(ψ(L+1) − ψ(1)) + O(Λ²), and ψ(L+1) − ψ(1) < 1 + ln(L + 1) stays below 30 for any L a float32 Λ_i gives
# (L < e^29), so at Λ < 1e-9 the logarithm is above −3e-8 and its exponential rounds to 1 (or its neighbour
# below: at most one rounding step from ``l_beta``).
ORDER_ONE_LAMBDA_NEGLIGIBLE = 1e-9


def _order_one_last(segments, transmit, l, lambda_o):
    """``last`` at the walk's first vertex with ``l_beta`` computed only in the packets that have a transmitting
    lane whose Λ_o is not negligible (ORDER_ONE_LAMBDA_NEGLIGIBLE; its Stirling form is most of order 1's
    cost, and on a smooth surface Λ_o underflows for most directions: Beckmann α 0.1 below ≈ 66° from the
    normal)."""
    if segments != CORRELATED:
        return last(segments, transmit, l, lambda_o)
    need = transmit & (lambda_o >= ORDER_ONE_LAMBDA_NEGLIGIBLE)
    lb = dr.if_stmt((l, lambda_o), need, lambda l, lo: l_beta(l, lo),
                    lambda l, lo: dr.full(mi.Float, 1.0, dr.width(l)), label="msx_posfree_order_one_across")
    v = dr.select(transmit, dr.select(need, lb, 1.0) / l, 1.0 / (l + lambda_o))
    return dr.select(dr.isfinite(v), dr.maximum(v, 0.0), 0.0)


def _order_one_start(eta, wi, wo):
    return valid_inputs(eta, wi) & (wo[2] != 0.0) & dr.all(dr.isfinite(wo))


def order_one_eval(segments, mf, eta, radiance, wi, wo):
    """Order 1 of the PT estimator: the walk's next event at its first vertex (``eval_pt`` capped at one
    vertex, the same operations: the same bits), Radiance mode's 1/η_r² included. Deterministic."""
    eta, wi, wo = mi.Float(eta), mi.Vector3f(wi), mi.Vector3f(wo)
    w, l, side, eta_f = initial_state(mf, eta, wi)
    o = side * wo
    transmit = o[2] < 0.0
    v = _order_one_last(segments, transmit, l, lambda_out(mf, wo)) * vertex_next_event(mf, eta_f, w, o, transmit)
    return dr.select(_order_one_start(eta, wi, wo), v, 0.0) * radiance_scale(eta, radiance, wi[2] > 0.0,
                                                                              wo[2] > 0.0)


def order_one_pdf(mf, eta, wi, wo):
    """The density of ``order_one_finish``'s ω_o: v(ω_o)/L_0 (the visible normal of ω_i, then reflection with
    probability F on ω_i's side or refraction across, with the branch's Jacobian)."""
    eta, wi, wo = mi.Float(eta), mi.Vector3f(wi), mi.Vector3f(wo)
    w, l, side, eta_f = initial_state(mf, eta, wi)
    o = side * wo
    p = vertex_next_event(mf, eta_f, w, o, o[2] < 0.0) / l
    return dr.select(_order_one_start(eta, wi, wo) & dr.isfinite(p), p, 0.0)


def order_one_finish(segments, mf, eta, radiance, wi, first_vertex):
    """Order 1's sample (twin of ``order_one_sample`` in dielectric.rs) from the walk's first vertex,
    ``sample_first_vertex``'s: the same direction as the walk where the
    new direction leaves the surface, (ω_o, pdf, weight, valid) with pdf = ``order_one_pdf`` and weight =
    eval/pdf = L_0·last × Radiance mode's 1/η_r² — the probability of the walk's exit there instead of a random
    exit. Invalid where the direction goes down in its frame (the walk would go on) or has no density."""
    eta, wi = mi.Float(eta), mi.Vector3f(wi)
    init, after, (d, refracted, _, valid, _, _, _) = first_vertex
    l0 = init["l"]
    wo = after["side"] * d
    pdf = order_one_pdf(mf, eta, wi, wo)
    valid &= init["active"] & (d[2] > 0.0) & (pdf > 0.0)
    weight = l0 * _order_one_last(segments, refracted, l0, after["l"])
    weight = weight * radiance_scale(eta, radiance, wi[2] > 0.0, wo[2] > 0.0)
    return wo, pdf, dr.select(valid, weight, 0.0), valid


# ------------------------------------------------------------------ the estimators


def eval_pt(segments, mf, eta, radiance, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
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
    in η is then unbiased.

    ``direction_tangent`` (traced only; docs/gradients.md, "Directions through the walks"): (s, t_i, t_o)
    while one coordinate s of ω_i, ω_o is differentiated (gradients.TangentCoordinates). ω_i enters the
    first state attached, ω_o and its tangent travel in the loop's state, and the normals are drawn as above
    (the draw's weight D_w(m)/p(m) is the density ratio in w too). The throughput is then carried in logs: a
    step going up near the normal has a tiny Λ, its continue factor c ~ Λ and the next vertex's last factor
    ~ 1/Λ, whose derivative −dΛ/Λ² overflows in float32 although the product is O(1); in logs the walk adds
    ln c (``log_continue_up``), ln of the draw's weight times L over L (``scatter_traced(times_area=True)``)
    and ln last (``log_last``), whose derivatives are relative ones (dΛ/Λ), and never forms 1/Λ. On GGX each
    vertex adds the next vertex's edge terms along s (``eta_edge_term`` with the tangent of ω_o), the tangent
    of w carried in the state."""
    eta = mi.Float(eta)
    wi, wo = mi.Vector3f(wi), mi.Vector3f(wo)
    start = valid_inputs(eta, wi) & (wo[2] != 0.0) & dr.all(dr.isfinite(wo))
    lambda_o = lambda_out(mf, wo)
    w0, l0, side0, eta_f0 = initial_state(mf, eta, wi)
    traced = mf_sample is not None
    eta_traced = traced and dr.grad_enabled(eta)  # the edge terms are derivatives in η only
    dirs = traced and direction_tangent is not None  # a pass along one coordinate of the directions
    dir_edges = dirs and mf.dist != BECKMANN  # Beckmann's D vanishes at horizontal normals: no edge

    def body(j, w, l, side, eta_f, thr, result, active, counter, piped):
        mfa, mfs, lo, efa, efs, wo_ = mf, mf, lambda_o, eta_f, eta_f, wo
        if traced:  # the differentiated values come through the state (gradients.LoopValues)
            lv = LoopValues(mf.dist, piped)
            mfa, mfs, lo = lv.mf, lv.mf_sample, lv.lambda_o
            if dirs:
                eta_a, tw, wo_, s_dir, two, log_l = lv.rest
            else:
                eta_a, tw = lv.rest
            efa = eta_seen(eta_a, side > 0.0)
            efs = dr.detach(efa)
        rng = Stream(key, counter)
        o = side * wo_  # ω_o in the current frame
        transmit = o[2] < 0.0
        u_rr, u_choice = rng.next2()
        if dirs:
            vertex = dr.select(transmit, vertex_transmit(mfa, efa, w, o), vertex_reflect(mfa, efa, w, o))
            # thr is ln of the throughput: the next event is e^{thr + ln last}·vertex; the roulette's survival
            # probability (detached) divides the throughput, i.e. its log subtracts from thr.
            log_lst, lst_ok = log_last(segments, transmit, l, log_l, lo)
            lst_ok &= vertex > 0.0
            log_lst = dr.select(lst_ok, log_lst, 0.0)
            lst_d = dr.detach(dr.select(lst_ok, dr.exp(log_lst), 0.0))
            importance = dr.maximum(dr.maximum(RR_NEE_GAIN * lst_d * dr.detach(vertex), RR_LAST_WEIGHT * lst_d), 1.0)
            q = dr.maximum(dr.minimum(dr.detach(dr.exp(thr)) * importance, 1.0), RR_TRACED_FLOOR)
            play = j >= RR_START
            survived = (q > 0.0) & ((q >= 1.0) | (u_rr < q))
            thr = dr.select(play & survived, thr - dr.log(dr.select(q > 0.0, q, 1.0)), thr)
            alive = ~play | survived
            v = dr.select(lst_ok, dr.exp(thr + log_lst) * vertex, 0.0)
            active &= alive
            result = dr.select(active, result + v, result)
        else:
            v, lst = next_event(segments, mfa, efa, w, l, o, lo, traced)
            thr, alive = walk.roulette_from(j >= RR_START, thr, u_rr,
                                            1.0 / roulette_importance(v, lst, RR_NEE_GAIN),
                                            RR_TRACED_FLOOR if traced else 0.0)
            active &= alive
            result = dr.select(active, result + thr * v, result)
        active &= j + 1 < max_bounces
        u1, u2 = rng.next2()
        if not traced:
            # The scatter and the new segment's continue factor only in the lanes that go on: every walk ends
            # in the roulette (or at the bounce cap) above, and a packet whose lanes all ended skips the
            # vertex's sampler (its Newton loop runs on the live lanes only). The live lanes' bits are the
            # same as computing it everywhere.
            def step(w, l, side, eta_f, thr):
                d, refracted, _, side, eta_f, valid = scatter(mf, w, side, eta_f, u_choice, u1, u2)
                up = d[2] > 0.0
                lam = mf.abs_lambda(d)
                thr = dr.select(up, thr * continue_up(segments, refracted, l, lam, branch=True), thr)
                return -d, lam, side, eta_f, thr, valid & (~up | ((lam > 0.0) & (thr > 0.0)))

            def ended(w, l, side, eta_f, thr):
                return w, l, side, eta_f, thr, dr.zeros(mi.Bool, dr.width(thr))

            w, l, side, eta_f, thr, valid = dr.if_stmt((w, l, side, eta_f, thr), active, step, ended,
                                                       label="msx_posfree_dielectric_scatter")
            return dict(j=j + 1, w=w, l=l, side=side, eta_f=eta_f, thr=thr, result=result, active=active & valid,
                        counter=rng.counter, piped=piped)
        # ∂/∂η of the next vertex's value along its moving edge, for either event here (detached: it
        # enters as (η − η̄)·term, a derivative only).
        ws = dr.detach(w)
        teta = dr.select(side > 0.0, 1.0, -efs * efs) if not dirs else dr.zeros(mi.Float, dr.width(efs))
        u_e1, u_e2 = rng.next2()  # drawn in every traced call: the same stream with η differentiated or not
        u_mix = rng.next()
        if eta_traced:
            edge = sum(eta_edge_term(segments, mfs, ws, tw, dr.detach(l), side, efs, teta, wo, dr.detach(lo),
                                     b, u_e) for b, u_e in ((False, u_e1), (True, u_e2)))
            result = dr.select(active, result + (eta_a - dr.detach(eta_a)) * dr.detach(thr) * edge, result)
        if dir_edges:  # the same circles, moving with ω_o and with w along s
            edge = sum(eta_edge_term(segments, mfs, ws, tw, dr.detach(l), side, efs, teta, dr.detach(wo_),
                                     dr.detach(lo), b, u_e, two) for b, u_e in ((False, u_e1), (True, u_e2)))
            thr_d = dr.detach(dr.exp(thr))  # the throughput itself
            result = dr.select(active, result + (s_dir - dr.detach(s_dir)) * thr_d * edge, result)
        d, refracted, side, valid, weight, m = scatter_traced(mfa, mfs, w, side, efa, u_choice, u1, u2, u_mix,
                                                              times_area=dirs)
        tw = eta_tangent_step(ws, tw, m, efs, teta, refracted)
        if not dirs:  # (along moving directions the state's ln L joins below)
            piped = lv.piped(eta_a, tw)
        eta_f = dr.select(refracted, 1.0 / eta_f, eta_f)
        if dirs:  # the weight times L (``times_area``), over L in logs
            log_weight, weight_ok = _log_pos(weight)
            thr = thr + log_weight - log_l
            valid &= weight_ok
        else:
            thr = thr * weight
        active &= valid
        up = d[2] > 0.0
        lam = mfa.abs_lambda(d)
        if dirs:
            log_lam = log_abs_lambda(mfa, d, lam)
            log_c, c_ok = log_continue_up(segments, refracted, l, log_l, lam, log_lam)
            thr = dr.select(up, thr + dr.select(c_ok, log_c, 0.0), thr)
            active &= ~up | c_ok
            piped = lv.piped(eta_a, tw, wo_, s_dir, two, log_lam)
        else:
            thr = dr.select(up, thr * continue_up(segments, refracted, l, lam), thr)
            active &= ~up | ((lam > 0.0) & (thr > 0.0))
        return dict(j=j + 1, w=-d, l=lam, side=side, eta_f=eta_f, thr=thr, result=result, active=active,
                    counter=rng.counter, piped=piped)

    piped = ()
    thr0 = mi.Float(1.0)
    if traced:
        tw0 = mi.Vector3f(0.0)
        more = ()
        if dirs:
            s_dir, t_i, t_o = direction_tangent
            tw0 = side0 * mi.Vector3f(t_i)
            more = (mi.Vector3f(wo), mi.Float(s_dir), mi.Vector3f(t_o), dr.log(l0))  # l0 = 1 + Λ(w0) ≥ 1
            thr0 = mi.Float(0.0)  # ln 1
        piped = LoopValues.state(mf, lambda_o, mi.Float(eta), tw0, *more)
    state = dict(j=mi.UInt32(0), w=w0, l=l0, side=side0, eta_f=eta_f0, thr=thr0, result=mi.Float(0.0),
                 active=mi.Bool(start), counter=mi.UInt32(0), piped=piped)
    result = walk.while_loop(state, body, label="msx_posfree_dielectric_pt")["result"]
    return result * radiance_scale(eta, radiance, wi[2] > 0.0, wo[2] > 0.0)


def _sample_scatter(mf, key, first_numbers, j, w, side, eta_f, counter):
    """A vertex of ``sample_walk``'s loop up to its new direction: (the loop's next state without ``done`` and
    ``active``, and what the exit decision takes: (d in the new frame, refracted, F, valid (a visible normal),
    u_choice, the stream's exit number, whether it is vertex 0))."""
    s1, v1, v2 = first_numbers
    rng = Stream(key, counter)
    c_r, e_r = rng.next2()
    a_r, b_r = rng.next2()
    first = j == 0
    u_choice = dr.select(first, s1, c_r)
    d, refracted, f, side, eta_f, valid = scatter(mf, w, side, eta_f, u_choice,
                                                  dr.select(first, v1, a_r), dr.select(first, v2, b_r))
    state = dict(j=j + 1, w=-d, l=mf.abs_lambda(d), side=side, eta_f=eta_f, counter=rng.counter)
    return state, (d, refracted, f, valid, u_choice, e_r, first)


def _sample_leaves(segments, l, lam, vertex):
    """Whether the new direction of ``_sample_scatter``'s ``vertex`` (Λ = ``lam``, arriving with L = ``l``)
    goes up and leaves: its exit decision against the continue factor (sample1 rescaled within its branch at
    vertex 0, the stream's number after it)."""
    d, refracted, f, _, u_choice, e_r, first = vertex
    c = continue_up(segments, refracted, l, lam, branch=True)
    u = dr.select(refracted, (u_choice - f) / (1.0 - f), u_choice / f)
    u = dr.select(dr.isfinite(u), dr.clip(u, 0.0, ONE_MINUS_EPS), e_r)
    u_exit = dr.select(first, u, e_r)
    return (d[2] > 0.0) & (u_exit >= c)


def _sample_start(mf, eta, wi):
    """The sampling walk's initial state (before vertex 0)."""
    w0, l0, side0, eta_f0 = initial_state(mf, eta, wi)
    return dict(j=mi.UInt32(0), w=w0, l=l0, side=side0, eta_f=eta_f0, done=mi.Bool(False),
                active=mi.Bool(valid_inputs(eta, wi)), counter=mi.UInt32(0))


def sample_walk(segments, mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key, first_vertex=None):
    """Random-walk sampler: at each vertex m ~ D_w, reflect with probability F or refract, and an upward
    direction (in its medium's frame) leaves with probability 1 − c, so the weight is 1 (× Mitsuba's 1/η_r²
    for a transmission in Radiance mode). The first vertex uses (sample1, u1, u2); sample1, rescaled to
    [0, 1) within the chosen branch, also decides the first exit; later vertices use the lane's stream.
    Returns (ω_o, weight, valid); invalid when no visible normal or the bounce cap is reached.

    ``first_vertex``: ``sample_first_vertex``'s result, from which the walk goes on (its exit decision, then
    the loop from vertex 1: the same operations as the loop's vertex 0, the same bits)."""
    eta = mi.Float(eta)
    wi = mi.Vector3f(wi)
    numbers = (mi.Float(sample1), mi.Float(u1), mi.Float(u2))

    def body(j, w, l, side, eta_f, done, active, counter):
        state, vertex = _sample_scatter(mf, key, numbers, j, w, side, eta_f, counter)
        leaves = _sample_leaves(segments, l, state["l"], vertex)
        valid = vertex[3]
        return dict(state, done=valid & leaves, active=valid & ~leaves & (j + 1 < max_bounces))

    if first_vertex is None:
        state = _sample_start(mf, eta, wi)
    else:
        init, after, vertex = first_vertex
        start, valid = init["active"], vertex[3]
        leaves = _sample_leaves(segments, init["l"], after["l"], vertex)
        # A lane that does not start keeps the initial state (the loop never runs it).
        state = {k: dr.select(start, v, init[k]) for k, v in after.items()}
        state.update(done=start & valid & leaves, active=start & valid & ~leaves & (1 < max_bounces))
    out = walk.while_loop(state, body, label="msx_posfree_dielectric_sample")
    done = out["done"]
    wo = -out["side"] * out["w"]
    return wo, radiance_scale(eta, radiance, wi[2] > 0.0, wo[2] > 0.0), done


def sample_first_vertex(mf, eta, wi, sample1, u1, u2, key):
    """Vertex 0 of ``sample_walk`` on every lane, outside its loop, up to its new direction (the same
    operations): (initial state, state after it, the vertex's values), for ``sample_walk(first_vertex=…)`` and
    ``order_one_finish``."""
    eta, wi = mi.Float(eta), mi.Vector3f(wi)
    init = _sample_start(mf, eta, wi)
    after, vertex = _sample_scatter(mf, key, (mi.Float(sample1), mi.Float(u1), mi.Float(u2)),
                                    *(init[k] for k in ("j", "w", "side", "eta_f", "counter")))
    return init, after, vertex


# The dielectric walks this module provides, by model name (jit/bsdf.py collects them).
DIELECTRIC_WALKS = {
    name: DielectricWalk(partial(eval_pt, name), partial(sample_walk, name), differentiable=True,
                         eta_differentiable=True, direction_distributions=(BECKMANN, GGX))
    for name in (UNCORRELATED, CORRELATED)
}
