"""The invariance principle on conductor facets (Cui et al. 2023) in the Dr.Jit engine: twin of
``src/models/invariance/conductor.rs``. PT ``eval``/``sample`` with the incremental exit table
``MonotoneExit`` (jit/invariance_recursion.py), and the BDPT estimator (``eval_bdpt``: the position-free
conductor's of jit/posfree.py with the whole path's exit probability, ``WholePath``).

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

from . import walk
from .gradients import LoopValues
from .invariance_recursion import MonotoneExit, run_slots
from .microfacet import BECKMANN, ConductorFresnel, dot, half_vector, max_channel, reflect
from .posfree import horizon_circle
from .rng import Stream, mix32, mix32_int

# src/models/invariance/conductor.rs: the roulette's sure-survival level, and the highest order the
# connection strategy serves.
RR_KEEP = 0.5
CONNECT_MAX_ORDER = 3
# The connection's work inside a ``dr.if_stmt`` that packets of lanes skip where none of them makes one
# (``walk_from``); False computes it at every vertex and masks it: the same bits (a test), slower.
CONNECTION_BRANCH = True
# The key of the edge terms' own stream (``walk_from`` along moving directions on GGX): a salt mixed into the
# lane's key, so that the walk's stream is the same with the terms or without.
EDGE_SALT = mix32_int(0x494E5645)


def half_vector_d(mf, w, x):
    """(D(h), w·h) for the half vector h of w and x; (0, 0) where w does not see h."""
    h, length = half_vector(w, x)
    c = dot(w, h)
    ok = (length > 0.0) & (c > 0.0)
    return dr.select(ok, mf.d(h), 0.0), dr.select(ok, c, 0.0)


def valid_direction(w):
    return dr.all(dr.isfinite(w)) & (w[2] > 0.0)


class LightVertex:
    """The connection's one-vertex light subpath: y = −(ω_o reflected about a visible normal of ω_o)
    (twin of ``LightVertex``)."""

    def __init__(self, mf, fresnel, wo, pdf_scale_o, u1, u2, mf_sample=None):
        # Drawn with ``mf_sample``, the normal is drawn for the detached ω_o and the attached ω_o reflects about
        # it (docs/gradients.md, "Directions through the walks"); ``jacobian`` is then ⟨ω_o·m⟩ over its
        # detached value, the change of the reflection's Jacobian 4⟨ω_o·m⟩ from the space of normals to y's.
        traced = mf_sample is not None
        m, valid = (mf if mf_sample is None else mf_sample).sample_visible(dr.detach(wo) if traced else wo, u1, u2)
        cos1 = dot(wo, m)
        self.jacobian = cos1 / dr.detach(cos1) if traced else None
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

    def connect(self, mf, fresnel, has_up, w, pdf_scale, via_up, column_ly_o, traced=False, attached_mis=False):
        """The connection estimate at the vertex (w = −d_m): ``via_up`` = p_exit(.., y, ω_o)/H_m for an
        upward y, ``column_ly_o`` = column(Λ_o) for the downward case (the caller's one pass). ``traced``
        (y drawn with the parameters detached, docs/gradients.md): the balance weight detached (attached with
        ``attached_mis``: ``walk_from``), the integrand over y's detached density."""
        d_h, cos0 = half_vector_d(mf, w, self.y)
        p_fwd = d_h * pdf_scale
        ok = self.valid & (p_fwd > 0.0) & dr.isfinite(p_fwd)
        via_down = dr.select(has_up, 0.0, self.l_y / (self.l_y + self.lambda_o) * column_ly_o)
        exit = dr.select(self.up, via_up, via_down)
        if traced:
            balance = self.pdf / (p_fwd + self.pdf)
            value = (balance if attached_mis else dr.detach(balance)) * (p_fwd * self.phase * exit) / dr.detach(self.pdf)
            value = value * dr.select(dr.detach(self.jacobian) > 0.0, self.jacobian, 0.0)
        else:
            value = p_fwd * self.phase * exit / (p_fwd + self.pdf)
        ok &= (value > 0.0) & dr.isfinite(value)
        return dr.select(ok, fresnel.eval(cos0) * self.fresnel * value, 0.0)


# ------------------------------------------------------------------ edge terms (GGX, moving directions)
#
# docs/gradients.md, "The invariance walk on conductor facets". GGX's D is α²/π at a horizontal normal, so two
# values of the walk jump where a half vector turns horizontal, on circles that move with the directions:
# the next event of the vertex a step reaches going up (its half vector towards ω_o, ``nee_edge_term``) and
# the connection with the light vertex's y (the half vector of w and y, ``connect_edge_term``). Everything in
# them is detached: they enter as (s − s̄)·term.


def _detached_exit(dp):
    """A detached copy of the exit table ``dp`` (its pushes do not touch ``dp``)."""
    return MonotoneExit([dr.detach(x) for x in dp.down], [dr.detach(x) for x in dp.g], dp.a, dp.has_up,
                        dr.detach(dp.hit), dp.unrolled)


def nee_edge_term(mf, fresnel, dp, w, tw, pdf_scale, wo, two, lambda_o, mis_next, u):
    """The term the next vertex's next event misses where it jumps: as ``posfree.horizon_edge_term`` (the
    circle of new directions d with d_z = ω_o,z, ``posfree.horizon_circle``), ∫ ρ(d)·V⁺(d)·(∂ω_o,z − u_z) dφ,
    with this walk's factors: ρ = F(w·m)·D(m)/(4A(w)) (``pdf_scale`` = 1/(4A(w))), and the next value's limit
    V⁺ = (H_{m+1}/H_m)·F(−d·h)·D(h)/(4A(−d))·b⁺·p_exit(d_0..d_m, d, ω_o)/H_{m+1} at the horizontal half vector
    h (D(h) its limit ``d_horizon``; A(−d) = d_z·Λ(d)), b⁺ the balance weight against the connection where the
    next order is one it serves (``mis_next``): p/(p + p_rev⁺), p = D(m)/(4A(w)) the step's density of d and
    p_rev⁺ = D(h)/(4A(ω_o)) the light vertex's. Beyond the circle the walk stops (an upward d at least as
    steep as ω_o), and what the later vertices add goes to 0 there continuously. One uniform azimuth ``u``."""
    d, m, cos_wm, h, u_z, ok = horizon_circle(w, tw, wo, u)
    z = wo[2]
    p_step = mf.d(m) * pdf_scale
    rho = fresnel.eval(cos_wm) * p_step
    l_d = mf.lambda_(d)
    dp = _detached_exit(dp)
    cont = dp.push_up(l_d, ok)
    col_o = dp.column(lambda_o)
    d_h = mf.d_horizon(h)
    p_rev = d_h * (0.25 / (z * (1.0 + lambda_o)))
    balance = dr.select(mis_next, p_step / (p_step + p_rev), 1.0)
    v = cont * fresnel.eval(dot(-d, h)) * (d_h * 0.25 / (z * l_d)) * balance * col_o
    term = 2.0 * math.pi * rho * v * (two[2] - u_z)
    ok &= (l_d > 0.0) & (p_step > 0.0)
    return dr.select(ok & dr.all(dr.isfinite(term)), term, 0.0)


def connect_edge_term(mf, fresnel, dp, col_o, w, tw, pdf_scale, wo, two, lambda_o, u):
    """The term the connection misses where it jumps: its integrand over y (the light vertex's direction,
    y = ω_o − 2(ω_o·m_y)m_y for the light's normal m_y), g(y) = b·p_fwd·phase·exit·F(w·h)·F(ω_o·m_y) with
    p_fwd = D(h)/(4A(w)) and h = normalize(w + y), is nonzero on y_z > −w_z and jumps to 0 where h turns
    horizontal, on the circle y_z = z* = −w_z. y moves with ω_o at the fixed m_y (speed t_o − 2(t_o·m_y)m_y)
    and the circle with w (dz*/ds = −t_w,z): the term is ∫ g⁺(y)·(u_z + t_w,z) dφ over the circle (solid angle
    dz dφ), g⁺ with D(h) at its limit ``d_horizon``, the balance weight b⁺ = p_y/(p_fwd⁺ + p_y) (p_y =
    D(m_y)/(4A(ω_o)), the light's density of y), the light's phase D(m_y)/(4A(y)) and the exit probability
    of the path through y (``LightVertex.connect``). One uniform azimuth ``u``."""
    z = -w[2]
    r = dr.safe_sqrt(1.0 - z * z)
    sp, cp = dr.sincos(2.0 * math.pi * u)
    y = mi.Vector3f(r * cp, r * sp, z)
    m_y, length_y = half_vector(wo, -y)
    cos1 = dot(wo, m_y)
    h = mi.Vector3f(w[0] + y[0], w[1] + y[1], 0.0)
    h_len = dr.norm(h)
    h = h / dr.select(h_len > 0.0, h_len, 1.0)
    cos0 = dot(w, h)
    up = z > 0.0
    l_y = dr.select(up, mf.lambda_(y), mf.abs_lambda(y))
    area_y = dr.abs(z) * l_y
    d_m = mf.d(m_y)
    p_y = d_m * (0.25 / (wo[2] * (1.0 + lambda_o)))
    phase = 0.25 * d_m / area_y
    p_fwd = mf.d_horizon(h) * pdf_scale
    balance = p_y / (p_fwd + p_y)
    via_up = _detached_exit(dp).columns(lambda_o, l_y)[1]
    via_down = dr.select(dp.has_up, 0.0, l_y / (l_y + lambda_o) * col_o)
    exit = dr.select(up, via_up, via_down)
    g = fresnel.eval(cos0) * fresnel.eval(cos1) * (balance * p_fwd * phase * exit)
    u_z = two[2] - 2.0 * dot(two, m_y) * m_y[2]
    term = 2.0 * math.pi * g * (u_z + tw[2])
    ok = ((length_y > 0.0) & (cos1 > 0.0) & (m_y[2] > 0.0) & (h_len > 0.0) & (cos0 > 0.0) & (z != 0.0)
          & (area_y > 0.0) & (p_y > 0.0) & (wo[2] > 0.0))
    return dr.select(ok & dr.all(dr.isfinite(term)), term, 0.0)


# ------------------------------------------------------------------ the walks


def eval(mf, fresnel, wi, wo, max_bounces, key, mf_sample=None, direction_tangent=None):
    """One unbiased estimate of f(ω_i, ω_o)·cos θ_o, orders 1..max_bounces (Rust ``eval`` and
    ``Walk::from``). ``mf_sample``: the statistics directions are drawn from when they are not ``mf`` (the
    parameters detached; the estimate's derivative is then unbiased: docs/gradients.md). With it, ω_i and ω_o
    may carry a derivative (docs/gradients.md, "Directions through the walks"): every normal is drawn for the
    detached direction and the attached one reflects about it, weighed by the ratio of its density in the
    space of normals; on Beckmann nothing jumps where the directions move. On GGX the next events and the
    connection jump where a half vector turns horizontal: with ``direction_tangent`` = (s, t_i, t_o)
    (gradients.TangentCoordinates) the walk adds those edges' terms (``walk_from``)."""
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
    # Unrolled passes only where a derivative is propagated through the walk (``over_run``): a traced walk
    # with nothing differentiated — prb's primal passes — keeps the branches, the same bits.
    material = () if fresnel.mirror else (fresnel.eta, fresnel.k)
    unrolled = mf_sample is not None and walk.carries_gradients(mf, wi, wo, *material)
    dp0 = MonotoneExit.new(l0, slots, unrolled=unrolled)
    return walk_from(mf, fresnel, wo, lambda_o, light, CONNECT_MAX_ORDER, mi.Vector3f(wi), 0.25 / (wi[2] * l0),
                     mi.Spectrum(1.0), dp0, start, 0, last, key, rng0.counter, mf_sample=mf_sample,
                     attached_mis=direction_tangent is not None, direction_tangent=direction_tangent)


def walk_from(mf, fresnel, wo, lambda_o, light, connect_max, w, pdf_scale, thr, dp0, active, first_vertex, last,
              key, counter, label="msx_invariance_conductor_eval", mf_sample=None, attached_mis=False,
              direction_tangent=None):
    """The walk of ``eval`` from vertex ``first_vertex`` on (twin of ``Walk::from``), arriving there with
    w = −d_m, ``pdf_scale`` = 1/(4 A(w)), the throughput Π F · H_m and the exit table ``dp0`` of d_0..d_m,
    on the lanes ``active``; orders up to ``last``. ``light`` (a ``LightVertex`` with ``lambda_o`` set, or
    None) and ``connect_max``: the connection strategy for orders 2..connect_max (none with None and 0: the
    BDPT's tail). The lane's stream is (``key``, ``counter``). ``mf_sample``: as ``eval``'s. The call's
    values (α, η, k, Λ(ω_o), the light vertex's) travel in the loop's state whenever they carry derivatives
    (``walk.carries_gradients``): with ``mf_sample``, and without it when a caller differentiates the walk as
    written (the traced ``sample``'s weight).

    ``attached_mis`` (traced, while a direction is differentiated): the balance heuristic's weights of the
    next event and the connection keep their derivative. Detached weights are unbiased only where the two
    strategies' paths stay put as θ moves (the parameters: every direction is drawn detached); with ω_i or
    ω_o moving, the next event's intermediate direction moves with ω_i and the connection's with ω_o, and the
    weights' derivatives along those two flows do not cancel (measured: ∂/∂ω_i −0.210 against the central
    difference's −0.174 at order 2, docs/gradients.md). Attached, each strategy's term is the derivative of
    its own weighted integral, and the weights sum to 1 at every θ.

    ``direction_tangent`` (traced, on a distribution whose D does not vanish at horizontal normals): (s, t_i,
    t_o) of the one coordinate s of the directions differentiated; each vertex then adds the terms of the
    edges where its values jump (``nee_edge_term`` for the next vertex's next event, ``connect_edge_term`` for
    its connection), with the tangent of w carried in the state (t ↦ t − 2(t·m)m per reflection, from the
    tangent of ω_i) and their two numbers from a stream of their own (``EDGE_SALT``)."""
    connects = light is not None
    traced = mf_sample is not None
    # The connection serves orders 2..connect_max: the first connect_max − 1 vertices of a walk, while a packet
    # of lanes runs 5 of them on average on Fig. 9 (benches/README.md, "`invariance` on Fig. 9"). Its work, with
    # its own pass over the run, sits in a ``dr.if_stmt`` that the packets skip at the later vertices and where
    # no lane is active (``CONNECTION_BRANCH``); not where the run's passes are unrolled (a derivative is
    # propagated through the walk: drjit 1.5's forward mode cannot take a branch in a loop, ``over_run``).
    branchy = connects and not dp0.unrolled and CONNECTION_BRANCH
    edges = traced and direction_tangent is not None and mf.dist != BECKMANN
    edge_key = mix32(key ^ EDGE_SALT) if edges else None
    material = () if fresnel.mirror else (fresnel.eta, fresnel.k)
    piped_values = traced or walk.carries_gradients(mf, lambda_o, *material)

    def body(j, w, pdf_scale, pdf_walk, thr, result, active, counter, dp_state, piped):
        mf, fresnel, lambda_o, light, mf_s = outer_mf, outer_fresnel, outer_lambda_o, outer_light, outer_mf
        wo = outer_wo
        if piped_values:
            lv = LoopValues(outer_mf.dist, piped)
            mf, lambda_o, rest = lv.mf, lv.lambda_o, lv.rest
            mf_s = lv.mf_sample if traced else mf
            if connects:
                light = copy.copy(outer_light)
                light.l_y, light.pdf, light.phase, light.fresnel = rest[:4]
                light.lambda_o = lambda_o
                rest = rest[4:]
                if traced:  # the light vertex's direction and Jacobian (they move with ω_o)
                    light.y, light.jacobian = rest[:2]
                    rest = rest[2:]
            if not outer_fresnel.mirror:
                fresnel = ConductorFresnel(rest[0], rest[1])
                rest = rest[2:]
            if traced:  # ω_o, which may carry a derivative
                wo = rest[0]
            if edges:  # then the coordinate s and the tangents of w and of ω_o
                s_dir, tw, two = rest[1:4]
        rng = Stream(key, counter)
        dp = MonotoneExit.from_state(dp_state, dp0.unrolled)
        order = j + 1
        # NEE: D(h)/(4 A(w)) · F · p_exit(d_0..d_m, ω_o)/H_m, with the balance heuristic against the
        # connection for orders 2..connect_max.
        d_h, cos_wh = half_vector_d(mf, w, wo)
        value = d_h * pdf_scale
        if branchy:  # the connection's pass over the run only inside its branch, below
            col_o = dp.column(lambda_o)
        elif connects:
            col_o, via_up = dp.columns(lambda_o, light.l_y)
        else:
            col_o = dp.column(lambda_o)
        if connects:
            mis_w = (j > 0) & (order <= connect_max) & (value > 0.0)
            p_rev = d_h * (0.25 / (wo[2] * (1.0 + lambda_o)))
            balance = pdf_walk / (pdf_walk + p_rev)
            value = dr.select(mis_w, value * (dr.detach(balance) if traced and not attached_mis else balance), value)
        ok = (value > 0.0) & dr.isfinite(value)
        result = dr.select(active & ok, result + thr * fresnel.eval(cos_wh) * (value * col_o), result)
        active &= order < last
        # The connection for order + 1: d_{m+1} = y from the side of ω_o.
        if edges:
            u_nee_edge, u_conn_edge = Stream(edge_key, counter).next2()
            mf_e, wo_e, lo_e, w_e, scale_e = mf_s, dr.detach(wo), dr.detach(lambda_o), dr.detach(w), dr.detach(pdf_scale)
            fr_e = fresnel if fresnel.mirror else ConductorFresnel(dr.detach(fresnel.eta), dr.detach(fresnel.k))
        if connects:
            conn_on = active & (order < connect_max)

            def connection(result):
                via = dp.columns(lambda_o, light.l_y)[1] if branchy else via_up
                conn = light.connect(mf, fresnel, dp.has_up, w, pdf_scale, via, col_o, traced, attached_mis)
                return (dr.select(conn_on, result + thr * conn, result),)

            if branchy:
                result = dr.if_stmt(args=(result,), cond=conn_on, true_fn=connection, false_fn=lambda r: (r,),
                                    label="msx_invariance_connection")[0]
            else:
                result = connection(result)[0]
            if edges:
                edge = connect_edge_term(mf_e, fr_e, dp, dr.detach(col_o), w_e, tw, scale_e, wo_e, two, lo_e,
                                         u_conn_edge)
                result = dr.select(conn_on, result + (s_dir - dr.detach(s_dir)) * dr.detach(thr) * edge, result)
        # Russian roulette on Π F · H_m, after the vertex's estimates.
        u_rr, _ = rng.next2()
        thr, alive = walk.roulette_from(j >= walk.RR_START, thr, u_rr, RR_KEEP)
        active &= alive
        if edges:  # the next vertex's next event, of order + 1 (the balance weight where a connection serves it)
            mis_next = mi.Bool(connects) & (order + 1 <= connect_max)
            edge = nee_edge_term(mf_e, fr_e, dp, w_e, tw, scale_e, wo_e, two, lo_e, mis_next, u_nee_edge)
            result = dr.select(active, result + (s_dir - dr.detach(s_dir)) * dr.detach(thr) * edge, result)
        # The next direction.
        u1, u2 = rng.next2()
        # Traced, the normal is drawn for the detached w, and the attached w reflects about it.
        m, valid = mf_s.sample_visible(dr.detach(w) if traced else w, u1, u2)
        cos_wm = dot(w, m)
        active &= valid & (cos_wm > 0.0)
        d_next = reflect(w, m)
        up = d_next[2] > 0.0
        # Along the upward run z only grows: once an upward d.z ≥ ω_o.z no later vertex reaches ω_o.
        active &= ~(up & (d_next[2] >= wo[2]))
        thr = thr * fresnel.eval(cos_wm)
        if traced:
            # The step's density in the space of normals, ⟨w·m⟩·D(m)/A(w), over its detached value: D(m)/(4A(w))
            # over its detached value, times ⟨w·m⟩ over its detached value (1 with no derivative unless w moves).
            thr = thr * ((mf.d(m) * pdf_scale) / (mf_s.d(m) * dr.detach(pdf_scale)))
            thr = thr * dr.select(dr.detach(cos_wm) > 0.0, cos_wm / dr.detach(cos_wm), 0.0)
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
        if edges:  # the tangent of the next w = w − 2(w·m)m at the fixed normal
            tw = tw - 2.0 * dot(tw, m) * m
            piped = piped[:-3] + (s_dir, tw, two)
        pdf_scale = 0.25 / (dr.abs(d_next[2]) * l_next)
        return dict(j=j + 1, w=w, pdf_scale=pdf_scale, pdf_walk=pdf_walk, thr=thr, result=result, active=active,
                    counter=rng.counter, dp_state=dp.state(), piped=piped)

    outer_mf, outer_fresnel, outer_lambda_o, outer_light, outer_wo = mf, fresnel, lambda_o, light, wo
    width = dr.width(w)
    piped = ()
    if piped_values:
        piped += (mi.Float(mf.alpha_u), mi.Float(mf.alpha_v), mi.Float(lambda_o))
        if connects:
            piped += (mi.Float(light.l_y), mi.Float(light.pdf), mi.Float(light.phase), mi.Spectrum(light.fresnel))
            if traced:
                piped += (mi.Vector3f(light.y), mi.Float(light.jacobian))
        if not fresnel.mirror:
            piped += (mi.Spectrum(fresnel.eta), mi.Spectrum(fresnel.k))
        if traced:
            piped += (mi.Vector3f(wo),)
        if edges:
            s_dir, t_i, t_o = direction_tangent
            piped += (mi.Float(s_dir), mi.Vector3f(t_i), mi.Vector3f(t_o))
    state = dict(j=mi.UInt32(first_vertex), w=mi.Vector3f(w), pdf_scale=mi.Float(pdf_scale), pdf_walk=mi.Float(0.0),
                 thr=mi.Spectrum(thr), result=dr.zeros(mi.Spectrum, width), active=mi.Bool(active),
                 counter=mi.UInt32(counter), dp_state=dp0.state(), piped=piped)
    return walk.while_loop(state, body, label=label)["result"]

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
        # Differentiated (the sample weight's derivative), the run's passes are unrolled: drjit 1.5's forward
        # mode cannot take their branch inside the loop (``over_run``).
        material = () if surface.fresnel.mirror else (surface.fresnel.eta, surface.fresnel.k)
        dp = MonotoneExit.new(cam[0].l, run_slots(last),
                              unrolled=walk.carries_gradients(surface.mf, surface.lambda_o, *material))
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
    start = valid_direction(wi) & (max_bounces > 0)

    def vertex(w, weight, u, dp_state, rng, active):
        u_exit, u1, u2 = u
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
        pushed = dp.push_down(l_down, active & ~up)
        active &= (up & ~leaves) | pushed
        return d_next, weight, leaves & dr.all(dr.isfinite(d_next)), active, dp.state()

    dp0 = MonotoneExit.new(mf.abs_lambda(-wi), run_slots(max_bounces))
    return walk.sample_walk(wi, (sample1, u1, u2), start, dp0.state(), vertex, max_bounces, key, mi.Spectrum(1.0),
                            label="msx_invariance_conductor_sample")
