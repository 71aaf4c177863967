"""Heitz et al. 2016, the stochastic random walk on the Smith microsurface with explicit heights, in the
Dr.Jit engine: twin of ``src/walk/height.rs`` on the three microsurfaces (conductor, Lambertian
facets, dielectric).

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
the per-vertex weights (Fresnel for conductors, albedo for Lambertian facets, 1 for dielectrics) divided by
the roulette's survival probabilities.

Dielectric sides (as the core): the walk works in the frame of the medium the ray travels in, the identity
outside and the point reflection v ↦ −v inside, where it sees the standard microsurface from above with
relative IOR η (outside) or 1/η (inside); a refraction switches the frame and maps the height to the
flipped microsurface's, t ↦ ln(1 − e^t) (``flip_height``). The walk yields the Importance-mode BSDF;
Radiance mode multiplies a result whose ω_o lies on the other side than ω_i by 1/η_r² once at the end
(``dielectric.radiance_scale``: the refractions' factors telescope). Fresnel and refraction are the
unit-vector forms the core's height-based walks use (``dielectric.fresnel_dielectric``, ``refract_unit``).

As in the core (``valid_incidence``), conductor and Lambertian facets need ω_i (and, for eval, ω_o)
strictly above the macro surface (``below=False``; the MIS density is 0 there); a dielectric takes both
sides (z ≠ 0) and a finite η > 0.

Everything is float32 on arrays of lanes; ``expm1``/``log1p`` (``special.py``) keep the hit probability of
a near-vertical ray to its relative precision.
"""

import math

import drjit as dr
import mitsuba as mi

from . import mis, walk
from .dielectric import eta_seen, fresnel_dielectric, radiance_scale, scatter_unit, transmit_half_vector
from .glass_traced import RR_TRACED_FLOOR, edge_point, eta_tangent_step, scatter_traced
from .gradients import LoopValues, trimmed
from .microfacet import BECKMANN, GGX, INV_PI, ConductorFresnel, dot, half_vector, normalized, reflect
from .model import ConductorWalk, DielectricWalk, DiffuseWalk
from .posfree import horizon_circle
from .posfree_dielectric import vertex_reflect, vertex_transmit
from .rng import ONE_MINUS_EPS, Stream, clean_uniform, mix32, mix32_int
from .special import expm1, log1p, optical_depth

LN_2 = 0.6931471805599453
# The key of the edge terms' own stream (``eval_from`` along moving directions on GGX): a salt mixed into the
# lane's key, so that the walk's stream is the same with the terms or without.
EDGE_SALT = mix32_int(0x45444745)


# ------------------------------------------------------------------ height machinery


def sample_height(mf, w, t, u, lam=None, lam_abs=None):
    """Next intersection of a ray along ``w`` from height t with U = ``u`` (Rust ``sample_height``):
    (t', hit); hit False when the ray leaves the microsurface. ``lam``, ``lam_abs``: Λ(w) and |Λ(w)| when the
    caller has them (the same variables: recorded once)."""
    e = optical_depth(u)
    up = w[2] > 0.0
    lam_up = mf.lambda_(w) if lam is None else lam  # ≥ 0 for an upward w
    lam_abs = mf.abs_lambda(w) if lam_abs is None else lam_abs  # ≥ 1 downward, ∞ horizontal
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
    u = dr.clip(u, 0.0, ONE_MINUS_EPS)
    # One logarithm for both directions, its argument selected per lane: ln(1 − U·P_hit) upward (``log1p``
    # inlined), ln(1 − U) downward (``optical_depth``); each lane rounds its own direction's operations.
    z = -u * p_hit
    v = 1.0 + z
    ln = dr.log(dr.select(up, v, 1.0 - u))
    t_up = t - dr.select(v == 1.0, z, ln * z / (v - 1.0)) / lam
    leaves = ~(lam > 0.0) | (t >= 0.0)
    horizontal = lam == dr.inf
    bad = ~(p_hit > 0.0) | dr.isnan(t_up)
    t_up_res = dr.select(leaves | bad, t, dr.select(horizontal, t, dr.minimum(t_up, 0.0)))
    p_up = dr.select(leaves, 0.0, dr.select(horizontal, 1.0, dr.select(bad, 0.0, dr.minimum(p_hit, 1.0))))
    # Downward: always hits (unless the height is NaN): ``sample_height``'s step, E = −ln(1 − U).
    t_down = t - (-ln) / mf.abs_lambda(w)
    hit_down = ~dr.isnan(t_down)
    t_res = dr.select(up, t_up_res, dr.select(hit_down, t_down, t))
    p_res = dr.select(up, p_up, dr.select(hit_down, 1.0, 0.0))
    return t_res, p_res


def masking_at(lambda_w, t):
    """G1(ω, h) = e^{Λ(ω)·t} of an upward direction with Λ(ω) = ``lambda_w`` at height t (Rust
    ``masking_at``; the caller checks that ω points up)."""
    g = dr.exp(lambda_w * t)
    g = dr.select(dr.isfinite(g), g, 0.0)
    return dr.select(~(lambda_w > 0.0) | (t >= 0.0), 1.0, g)


def flip_height(t):
    """The height seen from the other side of the interface, ln(1 − e^t), without cancellation (Rust
    ``flip_height``): log1p(−e^t) below −ln 2, ln(−expm1(t)) above. Written with one exponential and one
    logarithm for both forms (``special.log1p`` and ``expm1`` inlined, the logarithm's argument selected per
    lane): each lane rounds its own form's operations, as computing both and selecting (the same bits; e^t is
    taken of min(t, 0), equal to t where the first form is chosen)."""
    t0 = dr.minimum(t, 0.0)
    first = t < -LN_2
    x = -dr.exp(t0)
    u = 1.0 + x
    ln = dr.log(dr.select(first, u, -expm1(t0)))
    return dr.select(first, dr.select(u == 1.0, x, ln * x / (u - 1.0)), ln)


# ------------------------------------------------------------------ phase function


def conductor_phase(mf, wi, wo):
    """The conductor phase function without Fresnel, D_ωi(h)/(4 ωi·h), and ωi·h (Rust
    ``conductor_phase``): (p, c, valid)."""
    h, length = half_vector(wi, wo)
    c = dot(wi, h)
    p = mf.d_visible(wi, h) / (4.0 * c)
    valid = (length > 1e-12) & (c > 0.0) & (h[2] > 0.0) & dr.isfinite(p) & (p > 0.0)
    return dr.select(valid, p, 0.0), c, valid


def dielectric_phase_transmit(mf, wi, wo, eta):
    """The dielectric phase function towards ω_o on the other side (supplement §3.4; Rust
    ``dielectric_phase`` with ``same = false``): ``wo`` in the current side's frame points down, ``eta``
    the relative IOR of the far side. η²(1 − F) D_ωi(h) |ωo·h| / (ωi·h + η ωo·h)², h ∝ −(ωi + η ωo)
    oriented upward."""
    h, length = normalized(transmit_half_vector(wi, wo, eta))
    ci = dot(wi, h)
    co = dot(wo, h)
    f = fresnel_dielectric(ci, eta)
    denom = ci + eta * co
    v = eta * eta * (1.0 - f) * mf.d_visible(wi, h) * (-co) / (denom * denom)
    ok = (length > 1e-12) & (ci > 0.0) & (co < 0.0) & (f < 1.0) & dr.isfinite(v) & (v > 0.0)
    return dr.select(ok, v, 0.0)


def dielectric_phase_reflect(mf, wi, wo, eta):
    """The dielectric phase function towards ω_o on the same side: F(ωi·h)·D_ωi(h)/(4 ωi·h) (Rust
    ``dielectric_phase`` with ``same = true``)."""
    p, c, ok = conductor_phase(mf, wi, wo)
    return dr.select(ok, p * fresnel_dielectric(dr.select(ok, c, 1.0), eta), 0.0)


def phase_next_event(mf, w, o, eta, transmit, lam_up=None):
    """Heitz's phase function towards ``o`` (``heitz.dielectric_phase_transmit`` where ``transmit``, else
    ``heitz.dielectric_phase_reflect``) with one half vector, one visible-normal density and one Fresnel factor
    per lane: each lane rounds the operations of its own branch's function (the same bits), at about half the
    cost of computing both and selecting (as ``posfree_dielectric.vertex_next_event``); the next event of the
    plain glass walks here and in jit/invariance_dielectric.py. ``lam_up``: as ``Microfacet.d_visible``'s."""
    h, length = normalized(dr.select(transmit, transmit_half_vector(w, o, eta), w + o))
    c, co = dot(w, h), dot(o, h)
    d = mf.d_visible(w, h, lam_up)
    p = d / (4.0 * c)
    ok_r = (length > 1e-12) & (c > 0.0) & (h[2] > 0.0) & dr.isfinite(p) & (p > 0.0)
    # The reflection's Fresnel argument where its term is valid (its other lanes give 0 either way).
    f = fresnel_dielectric(dr.select(transmit | ok_r, c, 1.0), eta)
    v_r = dr.select(ok_r, p * f, 0.0)
    denom = c + eta * co
    v_t = eta * eta * (1.0 - f) * d * (-co) / (denom * denom)
    ok_t = (length > 1e-12) & (c > 0.0) & (co < 0.0) & (f < 1.0) & dr.isfinite(v_t) & (v_t > 0.0)
    return dr.select(transmit, dr.select(ok_t, v_t, 0.0), v_r)


def visible_normal(mf, wi, u1, u2, where=None):
    """A visible normal of ``wi`` (Rust ``visible_normal``): (m, ωi·m, valid). ``where`` (a mask, plain
    walks only): drawn only there, (ωi, 0, False) elsewhere; a packet with no lane of it skips the sampler."""
    if where is not None:
        def nothing(w, a, b):
            return w, dr.zeros(mi.Float, dr.width(a)), dr.zeros(mi.Bool, dr.width(a))

        return dr.if_stmt((wi, u1, u2), where, lambda w, a, b: visible_normal(mf, w, a, b), nothing,
                          label="msx_visible_normal")
    m, valid = mf.sample_visible(wi, u1, u2)
    c = dot(wi, m)
    return m, c, valid & dr.all(dr.isfinite(m)) & (c > 0.0)


def valid_incidence(w):
    """A conductor's (or Lambertian facets') direction must be finite and strictly above the macro
    surface."""
    return dr.all(dr.isfinite(w)) & (w[2] > 0.0)


def valid_incidence_dielectric(w, eta):
    """A dielectric's direction must be finite and off the macro surface, its IOR finite and > 0."""
    return dr.all(dr.isfinite(w)) & (w[2] != 0.0) & dr.isfinite(eta) & (eta > 0.0)


# ------------------------------------------------------------------ the walks


def visible_ratio(mfa, mfs, w, m):
    """D_ω(m) under ``mfa`` with ω = ``w`` attached over D_ω(m) under ``mfs`` with ω detached (m drawn from
    the latter): value 1, derivative the score; 1 where the drawn normal has no finite positive density."""
    ds = mfs.d_visible(dr.detach(w), m)
    ok = (ds > 0.0) & dr.isfinite(ds)
    return dr.select(ok, mfa.d_visible(w, m) / dr.select(ok, ds, 1.0), 1.0)


def eval(mf, fresnel, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o, orders 1..max_bounces (Rust ``eval`` with
    ``eval_from``): the walk enters from ω_i at t = 0; at each vertex the height step is conditioned on
    hitting (the throughput carries P_hit), the path is closed towards ω_o (F · phase · G1(ω_o, h)), then
    the walk reflects about a visible normal and plays Russian roulette.

    ``mf_sample`` (docs/gradients.md): the statistics with their derivatives detached. The visible normals
    are then drawn from them, each draw's throughput carrying the ratio of its density under ``mf`` to its
    density under ``mf_sample`` (value 1, derivative the score); the heights are reparameterized (the step's
    uniform number held, t' and P_hit from the attached Λ); the roulette is detached
    (``walk.russian_roulette_keep``). The estimate's derivative is then an unbiased estimate of the
    derivative of f. The differentiated values travel in the loop's state.

    With ``mf_sample``, ω_i and ω_o may carry a derivative (docs/gradients.md, "Directions through the
    walks"): the normals are drawn for the detached direction and the attached direction is reflected about
    them, each weighed by its density ratio, and the heights move with the attached direction. On Beckmann nothing
    jumps where the directions move (its D is 0 at a horizontal half vector). On GGX the next event of a vertex
    reached going up jumps where its half vector turns horizontal: with ``direction_tangent`` = (s, t_i, t_o)
    (gradients.TangentCoordinates) each vertex adds that edge's term (``horizon_edge_term``)."""
    return eval_from(mf, ConductorFacets(fresnel), wi, wo, max_bounces, key, mf_sample,
                     direction_tangent=direction_tangent)


def horizon_edge_term(mf, fresnel, w, tw, t, wo, two, lambda_o, u_phi, u_h):
    """The term of a directional derivative that the next vertex's next-event value misses where it jumps
    (GGX conductor facets; docs/gradients.md, "Heitz's walk on conductor facets"): as
    ``posfree.horizon_edge_term`` (the circle of new directions d with d_z = ω_o,z, ``posfree.horizon_circle``),
    with this walk's factors: the step's density times its weight in the space of new directions,
    ρ = F(w·m)·D(m)/(4A(w)) (the visible normal's density ⟨w·m⟩D(m)/A(w) over the reflection's Jacobian
    4⟨w·m⟩), and the next value's limit on its nonzero side, the next height step from this vertex's height
    ``t`` along d conditioned on a hit (drawn with ``u_h``, its hit probability P_hit in the value), Heitz's
    phase function at the horizontal half vector h, D_{−d}(h)/(4⟨−d·h⟩) = D(h)/(4A(−d)) with D(h) its limit
    ``d_horizon``, the Fresnel term and ω_o's masking at the next height: V⁺ = P_hit·F(−d·h)·D(h)/(4A(−d))·
    G1(ω_o, t′). One uniform azimuth ``u_phi`` estimates the integral over the circle. Everything is detached:
    the term enters as (s − s̄)·term."""
    d, m, cos_wm, h, u_z, ok = horizon_circle(w, tw, wo, u_phi)
    area_w = mf.projected_area(w)
    rho = fresnel.eval(cos_wm) * mf.d(m) / (4.0 * area_w)
    t_next, p_hit = sample_height_hit(mf, d, t, u_h)
    area_d = mf.projected_area(-d)
    v = p_hit * fresnel.eval(dot(-d, h)) * (mf.d_horizon(h) / (4.0 * area_d)) * masking_at(lambda_o, t_next)
    term = 2.0 * math.pi * rho * v * (two[2] - u_z)
    ok &= (area_w > 0.0) & (area_d > 0.0) & (p_hit > 0.0)
    return dr.select(ok & dr.all(dr.isfinite(term)), term, 0.0)


def eval_from(mf, facets, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """Heitz's eval walk on conductor or Lambertian facets (Rust ``eval_from`` with ``Mat::Conductor`` /
    ``Mat::Diffuse``; the dielectric's, which changes sides, is ``dielectric_eval_from``): entering from ω_i
    at t = 0, each vertex draws its height conditioned on hitting (the throughput carries P_hit), then the
    facets estimate towards ω_o and scatter (``facets.eval_vertex``), then Russian roulette (keep = 1).
    ``mf_sample``: as ``eval``'s. The statistics and the facets' own values (``facets.values``) travel in the
    loop's state whenever they carry derivatives (``walk.carries_gradients``; gradients.LoopValues): with
    ``mf_sample``, and without it when a caller differentiates the walk as written (the traced ``sample``'s
    weight). ``direction_tangent`` (traced, facets with ``horizon_edges``, a distribution whose D does not
    vanish at horizontal normals): (s, t_i, t_o) of the one coordinate s of the directions differentiated;
    each vertex then adds the next vertex's edge term (``horizon_edge_term``), with the tangent of the vertex's
    direction −wr carried in the state (t ↦ t − 2(t·m)m per reflection, from the tangent of ω_i) and its two
    numbers from a stream of their own (``EDGE_SALT``)."""
    last = max_bounces  # a Python int, or a UInt32 per lane (model 'auto' style caps)
    lambda_o = mf.lambda_(wo)
    start = valid_incidence(wi) & valid_incidence(wo) & (last > 0)
    carries = walk.carries_gradients(mf, lambda_o, *facets.values())
    # Traced with nothing differentiated (prb's primal pass and its adjoint pass's ``sample``: gradients
    # suspended), the walk is the one as written bit for bit: the same heights and normals (drawn from equal
    # statistics and directions), each density ratio exactly 1 (x/x). It runs as that, without the values in
    # its loop state and the ratios (benches/README.md, "Gradient steps of the walks ≤ 3× the built-in").
    traced = mf_sample is not None and (carries or dr.grad_enabled(wi) or dr.grad_enabled(wo) or not trimmed())
    piped_values = traced or carries
    # Traced, ω_o travels in the loop's state when it may carry a derivative (a fixed ω_o is read from outside
    # the loop, as the walk as written reads it: the same value).
    pipe_wo = traced and (dr.grad_enabled(wo) or not trimmed())
    edges = (traced and direction_tangent is not None and getattr(facets, "horizon_edges", False)
             and mf.dist != BECKMANN)
    edge_key = mix32(key ^ EDGE_SALT) if edges else None

    def body(order, wr, t, thr, result, active, counter, piped):
        mfa, mfs, lo, values = LoopValues.unpack(piped_values, mf, lambda_o, (), piped)
        mfs = mfs if traced else mfa  # the walk as written draws from the statistics it evaluates
        if edges:  # ... then the coordinate s and the tangents of −wr and of ω_o
            values, (s_dir, tw, two) = values[:-3], values[-3:]
        # Traced, ω_o travels in the state too, after the facets' values (it may carry a derivative).
        values, wo_ = (values[:-1], values[-1]) if pipe_wo else (values, wo)
        f = facets.with_values(values) if piped_values else facets
        if edges:
            u_phi, u_eh = Stream(edge_key, counter).next2()
        rng = Stream(key, counter)
        u_h, u_rr = rng.next2()
        # Traced, the height is reparameterized, as on glass (``dielectric_eval_from``): the step's uniform
        # number is held and the attached Λ of the attached direction maps it to t' (and gives P_hit). A
        # density ratio of the height held fixed would carry the score Λ′(1/Λ − Δt), of infinite variance where the direction turns horizontal (Λ ~ 1/w_z): measured on conductor facets
        # with moving directions, per-lane derivatives up to 1.6·10⁵ (docs/gradients.md).
        tn, p_hit = sample_height_hit(mfa if traced else mfs, wr, t, u_h)
        active &= p_hit > 0.0
        thr = thr * p_hit
        t = tn
        thr_vertex, w_vertex = thr, -wr
        nee, nee_ok, wr, thr, valid = f.eval_vertex(mfa, mfs, -wr, wo_, lo, t, thr, rng, traced)
        result = dr.select(active & nee_ok, result + nee, result)
        active &= order < last
        if edges:
            frd = f.fresnel if f.fresnel.mirror else ConductorFresnel(dr.detach(f.fresnel.eta),
                                                                      dr.detach(f.fresnel.k))
            w_s = dr.detach(w_vertex)
            edge = horizon_edge_term(mfs, frd, w_s, tw, dr.detach(t), dr.detach(wo_), two, dr.detach(lo), u_phi,
                                     u_eh)
            result = dr.select(active, result + (s_dir - dr.detach(s_dir)) * dr.detach(thr_vertex) * edge, result)
            m = f.normal  # the normal this vertex reflected about: the tangent of the next −wr at fixed m
            tw = tw - 2.0 * dot(tw, m) * m
            piped = piped[:-3] + (s_dir, tw, two)
        thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0)
        active &= valid & survived & dr.all(dr.isfinite(wr))
        return dict(order=order + 1, wr=wr, t=t, thr=thr, result=result, active=active, counter=rng.counter,
                    piped=piped)

    state = dict(order=mi.UInt32(1), wr=-mi.Vector3f(wi), t=mi.Float(0.0), thr=mi.Spectrum(1.0),
                 result=dr.zeros(mi.Spectrum), active=mi.Bool(start), counter=mi.UInt32(0),
                 piped=LoopValues.state(mf, lambda_o, *facets.values(), *((mi.Vector3f(wo),) if pipe_wo else ()))
                 if piped_values else ())
    if edges:
        s_dir, t_i, t_o = direction_tangent
        state["piped"] += (mi.Float(s_dir), mi.Vector3f(t_i), mi.Vector3f(t_o))
    return walk.while_loop(state, body, label=facets.eval_label)["result"]


class ConductorFacets:
    """What a vertex of the sampling walk does on conductor facets (Rust ``scatter`` with
    ``Mat::Conductor``): reflect about the visible normal, weight × F."""

    choice = False  # a vertex draws no reflect-or-refract number
    sides = False  # the walk stays above the microsurface
    horizon_edges = True  # the next event jumps where its half vector turns horizontal (GGX: ``eval_from``)
    label = "msx_heitz_conductor_sample"
    eval_label = "msx_heitz_conductor_eval"

    def __init__(self, fresnel):
        self.fresnel = fresnel

    def values(self):
        """The facets' values a differentiated walk carries in its loop state (the material's η, k)."""
        return () if self.fresnel.mirror else (mi.Spectrum(self.fresnel.eta), mi.Spectrum(self.fresnel.k))

    def with_values(self, values):
        """The facets with the values of ``values`` (as ``values`` gives them) in the loop's body."""
        return ConductorFacets(ConductorFresnel(*values)) if values else self

    def eval_vertex(self, mfa, mfs, wi_l, wo, lambda_o, t, thr, rng, traced):
        """A vertex of the eval walk at height ``t``, the ray arriving along −``wi_l``: the next event towards
        ω_o, F · phase · G1(ω_o, h) (times ``thr``), then reflection about a visible normal of ``wi_l`` drawn
        from ``mfs`` (× its density ratio when ``traced``). Returns (next event, where it counts, next
        direction, throughput, valid)."""
        p, c, ok = conductor_phase(mfa, wi_l, wo)
        nee = thr * (self.fresnel.eval(c) * (p * masking_at(lambda_o, t)))
        u1, u2 = rng.next2()
        # Traced, the normal is drawn for the detached direction and the attached one reflects about it.
        m, cos_wm, valid = visible_normal(mfs, dr.detach(wi_l) if traced else wi_l, u1, u2)
        if traced:
            cos_wm = dot(wi_l, m)
        self.normal = m  # read by ``eval_from`` along moving directions (the tangent of the next direction)
        thr = thr * self.fresnel.eval(cos_wm)
        if traced:
            thr = thr * visible_ratio(mfa, mfs, wi_l, m)
        return nee, ok, dr.normalize(reflect(wi_l, m)), thr, valid

    def scatter(self, wi_l, m, cos_wm, outside, u_choice, thr, rng):
        """(next direction, crossed the interface (None: never), weight)."""
        return dr.normalize(reflect(wi_l, m)), None, thr * self.fresnel.eval(cos_wm)

    def exits(self, wr, thr):
        """A walk that leaves along ``wr`` gives a sample."""
        return (wr[2] > 0.0) & dr.all(dr.isfinite(thr))


class DiffuseFacets(ConductorFacets):
    """What a vertex of the sampling walk does on Lambertian facets (``Mat::Diffuse``): a cosine lobe about
    the visible normal (two numbers of the lane's stream), weight × albedo."""

    label = "msx_heitz_diffuse_sample"
    eval_label = "msx_heitz_diffuse_eval"
    horizon_edges = False  # its next event is continuous (``diffuse_eval``)

    def __init__(self, albedo):
        self.albedo = albedo

    def values(self):
        return (mi.Spectrum(self.albedo),)

    def with_values(self, values):
        return DiffuseFacets(values[0])

    def eval_vertex(self, mfa, mfs, wi_l, wo, lambda_o, t, thr, rng, traced):
        """A vertex of the eval walk: a visible normal m of ``wi_l`` (from ``mfs``, × its density ratio when
        ``traced``) shared by the next event, (a/π)⟨ω_o, m⟩⁺·G1(ω_o, h), and the continuation, a cosine lobe
        about m with weight a."""
        u1, u2 = rng.next2()
        m, _, valid = visible_normal(mfs, dr.detach(wi_l) if traced else wi_l, u1, u2)
        if traced:
            thr = thr * visible_ratio(mfa, mfs, wi_l, m)
        nee = thr * (self.albedo * (dr.maximum(dot(m, wo), 0.0) * INV_PI * masking_at(lambda_o, t)))
        ua, ub = rng.next2()
        return nee, valid, walk.cosine_about(m, ua, ub), thr * self.albedo, valid

    def scatter(self, wi_l, m, cos_wm, outside, u_choice, thr, rng):
        ua, ub = rng.next2()
        return walk.cosine_about(m, ua, ub), None, thr * self.albedo


class DielectricFacets:
    """What a vertex of the sampling walk does on a rough dielectric (``Mat::Dielectric``): reflect or
    refract about the visible normal (``u_choice`` < F reflects) with the relative IOR of the ray's side,
    weight 1; a refraction switches the side."""

    choice = True
    sides = True
    label = "msx_heitz_dielectric_sample"

    def __init__(self, eta):
        self.eta = mi.Float(eta)

    def scatter(self, wi_l, m, cos_wm, outside, u_choice, thr, rng):
        wr, crossed = scatter_unit(wi_l, m, cos_wm, eta_seen(self.eta, outside), u_choice)
        return wr, crossed, thr

    def exits(self, wr, thr):
        return (wr[2] != 0.0) & dr.isfinite(thr)


def sample_from(mf, facets, wr, t, outside, order, thr, active, max_bounces, key, counter, first):
    """Heitz's sampling walk from a hit (Rust ``sample_from``, over the microsurface ``facets``): the ray
    along ``wr`` (frame of its side, ``outside``) has hit at height ``t`` the vertex of order ``order`` + 1,
    which scatters with the numbers ``first`` = (u1, u2) of its visible normal, preceded by its
    reflect-or-refract number on a dielectric (``facets.choice``); the lane's stream from ``counter`` drives
    the rest (``walk.vertex_numbers``). Each vertex scatters, plays Russian roulette (keep = 1) and draws the
    next height; a ray that leaves the microsurface ends the walk with ω_o along it. Returns (ω_o in the macro
    frame, weight = Π vertex weights / Π q, valid); more than ``max_bounces`` vertices is invalid."""
    last = max_bounces

    def body(order, wr, t, outside, thr, done, active, counter, u):
        rng = Stream(key, counter)
        order = order + 1  # the vertex at height t
        wi_l = -wr
        m, cos_wm, valid = visible_normal(mf, wi_l, u[-2], u[-1])
        wr, crossed, thr = facets.scatter(wi_l, m, cos_wm, outside, u[0], thr, rng)
        if crossed is not None:
            outside = outside ^ crossed
            t = dr.select(crossed, flip_height(t), t)
        u_rr, u_h = rng.next2()
        thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0)
        active &= valid & survived & dr.all(dr.isfinite(wr))
        # The next height: leaving ends the walk with ω_o = wr.
        tn, hit = sample_height(mf, wr, t, u_h)
        leaves = active & ~hit
        done = leaves & facets.exits(wr, thr)
        active &= hit & (order < last)
        u = walk.vertex_numbers(rng) if facets.choice else rng.next2()
        return dict(order=order, wr=wr, t=tn, outside=outside, thr=thr, done=done, active=active,
                    counter=rng.counter, u=u)

    state = dict(order=mi.UInt32(order), wr=mi.Vector3f(wr), t=mi.Float(t), outside=mi.Bool(outside), thr=thr,
                 done=mi.Bool(False), active=mi.Bool(active & (order < last)), counter=mi.UInt32(counter),
                 u=tuple(clean_uniform(mi.Float(x)) for x in first))
    if not facets.sides:  # the walk stays outside: no side in the state
        state["outside"] = True
    out = walk.while_loop(state, body, label=facets.label)
    return dr.select(out["outside"], out["wr"], -out["wr"]) if facets.sides else out["wr"], out["thr"], out["done"]


def sample(mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling (supplement Algorithm 3; Rust ``sample`` with ``sample_from``): ``sample1``
    drives the first height, (u1, u2) the first visible normal, the lane's stream the rest. The walk exits
    when a height step leaves the microsurface; more than ``max_bounces`` vertices is invalid (the same
    truncation as ``eval``). Returns (ω_o, weight, valid), weight = the product of the Fresnel terms
    divided by the roulette's survival probabilities."""
    # The first height: the entering ray −ω_i points down and always hits.
    w0 = -mi.Vector3f(wi)
    t0, hit0 = sample_height(mf, w0, mi.Float(0.0), dr.select(dr.isfinite(sample1), sample1, 0.5))
    start = valid_incidence(wi) & (max_bounces > 0) & hit0
    return sample_from(mf, ConductorFacets(fresnel), w0, t0, True, 0, mi.Spectrum(1.0), start, max_bounces, key, 0,
                       (u1, u2))


# ------------------------------------------------------------------ Lambertian facets (diffuse)


def diffuse_eval(mf, albedo, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o on Lambertian facets of albedo ``albedo``, orders
    1..max_bounces (Rust ``eval_from`` with ``Mat::Diffuse``): per vertex the height step conditioned on
    hitting, a visible normal m of the incoming ray shared by the next event, (a/π)⟨ω_o, m⟩⁺·G1(ω_o, h),
    and the continuation, a cosine lobe about m with weight a; roulette after every vertex. ``mf_sample``:
    as in ``eval`` (the cosine lobe about m does not depend on the parameters). Traced, ω_i and ω_o may carry
    a derivative as in ``eval``; the next event, (a/π)⟨ω_o, m⟩⁺·G1(ω_o, h), is continuous on both distributions
    (no edge term)."""
    return eval_from(mf, DiffuseFacets(albedo), wi, wo, max_bounces, key, mf_sample)


def diffuse_sample(mf, albedo, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling on Lambertian facets (Rust ``sample_from`` with ``Mat::Diffuse``):
    ``sample1`` drives the first height, (u1, u2) the first visible normal, the lane's stream the cosine
    lobes and the rest. Returns (ω_o, weight = Π a / Π q, valid); more than ``max_bounces`` vertices is
    invalid."""
    w0 = -mi.Vector3f(wi)
    t0, hit0 = sample_height(mf, w0, mi.Float(0.0), clean_uniform(sample1))
    start = valid_incidence(wi) & (max_bounces > 0) & hit0
    return sample_from(mf, DiffuseFacets(albedo), w0, t0, True, 0, mi.Spectrum(1.0), start, max_bounces, key, 0,
                       (u1, u2))


# ------------------------------------------------------------------ dielectric


def dielectric_edge_term(mf, w, tw, t, outside, eta_f, teta_f, wo, lambda_o, refracted, u_phi, u_h,
                         two=None):
    """The term of ∂/∂η that the next vertex's next-event value misses on its moving edge, for the branch
    ``refracted`` (a Python bool) of this vertex's event: as ``posfree_dielectric.eta_edge_term`` (docs/
    gradients.md, "The IOR of the glass walks"), with the next vertex's height in place of the continue factor
    — the next height step from this vertex's height (flipped by a refraction) along the new direction, drawn
    conditioned on a hit with ``u_h`` (its hit probability in the weight), and ω_o's masking at that height —
    and the value Heitz's phase function takes at a horizontal half-vector, F·D(h)/(4A(w)) for a reflection (A
    the projected area) and η²(1 − F)(w·h)D(h)|o·h|/(A(w)(w·h + η o·h)²) for a transmission, i.e.
    ``edge_vertex``'s value × |w_z|/A(w). One uniform azimuth (``u_phi``) estimates the integral over the
    circle. Everything is detached: the term enters as (η − η̄)·term.

    ``two``: along moving directions instead (docs/gradients.md, "The glass walks along moving directions"),
    the tangent of ω_o, ``tw`` that of w and ``teta_f`` 0: the same circle moves with ω_o and with w; the term
    enters as (s − s̄)·term for the coordinate s."""
    o = dr.select(outside ^ refracted, wo, -wo)
    to = None if two is None else dr.select(outside ^ refracted, two, -two)
    w_next, transmit, density, value, speed, ok = edge_point(mf, w, tw, o, eta_f, teta_f, refracted, u_phi, to)
    t_b = flip_height(t) if refracted else t
    t_next, p_hit = sample_height_hit(mf, -w_next, t_b, u_h)
    masking = masking_at(lambda_o, dr.select(transmit, flip_height(t_next), t_next))
    area = mf.projected_area(w_next)
    value = value * dr.abs(w_next[2]) / dr.select(area > 0.0, area, 1.0)
    term = 2.0 * math.pi * density * p_hit * masking * value * speed
    return dr.select(ok & (area > 0.0) & dr.isfinite(term), term, 0.0)


def _expm1_over_x(x):
    """(e^x − 1)/x for x ≤ 0, by its series where |x| < 10⁻⁴ (there the quotient's derivative would divide by
    x², which underflows in float32; the series' error x³/24 is below float32's rounding)."""
    small = dr.abs(x) < 1e-4
    return dr.select(small, 1.0 + x * (0.5 + x * (1.0 / 6.0)), expm1(x) / dr.select(small, 1.0, x))


def _log1p_over_x(x):
    """ln(1 + x)/x for −1 < x ≤ 0, by its series where |x| < 10⁻⁴ (as ``_expm1_over_x``)."""
    small = dr.abs(x) < 1e-4
    return dr.select(small, 1.0 + x * (-0.5 + x * (1.0 / 3.0)), log1p(x) / dr.select(small, 1.0, x))


def sample_height_hit_over_area(mf, w, t, u):
    """``sample_height_hit`` for a walk along moving directions (docs/gradients.md, "Heitz's walk through glass
    along moving directions"): (t', P_hit/L, hit), L = |Λ(w)| (the next vertex's projected area over |w_z|),
    written so that no quotient divides by a tiny Λ. Upward, with x = Λt: P_hit = −expm1(x) = Λ·g with
    g = −t·expm1(x)/x, and t' = t − ln(1 − U·P_hit)/Λ = t + (ln(1 + z)/z)·U·g with z = −U·P_hit, so P_hit/L = g
    and t' come from O(1) quotients (their series near 0); Λ itself only multiplies. After a step going up near
    the normal Beckmann's Λ is below 10⁻¹⁹ and the derivatives of 1/Λ, of t′ as written and of the next
    vertex's 1/A(w) each overflow in float32 (−dΛ/Λ²), though the products are O(1). Downward: P_hit = 1,
    L ≥ 1, the step as ``sample_height``. The value is ``sample_height_hit``'s up to rounding."""
    up = w[2] > 0.0
    lam = mf.abs_lambda(w)  # Λ(w) upward, 1 + Λ(−w) ≥ 1 downward, ∞ horizontal
    x = lam * t
    g = -t * _expm1_over_x(x)
    p_hit = lam * g
    u = dr.clip(u, 0.0, ONE_MINUS_EPS)
    z = -u * p_hit
    t_up = dr.minimum(t + _log1p_over_x(z) * u * g, 0.0)
    leaves = ~(lam > 0.0) | (t >= 0.0) | (lam == dr.inf)  # (a horizontal w: A(w) = 0·∞, the lane ends)
    bad = ~(p_hit > 0.0) | ~(z > -1.0) | dr.isnan(t_up) | ~dr.isfinite(g)
    miss_up = leaves | bad
    t_down, hit_down = sample_height(mf, w, t, u, lam_abs=lam)
    hit_down &= dr.isfinite(lam)
    t_res = dr.select(up, dr.select(miss_up, t, t_up), dr.select(hit_down, t_down, t))
    q = dr.select(up, dr.select(miss_up, 0.0, g), dr.select(hit_down, 1.0 / dr.select(hit_down, lam, 1.0), 0.0))
    return t_res, q, dr.select(up, ~miss_up, hit_down)


def dielectric_eval_from(mf, eta, wo, wr, t, outside, order, thr, active, max_bounces, key, counter,
                         mf_sample=None, tw=None, direction=None, lambda_o=None):
    """Heitz's dielectric eval walk from a state on (Rust ``eval_from`` with ``Mat::Dielectric``): the ray
    travels along ``wr`` (frame of its side, ``outside``) from height ``t`` towards the vertex of order
    ``order``, carrying ``thr``; the lane's stream goes on at ``counter``. Returns the contributions of
    the vertices of order ``order``..max_bounces (no Radiance-mode factor). Public for the invariance
    model, which hands the rest of a path to this walk after the first refraction.

    At each vertex the height step is conditioned on hitting, the next event goes to ω_o with the
    reflection phase function × G1(ω_o, h) on ω_o's side, or the transmission phase function × G1(ω_o,
    flipped h) across, then the walk reflects or refracts about a visible normal (u < F) and plays
    Russian roulette.

    ``mf_sample`` (docs/gradients.md, "The IOR of the glass walks"): the statistics with their derivatives
    detached (η too). Each height step is then reparameterized (its uniform number held, the attached Λ of
    the attached direction mapping it to the new height, its hit probability attached); each vertex draws
    its normal and its choice in the space of normals and computes the new direction with the attached
    parameters (``glass_traced.scatter_traced``: the normal's and the choice's density ratio in the weight,
    the floors); the roulette is detached and keeps a floor; while η is differentiated
    each vertex adds the next vertex's edge term for both of its events (``dielectric_edge_term``), with the
    tangent of −``wr`` in η carried in the state (``tw``, 0 by default: the caller's direction fixed).

    ``direction`` (traced only; docs/gradients.md, "Heitz's walk through glass along moving directions"):
    (s, t_o) while one coordinate s of ω_i, ω_o is differentiated, t_o the tangent of ω_o in s; ``tw`` is then
    the tangent of −``wr`` in s. ω_o (attached), s and t_o travel in the loop's state. Each vertex's hit
    probability and its 1/A(w) are folded into one factor P_hit/L (``sample_height_hit_over_area``), the next
    event and the draw's weight taken times L (``posfree_dielectric.vertex_reflect``/``vertex_transmit``,
    ``scatter_traced(times_area=True)``), so that no derivative divides by a tiny Λ; on GGX each vertex adds
    the next vertex's edge terms along s (``dielectric_edge_term`` with the tangent of ω_o)."""
    last = max_bounces
    eta = mi.Float(eta)
    wo = mi.Vector3f(wo)
    wo_out = wo[2] > 0.0
    # Λ(ω_o) in the frame of ω_o's side (D and Λ are even under v ↦ −v); ``lambda_o``: that value when a plain
    # caller has it (jit/invariance_dielectric.py: the same bits).
    traced = mf_sample is not None
    if traced or lambda_o is None:
        lambda_o = mf.lambda_(dr.select(wo_out, wo, -wo))
    eta_traced = traced and dr.grad_enabled(eta)  # the edge terms are derivatives in η only
    dirs = traced and direction is not None  # a pass along one coordinate of the directions
    dir_edges = dirs and mf.dist != BECKMANN  # Beckmann's D vanishes at horizontal normals: no edge

    def body(order, wr, t, outside, thr, result, active, counter, piped):
        mfa, mfs, lo, eta_a, wo_ = mf, mf, lambda_o, eta, wo
        if traced:  # the differentiated values come through the state (gradients.LoopValues)
            lv = LoopValues(mf.dist, piped)
            mfa, mfs, lo = lv.mf, lv.mf_sample, lv.lambda_o
            if dirs:
                eta_a, tw, wo_, s_dir, two = lv.rest
            else:
                eta_a, tw = lv.rest
        rng = Stream(key, counter)
        u_h, u_rr = rng.next2()
        # Traced, the height is reparameterized: the step's uniform number is held and the attached Λ of the
        # attached direction maps it to t' (and gives P_hit); the density ratio of a height held fixed would
        # carry the score ∂Λ/Λ ~ ∂w_z/w_z, of infinite variance near the horizon.
        if dirs:  # thr becomes the throughput over L: the vertex's values below are taken times L
            tn, q_hit, hit = sample_height_hit_over_area(mfa, wr, t, u_h)
            active &= hit
            l_d = dr.detach(mfa.abs_lambda(wr))
            thr = thr * q_hit
            thr_at = dr.detach(thr) * dr.select(dr.isfinite(l_d), l_d, 0.0)  # the throughput itself
        else:
            tn, p_hit = sample_height_hit(mfa if traced else mfs, wr, t, u_h)
            active &= p_hit > 0.0
            thr = thr * p_hit
            thr_at = dr.detach(thr)
        t = tn
        wi_l = -wr
        wo_l = dr.select(outside, wo_, -wo_)
        e = eta_seen(eta_a, outside)
        e_s = dr.detach(e) if traced else e
        same = wo_out == outside
        # Next-event estimation towards ω_o.
        if dirs:  # Heitz's phase functions times L: the position-free vertex values
            p = dr.select(same, vertex_reflect(mfa, e, wi_l, wo_l), vertex_transmit(mfa, e, wi_l, wo_l))
        elif traced:
            p = dr.select(same, dielectric_phase_reflect(mfa, wi_l, wo_l, e),
                          dielectric_phase_transmit(mfa, wi_l, wo_l, e))
        else:  # one half vector, D and Fresnel factor per lane; Λ of the height step's direction (the same bits)
            p = phase_next_event(mfa, wi_l, wo_l, e, ~same, mfs.lambda_up(mfs.alpha_tan2(wr)))
        t_o = dr.select(same, t, flip_height(t))
        contrib = p * masking_at(lo, t_o)
        result = dr.select(active & (contrib > 0.0), result + thr * contrib, result)
        active &= order < last
        # Continue: reflect or refract about a visible normal, then the roulette.
        u1, u2 = rng.next2()
        ua, u_mix = rng.next2()
        if traced:
            ws = dr.detach(wi_l)
            teta = dr.select(outside, 1.0, -e_s * e_s) if not dirs else dr.zeros(mi.Float, dr.width(e_s))
            u_e = rng.next2() + rng.next2()  # drawn in every traced call: the same stream with η or without
            t_s, lo_s = dr.detach(t), dr.detach(lo)
            pairs = ((False, u_e[0], u_e[1]), (True, u_e[2], u_e[3]))
            if eta_traced:
                edge = sum(dielectric_edge_term(mfs, ws, tw, t_s, outside, e_s, teta, wo, lo_s, b, u_phi, u_hb)
                           for b, u_phi, u_hb in pairs)
                result = dr.select(active, result + (eta_a - dr.detach(eta_a)) * thr_at * edge, result)
            if dir_edges:  # the same circles, moving with ω_o and with w along s
                edge = sum(dielectric_edge_term(mfs, ws, tw, t_s, outside, e_s, teta, dr.detach(wo_), lo_s, b,
                                                u_phi, u_hb, dr.detach(two)) for b, u_phi, u_hb in pairs)
                result = dr.select(active, result + (s_dir - dr.detach(s_dir)) * thr_at * edge, result)
            wr, crossed, _, valid, weight, m = scatter_traced(mfa, mfs, wi_l, mi.Float(1.0), e, ua, u1, u2, u_mix,
                                                              times_area=dirs)
            tw = eta_tangent_step(ws, tw, m, e_s, teta, crossed)
            piped = lv.piped(eta_a, tw, wo_, s_dir, two) if dirs else lv.piped(eta_a, tw)
            thr = thr * weight
        else:
            # The roulette before the scatter (which leaves thr as it is here): the visible normal only in the
            # lanes that go on (the same bits).
            thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0)
            m, cos_wm, valid = visible_normal(mfs, wi_l, u1, u2, where=active & survived)
            wr, crossed = scatter_unit(wi_l, m, cos_wm, e_s, ua)
        outside = outside ^ crossed
        t = dr.select(crossed, flip_height(t), t)
        if traced:
            thr, survived = walk.russian_roulette_keep(thr, u_rr, 1.0, RR_TRACED_FLOOR)
        active &= valid & survived & dr.all(dr.isfinite(wr))
        return dict(order=order + 1, wr=wr, t=t, outside=outside, thr=thr, result=result, active=active,
                    counter=rng.counter, piped=piped)

    state = dict(order=mi.UInt32(order), wr=mi.Vector3f(wr), t=mi.Float(t), outside=mi.Bool(outside),
                 thr=mi.Float(thr), result=mi.Float(0.0), active=mi.Bool(active & (order <= last)),
                 counter=mi.UInt32(counter), piped=())
    if traced:
        more = () if direction is None else (mi.Vector3f(wo), mi.Float(direction[0]), mi.Vector3f(direction[1]))
        state["piped"] = LoopValues.state(mf, lambda_o, mi.Float(eta),
                                          mi.Vector3f(0.0) if tw is None else mi.Vector3f(tw), *more)
    return walk.while_loop(state, body, label="msx_heitz_dielectric_eval")["result"]


def dielectric_eval(mf, eta, radiance, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """One unbiased estimate of f(ω_i, ω_o)·|cos θ_o| through a rough dielectric, orders
    1..max_bounces (Rust ``eval``), one channel: the walk of ``dielectric_eval_from`` entering from ω_i's
    side at the top of the microsurface; Radiance mode: × 1/η_r² when ω_o is across. ``mf_sample``: see
    ``dielectric_eval_from``. ``direction_tangent`` (traced only): (s, t_i, t_o) while one coordinate s of
    ω_i, ω_o is differentiated (gradients.TangentCoordinates); ω_i enters the first state attached."""
    eta = mi.Float(eta)
    wi, wo = mi.Vector3f(wi), mi.Vector3f(wo)
    wi_out = wi[2] > 0.0
    start = valid_incidence_dielectric(wi, eta) & valid_incidence_dielectric(wo, eta) & (max_bounces > 0)
    w0 = -dr.select(wi_out, wi, -wi)
    tw, direction = None, None
    if mf_sample is not None and direction_tangent is not None:
        s_dir, t_i, t_o = direction_tangent
        t_i = mi.Vector3f(t_i)
        tw, direction = dr.select(wi_out, t_i, -t_i), (s_dir, t_o)  # the tangent of −w0 = ω_i in its side's frame
    v = dielectric_eval_from(mf, eta, wo, w0, mi.Float(0.0), wi_out, mi.UInt32(1), mi.Float(1.0), start,
                             max_bounces, key, mi.UInt32(0), mf_sample=mf_sample, tw=tw, direction=direction)
    return v * radiance_scale(eta, radiance, wi_out, wo[2] > 0.0)


def dielectric_sample(mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampling through a rough dielectric (Rust ``sample`` with ``sample_from``): (u1, u2)
    drive the first visible normal and ``sample1`` the first reflect/refract choice; the heights and later
    vertices come from the lane's stream. Returns (ω_o, weight, valid): weight 1 (the walk's vertex
    weights are 1), × 1/η_r² in Radiance mode when ω_o is across."""
    eta = mi.Float(eta)
    wi = mi.Vector3f(wi)
    wi_out = wi[2] > 0.0
    start = valid_incidence_dielectric(wi, eta) & (max_bounces > 0)
    rng0 = Stream(key)
    u_h0, _ = rng0.next2()
    w0 = -dr.select(wi_out, wi, -wi)
    t0, hit0 = sample_height(mf, w0, mi.Float(0.0), u_h0)
    wo, thr, done = sample_from(mf, DielectricFacets(eta), w0, t0, wi_out, 0, mi.Float(1.0), start & hit0,
                                max_bounces, key, rng0.counter, (sample1, u1, u2))
    return wo, thr * radiance_scale(eta, radiance, wi_out, wo[2] > 0.0), done

# The conductor walk this module provides (jit/bsdf.py collects it): height-correlated order-1 exit in
# the MIS density, and no walk from below the macro surface.
CONDUCTOR_WALKS = {"heitz": ConductorWalk(eval, sample, mis.HEIGHT_CORRELATED, below=False, differentiable=True,
                                          direction_distributions=(BECKMANN, GGX))}

# The walks on the other microsurfaces (jit/bsdf.py collects them; their MIS densities are
# ``mis.dielectric_pdf`` and ``mis.diffuse_pdf``).
DIELECTRIC_WALKS = {"heitz": DielectricWalk(dielectric_eval, dielectric_sample, differentiable=True,
                                            eta_differentiable=True, direction_distributions=(BECKMANN, GGX))}
DIFFUSE_WALKS = {"heitz": DiffuseWalk(diffuse_eval, diffuse_sample, differentiable=True,
                                        direction_distributions=(BECKMANN, GGX))}
