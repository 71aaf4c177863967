"""Position-free multiple scattering, Wang et al. 2022, in the Dr.Jit engine: twin of
``src/models/posfree/`` (``mod.rs``: the segment factors and the roulette; ``conductor.rs``: the PT
estimator with next-event estimation, the random-walk sampler and the vertex terms of the bidirectional
estimator, whose strategies are in jit/bdpt.py).

A path is d_0 = −ω_i, …, d_k = ω_o; with L_j = |Λ(d_j)| the pair factors of the segment models are
(``mod.rs`` has the table and its derivation):

| pair                    | uncorrelated | correlated |
|---|---|---|
| middle, d_{j+1} upward   | Λ/(1+Λ)      | Λ/(L_j+Λ)  |
| last (ω_o upward)        | 1/(L_j(1+Λ_o)) | 1/(L_j+Λ_o) |

The walks are ``dr.while_loop``s over named state (``walk.while_loop``): the vertex index, the direction the
light comes from, L_j, the throughput, the estimate, the lane's random stream (key, counter) and, while
differentiated, the values the loop must carry (``piped``: gradients.LoopValues).
"""

import math
from functools import partial

import drjit as dr
import mitsuba as mi

from . import bdpt, mis, walk
from .model import ConductorWalk, DiffuseWalk
from .gradients import LoopValues
from .microfacet import BECKMANN, GGX, INV_PI, ConductorFresnel, dot, half_vector, max_channel, normalized, reflect
from .rng import Stream

UNCORRELATED = "uncorrelated"
CORRELATED = "correlated"

# src/models/posfree/mod.rs and conductor.rs: where roulette starts, the weight of the next-event value
# and of the last-segment factor in the roulette's importance (measured there; the same values here).
RR_START = 1
RR_NEE_GAIN = 30.0
RR_LAST_WEIGHT = 0.05
# The smallest L_j the traced uncorrelated walk's last factor takes (``pt_walk``): 1/L_j² stays finite.
TRACED_L_MIN = 1e-15


def continue_up(segments, l, lam):
    """L_j·(p_j e_{j+1}) of a middle segment going upward with Λ = Λ(d_{j+1}); 1 for an infinite Λ."""
    v = lam / (1.0 + lam) if segments == UNCORRELATED else lam / (l + lam)
    return dr.select(dr.isinf(lam), 1.0, v)


def last(segments, l, lambda_o):
    """p_j·e_k of the last segment towards ω_o."""
    if segments == UNCORRELATED:
        return 1.0 / (l * (1.0 + lambda_o))
    return 1.0 / (l + lambda_o)


def roulette_importance(nee, last_factor, gain):
    """Importance per unit throughput of a walk at a vertex (mod.rs ``roulette_importance``)."""
    return dr.maximum(dr.maximum(gain * nee, RR_LAST_WEIGHT * last_factor), 1.0)


def nee_term(mf, w, wo, last_factor):
    """The conductor's next-event term without the Fresnel factor: (w·h, D(h)·last/(4|w_z|), valid)."""
    h, length = half_vector(w, wo)
    cos_wh = dot(w, h)
    valid = (length > 0.0) & (cos_wh > 0.0) & (dot(wo, h) > 0.0)
    value = mf.d(h) * last_factor / (4.0 * dr.abs(w[2]))
    return cos_wh, dr.select(valid, value, 0.0), valid


def eval_pt(segments, mf, fresnel, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """One PT estimate of f(ω_i, ω_o)·cos θ_o (Wang eqs. 24–26), all orders 1..max_bounces: the walk
    closes the path towards ω_o at every vertex and samples the next direction from the visible normals.
    ω_i may lie below the macro surface (normal mapping); ω_o must point up. ``mf_sample``,
    ``direction_tangent``: see ``pt_walk``."""
    lambda_o = mf.lambda_(wo)
    start = (wi[2] != 0.0) & (wo[2] > 0.0)
    width = dr.width(wi)
    # Vertex 0: light arrives from ω_i, L_0 = |Λ(d_0)| = |Λ(−ω_i)| (1 + Λ(ω_i) for ω_i above).
    return pt_walk(segments, mf, fresnel, wo, lambda_o, mi.Vector3f(wi), mf.abs_lambda(-wi),
                   dr.full(mi.Spectrum, 1.0, width), start, 0, max_bounces, RR_START, key, mi.UInt32(0),
                   mf_sample=mf_sample, direction_tangent=direction_tangent)


def horizon_circle(w, tw, wo, u):
    """The point of the circle of new directions d with d_z = ω_o,z at the azimuth 2πu, where the next
    vertex's half vector towards ω_o turns horizontal (``horizon_edge_term``; shared with heitz.py): (d, m the
    normal that reflects w into d, w·m, h the horizontal half vector of −d and ω_o, u_z the speed of d_z at the
    fixed m from the tangent ``tw`` of w, valid). Detached inputs."""
    z = wo[2]
    r = dr.safe_sqrt(1.0 - z * z)
    sp, cp = dr.sincos(2.0 * math.pi * u)
    d = mi.Vector3f(r * cp, r * sp, z)
    m, length = half_vector(w, d)
    cos_wm = dot(w, m)
    # The next vertex: light from w' = −d, its half vector towards ω_o horizontal (its z is 0 on the circle).
    h = mi.Vector3f(wo[0] - d[0], wo[1] - d[1], 0.0)
    h_len = dr.norm(h)
    h = h / dr.select(h_len > 0.0, h_len, 1.0)
    u_z = -tw[2] + 2.0 * dot(tw, m) * m[2]
    ok = (length > 0.0) & (cos_wm > 0.0) & (m[2] > 0.0) & (h_len > 0.0) & (z > 0.0)
    return d, m, cos_wm, h, u_z, ok


def horizon_edge_term(segments, mf, fresnel, w, tw, l, wo, two, lambda_o, u):
    """The term of a directional derivative that the next vertex's next-event value misses where it jumps
    (GGX; docs/gradients.md, "Directions through the walks"): from a vertex reached going up, that value jumps
    from D(h) at a horizontal h to 0 on the circle of new directions d with d_z = ω_o,z, which moves with the
    directions. In the space of new directions the term is ∫ ρ(d)·V⁺(d)·(∂ω_o,z − u_z) dφ over that circle
    (solid angle dz dφ): ρ the step's density times its weight, F(w·m)·D(m)/(4|w_z|L)·c(d), m the normal that
    reflects w into d; V⁺ the next value's limit on its nonzero side; u_z the speed of d_z at fixed m, from the
    tangent ``tw`` of w; ``two`` the tangent of ω_o. One uniform azimuth ``u`` estimates it. Everything here
    is detached: the term enters as (s − s̄)·term, a derivative with no value."""
    d, m, cos_wm, h, u_z, ok = horizon_circle(w, tw, wo, u)
    z = wo[2]
    lam = mf.abs_lambda(d)
    rho = fresnel.eval(cos_wm) * (mf.d(m) / (4.0 * dr.abs(w[2]) * l) * continue_up(segments, l, lam))
    v = fresnel.eval(dot(-d, h)) * (mf.d_horizon(h) * last(segments, lam, lambda_o) / (4.0 * z))
    term = 2.0 * math.pi * rho * v * (two[2] - u_z)
    ok &= lam > 0.0
    return dr.select(ok & dr.all(dr.isfinite(term)), term, 0.0)


def pt_walk(segments, mf, fresnel, wo, lambda_o, w, l, thr, active, first_vertex, max_bounces, rr_start, key,
            counter, label="msx_posfree_conductor_pt", mf_sample=None, direction_tangent=None):
    """The PT-with-NEE walk (twin of ``pt_walk`` in conductor.rs) from vertex ``first_vertex`` (0-based;
    a Python int or a UInt32 per lane) on, arriving there with the state (w = −d_j, l = L_j, ``thr`` the
    prefix throughput) on the lanes ``active``: at each vertex ≥ ``rr_start`` play Russian roulette on the
    vertex's importance (its next-event value included), close the path towards ω_o, then sample the next
    direction from the visible normals and multiply the Fresnel term and the continue factor; orders up to
    ``max_bounces``. The lane's stream is (``key``, ``counter``). Shared by ``eval_pt`` and the PT tail of
    the bidirectional estimator. Returns the estimate (mi.Spectrum).

    ``mf_sample`` (docs/gradients.md): the microfacet statistics the directions are drawn from, when they
    are not ``mf`` — the parameters with their derivatives detached. The normal is drawn with w detached too
    and the attached w reflected about it; each step's throughput carries the ratio of the visible-normal
    density ⟨w·m⟩·D(m)/(|w_z|·L_j) under the attached values to the same detached (value 1, the score as
    derivative), and the roulette's survival probability is detached: the estimate's derivative is then an
    unbiased estimate of the derivative of f, in the parameters and in ω_i, ω_o (docs/gradients.md).

    ``direction_tangent`` (traced only): (s, t_i, t_o) while one coordinate s of the directions is
    differentiated (gradients.TangentCoordinates), t_i and t_o the tangents of ω_i and ω_o in s. Where the
    distribution's D does not vanish at horizontal normals (GGX), each vertex then adds the edge term of the
    next vertex's next-event value (``horizon_edge_term``), with the tangent of w carried in the state."""
    traced = mf_sample is not None
    edges = traced and direction_tangent is not None and mf.dist != BECKMANN

    def body(j, w, l, thr, result, active, counter, piped):
        # Traced, the differentiated values come through the loop's state (gradients.LoopValues): the
        # material, then ω_o (which carries the derivative in the directions, if any).
        mfa, mfs, lo, rest = LoopValues.unpack(traced, mf, lambda_o, (), piped)
        if edges:  # ... then the coordinate s, the tangents of w and of ω_o
            material, (wo_, s_dir, tw, two) = rest[:-4], rest[-4:]
        else:
            material, wo_ = (rest[:-1], rest[-1]) if traced else ((), wo)
        fr = ConductorFresnel(*material) if material else fresnel
        rng = Stream(key, counter)
        active &= (l > 0.0) & dr.isfinite(l) & (max_channel(thr) > 0.0)
        # Traced, the uncorrelated last factor 1/(L_j(1 + Λ_o)) takes L_j ≥ TRACED_L_MIN: after an upward step
        # with a tiny Λ its derivative, ∝ 1/L_j², overflows and makes the whole lane's derivative NaN (which
        # gradients.attach then drops: measured, a 0.4 % bias at Beckmann α = 0.3). Such a vertex is reached
        # going up close to the normal (Λ falls as e^{−1/(α tan θ)²}: within ~10–20° for Beckmann α ≤ 1, a
        # hair's breadth for GGX), so its next-event half vector towards ω_o lies below or nearly at the
        # horizon, where D vanishes in float32 (Beckmann), or is below it unless ω_o is closer still to the
        # normal (GGX): the value does not change.
        last_factor = last(segments, dr.maximum(l, TRACED_L_MIN) if traced and segments == UNCORRELATED else l, lo)
        cos_wh, nee, nee_ok = nee_term(mfa, w, wo_, last_factor)
        u_rr, u_edge = rng.next2()
        importance = roulette_importance(nee, last_factor, RR_NEE_GAIN)
        thr, alive = walk.roulette_from(j >= rr_start, thr, u_rr,
                                        1.0 / (importance if not traced else dr.detach(importance)))
        active &= alive
        result = dr.select(active & nee_ok, result + thr * fr.eval(cos_wh) * nee, result)
        active &= j + 1 < max_bounces
        if edges:
            frd = ConductorFresnel(*[dr.detach(x) for x in material]) if material else fresnel
            edge = horizon_edge_term(segments, mfs, frd, dr.detach(w), tw, dr.detach(l), dr.detach(wo_), two,
                                     dr.detach(lo), u_edge)
            result = dr.select(active, result + (s_dir - dr.detach(s_dir)) * dr.detach(thr) * edge, result)

        def next_vertex(w, l, thr, active, counter):
            """The next direction, from the visible normals of w."""
            rng = Stream(key, counter)
            u1, u2 = rng.next2()
            # Traced, the normal is drawn with everything detached and the new direction reflects the
            # attached w about it: the draw happens in the space of normals (docs/gradients.md).
            m, valid = mfs.sample_visible(dr.detach(w) if traced else w, u1, u2)
            cos_wm = dot(w, m)
            d_next = reflect(w, m)
            thr = thr * fr.eval(cos_wm)
            if traced:
                # The visible-normal density ⟨w·m⟩·D(m)/A(w), A(w) = |w_z|·L, under the attached values over
                # the same detached: 1, with the score of the draw as its derivative.
                q = cos_wm * mfa.d(m) / (dr.abs(w[2]) * l)
                thr = thr * dr.select(dr.detach(q) > 0.0, q / dr.detach(q), 0.0)
            up = d_next[2] > 0.0
            lam = mfa.abs_lambda(d_next)
            thr = dr.select(up, thr * continue_up(segments, l, lam), thr)
            return -d_next, lam, thr, active & valid & (cos_wm > 0.0), rng.counter, m

        step = (w, l, thr, active, rng.counter)
        if traced:
            w, l, thr, active, counter, m = next_vertex(*step)
            if edges:  # the tangent of the next w = w − 2(w·m)m at the fixed normal
                tw = tw - 2.0 * dot(tw, m) * m
                piped = piped[:-4] + (wo_, s_dir, tw, two)
        else:
            # A packet whose lanes have all ended (the last vertex; auto's order-1 lanes) skips the sampling:
            # a symbolic if_stmt branches per packet. An ended lane's state is never read again.
            w, l, thr, active, counter = dr.if_stmt(step, active, lambda *a: next_vertex(*a)[:5], lambda *a: a,
                                                    label="msx_posfree_next_vertex")
        return dict(j=j + 1, w=w, l=l, thr=thr, result=result, active=active, counter=counter, piped=piped)

    width = dr.width(thr)
    piped = ()
    if traced:
        material = () if fresnel.mirror else (mi.Spectrum(fresnel.eta), mi.Spectrum(fresnel.k))
        piped = LoopValues.state(mf, lambda_o, *material, mi.Vector3f(wo))
        if edges:
            s_dir, t_i, t_o = direction_tangent
            piped += (mi.Float(s_dir), mi.Vector3f(t_i), mi.Vector3f(t_o))
    state = dict(j=mi.UInt32(first_vertex), w=mi.Vector3f(w), l=mi.Float(l), thr=mi.Spectrum(thr),
                 result=dr.zeros(mi.Spectrum, width), active=mi.Bool(active), counter=mi.UInt32(counter),
                 piped=piped)
    return walk.while_loop(state, body, label=label)["result"]


def sample_vertex(segments, mf, fresnel):
    """A vertex of the random-walk sampler (``sample_walk``; also ``auto``'s sampler, jit/auto.py):
    ``vertex(w, weight, u, L_j, rng, active)`` → (d, weight, leaves, continues, Λ(d)) for ``walk.sample_walk``:
    the visible normal drawn with (u1, u2) of ``u``, the reflection, its Fresnel factor, and the exit with
    probability 1 − continue_up at an upward direction decided by u_exit."""

    def vertex(w, weight, u, l, rng, active):
        u_exit, u1, u2 = u
        m, valid = mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        valid &= cos_wm > 0.0
        d_next = reflect(w, m)
        weight = weight * fresnel.eval(cos_wm)
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        leaves = up & (u_exit >= continue_up(segments, l, lam))
        return d_next, weight, valid & leaves, valid & ~leaves, lam

    return vertex


def sample_walk(segments, mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampler (Wang §4.3): at each upward direction the walk leaves with probability
    1 − continue_up, so the weight is the product of the Fresnel terms. The first vertex uses Mitsuba's
    (sample1, sample2), later ones the lane's stream (``walk.sample_walk``, whose exit state here is L_j).
    Returns (ω_o, weight, valid)."""
    return walk.sample_walk(wi, (sample1, u1, u2), wi[2] != 0.0, mf.abs_lambda(-wi),
                            sample_vertex(segments, mf, fresnel), max_bounces, key,
                            dr.full(mi.Spectrum, 1.0, dr.width(wi)), "msx_posfree_conductor_sample")


# ------------------------------------------------------------------ the bidirectional estimator
# (Wang 2022 §4.2, eqs. 27–29; conductor.rs ``Bidirectional``, jit/bdpt.py the strategies)
#
# With L_j = |Λ(d_j)| and the pair factors above, eq. 1 factors into one term per vertex j:
#   f = Π φ_j(d_j, d_{j+1}),  φ_j = F_j·D(h_j)/(4|cos d_j|)·g_j,  h_j = normalize(−d_j + d_{j+1}),
#   g_j = cont(L_j, d_{j+1})/L_j (j < k−1),  g_{k−1} = last(L_{k−1}, Λ(ω_o)).
# Densities (solid angle), A(ω) the projected area (A(−d_j) = |cos d_j|·L_j):
#   camera step at j: pf_j = D(h_j)/(4 A(−d_j)), so φ_j/pf_j = F_j·cont;
#   light step at j:  pr_j = D(h_j)/(4 A(d_{j+1})), so φ_j/pr_j = F_j·A(d_{j+1})·g_j/|cos d_j|.


def smith(mf, d):
    """(L = |Λ(d)|, A(d), A(−d)) of a direction from one Λ evaluation (twin of ``smith``), without
    cancellation: u = Λ of the upward direction with the same slope."""
    u = mf.lambda_up(mf.alpha_tan2(d))
    c = dr.abs(d[2])
    up = d[2] >= 0.0
    return (dr.select(up, u, 1.0 + u), dr.select(up, c * (1.0 + u), c * u), dr.select(up, c * u, c * (1.0 + u)))


def cont(segments, l, nxt, l_next):
    """g_j·L_j of a middle vertex: the continue factor of an upward next direction, 1 for a downward one."""
    return dr.select(nxt[2] > 0.0, continue_up(segments, l, l_next), 1.0)


class CamVertex:
    """A camera vertex: d_s, L_s, A(−d_s) and the prefix f/p (Π F·cont)."""

    def __init__(self, d, l, area_back, thr):
        self.d, self.l, self.area_back, self.thr = d, l, area_back, thr


class LightVertex:
    """A light vertex: e_t = d_{k−t}, |Λ(e_t)|, A(e_t) and Π φ/pr of its t steps."""

    def __init__(self, e, l, area, w):
        self.e, self.l, self.area, self.w = e, l, area, w


class PairSegments:
    """Wang's segment models as the bidirectional estimator uses them (twin of ``ConductorSegments for
    Segments``): pair factors along the path, no whole-path factor, the PT tail is ``pt_walk``."""

    whole_path = None

    def __init__(self, segments):
        self.segments = segments

    def cont(self, l, nxt, l_next):
        return cont(self.segments, l, nxt, l_next)

    def last(self, l, lambda_o):
        return last(self.segments, l, lambda_o)

    def pt_tail(self, surface, cam, ready, kb, orders, rng):
        """Orders above K_b: ``pt_walk`` from camera vertex K_b (roulette from vertex K_b + RR_START) on the
        lanes ``ready``; on the lanes ``surface.below`` (ω_i below the macro surface) the whole PT estimate
        from vertex 0, in the same loop."""
        cv, below = cam[kb], surface.below
        width = dr.width(cv.l)
        w = dr.select(below, surface.wi, -cv.d)
        l = dr.select(below, surface.mf.abs_lambda(-surface.wi), cv.l)
        thr = dr.select(below, dr.full(mi.Spectrum, 1.0, width), cv.thr)
        first = dr.select(below, mi.UInt32(0), mi.UInt32(kb))
        rr_start = dr.select(below, mi.UInt32(RR_START), mi.UInt32(kb + RR_START))
        return pt_walk(self.segments, surface.mf, surface.fresnel, surface.wo, surface.lambda_o, w, l, thr,
                       ready | below, first, orders[1], rr_start, rng.key, rng.counter,
                       label="msx_posfree_conductor_bdpt_tail")


class Bidirectional:
    """The conductor's vertex terms for jit/bdpt.py (twin of ``Bidirectional`` in conductor.rs), with the
    segment term ``seg`` (``PairSegments`` or a model's whole-path term). ``active``: the lanes with ω_i and
    ω_o above the surface; ``below``: the lanes the PT tail serves whole (ω_i below, ω_o above)."""

    def __init__(self, mf, fresnel, seg, wi, wo, active, below):
        self.mf, self.fresnel, self.seg, self.wi, self.wo = mf, fresnel, seg, wi, wo
        self.lambda_o = mf.lambda_(wo)
        self.active, self.below = active, below
        self.width = dr.width(wi)

    def zero(self):
        return dr.zeros(mi.Spectrum, self.width)

    def g(self, l, nxt, l_next, is_last):
        """g_j of the vertex between an arriving direction with |Λ| = l and the next direction ``nxt``
        (|Λ(nxt)| = l_next; ω_o when ``is_last``, a Python bool)."""
        if is_last:
            return self.seg.last(l, self.lambda_o)
        return self.seg.cont(l, nxt, l_next) / l

    # ---- camera subpath

    def camera_start(self):
        l0 = 1.0 + self.mf.lambda_(self.wi)
        return CamVertex(-mi.Vector3f(self.wi), l0, self.mf.projected_area(self.wi),
                         dr.full(mi.Spectrum, 1.0, self.width))

    def camera_ready(self, v):
        return (v.l > 0.0) & dr.isfinite(v.l) & (v.area_back > 0.0)

    def camera_step(self, v, s, rng):
        w = -v.d
        u1, u2 = rng.next2()
        m, valid = self.mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        d_next = reflect(w, m)
        l_next, area_next, area_back_next = smith(self.mf, d_next)
        dm = self.mf.d(m)
        pf = dm / (4.0 * v.area_back)
        valid &= (cos_wm > 0.0) & (pf > 0.0) & dr.isfinite(pf) & (area_next > 0.0)
        p_rev = dm / (4.0 * area_next) if s >= 1 else mi.Float(0.0)
        thr = v.thr * self.fresnel.eval(cos_wm) * self.seg.cont(v.l, d_next, l_next)
        return CamVertex(d_next, l_next, area_back_next, thr), pf, p_rev, valid

    def camera_last(self, v, ready, rng):
        return v

    # ---- light subpath

    def light_start(self):
        return LightVertex(mi.Vector3f(self.wo), self.lambda_o, self.mf.projected_area(self.wo),
                           dr.full(mi.Spectrum, 1.0, self.width))

    def light_ready(self, v):
        return (v.area > 0.0) & dr.isfinite(v.area)

    def light_step(self, v, t, rng):
        u1, u2 = rng.next2()
        m, valid = self.mf.sample_visible(v.e, u1, u2)
        cos_em = dot(v.e, m)
        e_next = -reflect(v.e, m)  # d_j, arriving at vertex j = k−1−t
        l_next, area_next, area_back_next = smith(self.mf, e_next)
        cos_next = dr.abs(e_next[2])
        dm = self.mf.d(m)
        pr = dm / (4.0 * v.area)
        valid &= ((cos_em > 0.0) & (l_next > 0.0) & dr.isfinite(l_next) & (cos_next > 0.0)
                  & (pr > 0.0) & dr.isfinite(pr) & (area_back_next > 0.0))
        # φ_j / pr_j = F·A(d_{j+1})·g_j / |cos d_j|.
        g = self.g(l_next, v.e, v.l, t == 0)
        w = v.w * self.fresnel.eval(cos_em) * (v.area * g / cos_next)
        p_rev = dm / (4.0 * area_back_next) if t >= 1 else mi.Float(0.0)
        return LightVertex(e_next, l_next, area_next, w), pr, p_rev, valid

    # ---- connections

    def connect(self, cam, light):
        s, t = len(cam) - 1, len(light) - 1
        cv, lv = cam[s], light[t]
        cos_s = dr.abs(cv.d[2])
        h, length = normalized(-cv.d + lv.e)
        cos_h = -dot(cv.d, h)
        dh = self.mf.d(h)
        valid = ((max_channel(cv.thr) > 0.0) & (max_channel(lv.w) > 0.0) & (cv.l > 0.0) & dr.isfinite(cv.l)
                 & (cos_s > 0.0) & (lv.area > 0.0) & (length > 0.0) & (h[2] > 0.0) & (cos_h > 0.0) & (dh > 0.0))
        phi = dh * self.g(cv.l, lv.e, lv.l, t == 0) / (4.0 * cos_s)
        if self.seg.whole_path is not None:
            whole, ok = self.seg.whole_path(self, cam, light)
            phi = phi * whole
            valid &= ok
        pr = dh / (4.0 * lv.area) if s >= 1 else mi.Float(0.0)
        pf = dh / (4.0 * cv.area_back) if t >= 1 else mi.Float(0.0)
        return pr, pf, (phi, cos_h), valid

    def weighted(self, data, cv, lv, denom):
        phi, cos_h = data
        weight = phi / denom
        return cv.thr * lv.w * self.fresnel.eval(cos_h) * weight, dr.isfinite(weight)

    def pt_tail(self, cam, ready, kb, orders, rng):
        return self.seg.pt_tail(self, cam, ready, kb, orders, rng)


def estimate_bdpt(mf, fresnel, seg, wi, wo, max_bounces, key, bdpt_orders=bdpt.DEFAULT_BDPT_ORDERS):
    """The bidirectional estimate of a conductor with the segment term ``seg`` (twin of ``eval_bdpt_with``
    and ``estimate_bdpt``), orders 1..max_bounces (a Python int): ω_i and ω_o above the surface
    bidirectionally; ω_i below with ω_o above by the PT walk (same expectation; in the tail's loop when
    there is one); 0 elsewhere."""
    if max_bounces < 1:
        return dr.zeros(mi.Spectrum, dr.width(wi))
    active = (wi[2] > 0.0) & (wo[2] > 0.0)
    below = (wi[2] < 0.0) & (wo[2] > 0.0)
    surface = Bidirectional(mf, fresnel, seg, wi, wo, active, below)
    kb = bdpt.bdpt_orders(max_bounces, bdpt_orders)
    rng = Stream(key)
    result = bdpt.estimate(surface, (1, max_bounces), bdpt_orders, rng=rng)
    if max_bounces <= kb:  # no PT tail: the lanes below get their own walk
        width = dr.width(wi)
        result += pt_walk(seg.segments, mf, fresnel, wo, surface.lambda_o, mi.Vector3f(wi), mf.abs_lambda(-wi),
                          dr.full(mi.Spectrum, 1.0, width), below, 0, max_bounces, RR_START, key, rng.counter)
    return result


def estimate_bdpt_above(mf, fresnel, seg, wi, wo, active, max_bounces, key, bdpt_orders=bdpt.DEFAULT_BDPT_ORDERS):
    """The bidirectional estimate with the segment term ``seg`` on the lanes ``active`` (ω_i and ω_o above
    the surface; twin of ``estimate_bdpt``), orders 1..max_bounces (a Python int); no walk from below."""
    surface = Bidirectional(mf, fresnel, seg, wi, wo, active, mi.Bool(False))
    return bdpt.estimate(surface, (1, max_bounces), bdpt_orders, rng=Stream(key))


def conductor_eval_bdpt(segments, mf, fresnel, wi, wo, max_bounces, key):
    """BDPT estimate of f(ω_i, ω_o)·cos θ_o (Wang eqs. 27–29) with K_b = ``bdpt.DEFAULT_BDPT_ORDERS``
    (twin of ``eval_bdpt`` in conductor.rs)."""
    return estimate_bdpt(mf, fresnel, PairSegments(segments), wi, wo, max_bounces, key)


# ------------------------------------------------------------------ diffuse facets (diffuse.rs)


def diffuse_eval_pt(segments, mf, albedo, wi, wo, max_bounces, key, mf_sample=None):
    """PT estimate of f(ω_i, ω_o)·cos θ_o on Lambertian facets of albedo ``albedo`` (diffuse.rs
    ``eval_pt``): per vertex a visible normal m serves the next event, L_j·(a/π)⟨ω_o, m⟩⁺·last, and the
    Lambertian continuation about m; roulette after every vertex. ``mf_sample``: as in ``pt_walk`` (the
    visible normals drawn from the detached statistics and the detached direction, each weighted by its
    density ratio; the cosine lobe about m depends on neither the parameters nor the directions).

    Traced, ω_i and ω_o may carry a derivative (docs/gradients.md, "Directions through the walks"): ω_i
    enters the first vertex alone, through its visible-normal density ⟨w·m⟩⁺·D(m)/(|w_z|·L_0) (later
    directions are cosine draws about detached normals), and ω_o the next events, whose value
    (a/π)⟨ω_o, m⟩⁺·L_j·last is continuous where ⟨ω_o, m⟩ changes sign: no edge term, on either distribution."""
    lambda_o = mf.lambda_(wo)
    start = (wi[2] > 0.0) & (wo[2] > 0.0)
    width = dr.width(wi)
    traced = mf_sample is not None

    def body(j, w, l, thr, result, active, counter, piped):
        # Traced, the differentiated values come through the loop's state (gradients.LoopValues): the
        # albedo, then ω_o.
        mfa, mfs, lo, (a, wo_) = LoopValues.unpack(traced, mf, lambda_o, (albedo, wo), piped)
        rng = Stream(key, counter)
        active &= (l > 0.0) & dr.isfinite(l) & (max_channel(thr) > 0.0)
        u1, u2 = rng.next2()
        m, valid = mfs.sample_visible(dr.detach(w) if traced else w, u1, u2)
        active &= valid
        if traced:
            # The visible-normal density ⟨w·m⟩·D(m)/(|w_z|·L_j) under the attached values over the same
            # detached (``pt_walk``), written as the ratio of D's and L's times that of the direction's part,
            # ⟨w·m⟩/|w_z|, which is 1 with no derivative unless w moves (the first vertex under moving ω_i).
            cos_ratio = dot(w, m) / dr.abs(w[2])
            thr = thr * ((mfa.d(m) * dr.detach(l)) / (mfs.d(m) * l))
            thr = thr * dr.select(dr.detach(cos_ratio) > 0.0, cos_ratio / dr.detach(cos_ratio), 0.0)
        c = dot(wo_, m)
        nee = a * (c * INV_PI * l * last(segments, l, lo))
        result = dr.select(active & (c > 0.0), result + thr * nee, result)
        active &= j + 1 < max_bounces
        u3, u4 = rng.next2()
        d_next = walk.cosine_about(m, u3, u4)
        thr = thr * a
        up = d_next[2] > 0.0
        lam = mfa.abs_lambda(d_next)
        thr = dr.select(up, thr * continue_up(segments, l, lam), thr)
        thr, alive = walk.roulette_from(j + 1 >= RR_START, thr, rng.next())
        active &= alive
        return dict(j=j + 1, w=-d_next, l=lam, thr=thr, result=result, active=active, counter=rng.counter,
                    piped=piped)

    state = dict(j=mi.UInt32(0), w=mi.Vector3f(wi), l=1.0 + mf.lambda_(wi), thr=dr.full(mi.Spectrum, 1.0, width),
                 result=dr.zeros(mi.Spectrum, width), active=mi.Bool(start), counter=mi.UInt32(0),
                 piped=LoopValues.state(mf, lambda_o, mi.Spectrum(albedo), mi.Vector3f(wo)) if traced else ())
    return walk.while_loop(state, body, label="msx_posfree_diffuse_pt")["result"]


def diffuse_sample_walk(segments, mf, albedo, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampler on Lambertian facets (diffuse.rs ``sample_walk``): (ω_o, weight = Π albedo,
    valid); ``walk.sample_walk``'s exit state is L_j."""

    def vertex(w, weight, u, l, rng, active):
        u_exit, u1, u2 = u
        m, valid = mf.sample_visible(w, u1, u2)
        u3, u4 = rng.next2()
        d_next = walk.cosine_about(m, u3, u4)
        weight = weight * albedo
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        leaves = up & (u_exit >= continue_up(segments, l, lam))
        return d_next, weight, valid & leaves, valid & ~leaves & (lam > 0.0) & dr.isfinite(lam), lam

    return walk.sample_walk(wi, (sample1, u1, u2), wi[2] > 0.0, 1.0 + mf.lambda_(wi), vertex, max_bounces, key,
                            dr.full(mi.Spectrum, 1.0, dr.width(wi)), "msx_posfree_diffuse_sample")


# The conductor walks this module provides, by model name (jit/bsdf.py collects them).
CONDUCTOR_WALKS = {
    name: ConductorWalk(partial(eval_pt, name), partial(sample_walk, name), exit, below=True,
                        eval_bdpt=partial(conductor_eval_bdpt, name), differentiable=True,
                        direction_distributions=(BECKMANN, GGX))
    for name, exit in ((UNCORRELATED, mis.SEPARABLE), (CORRELATED, mis.HEIGHT_CORRELATED))
}
DIFFUSE_WALKS = {name: DiffuseWalk(partial(diffuse_eval_pt, name), partial(diffuse_sample_walk, name),
                                   differentiable=True, direction_distributions=(BECKMANN, GGX))
                 for name in (UNCORRELATED, CORRELATED)}
