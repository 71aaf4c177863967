"""What the differentiated glass walks share (docs/gradients.md, "The IOR of the glass walks"): a vertex
that draws its normal in the space of normals with the parameters detached and computes the new direction
with them attached (``scatter_traced``), the tangent of a direction in the IOR at a fixed normal
(``eta_tangent_step``), the density of a vertex's new direction (``step_density``) and the next-event value
on its moving edge (``edge_vertex``). The position-free walks (``posfree_dielectric``), Heitz's walk
(``heitz``) and the invariance walk's first run (``invariance``) build their edge terms from these.

Frames as in posfree_dielectric.py: the walk's w points back along the ray, in the frame of the medium the
light travels in, η_f the relative IOR seen from there; a refraction switches the frame.
"""

import math

import drjit as dr
import mitsuba as mi

from .dielectric import transmit_half_vector
from .microfacet import BECKMANN, dot, reflect

# Share of the refraction probability kept when a differentiated walk draws its choice (below).
REFRACT_FLOOR = 0.5
# Share of the critical-cone density in a differentiated walk's draw of m, and its width in w·m (below).
CRITICAL_SHARE, CRITICAL_WIDTH = 0.2, 0.1
# Share and width (in w·m) of the density ∝ 1/√(w·m) at the edge of the visible normals in a differentiated
# walk's draw of m (below): the visible normals' density ∝ w·m vanishes there, and while w moves with η the
# ratio D_w(m)/p(m) of a density that vanishes as fast has the score (∂w·m)/(w·m), of infinite variance.
EDGE_SHARE, EDGE_WIDTH = 0.03, 0.1
# Least survival probability of a differentiated walk's roulette (docs/gradients.md): a survival ∝ the
# throughput divides a derivative by the throughput, and near total internal reflection the throughput is
# small where its derivative is not.
RR_TRACED_FLOOR = 0.25


def cone_density(x, width):
    """The density on the sphere of m = (c + x)·w + √(1 − (c + x)²)·(a direction ⟂ w) with x = width·u² and a
    uniform azimuth: ∝ 1/√x on 0 < x < width, 1/(4π√(width·x)) per steradian (0 elsewhere)."""
    return dr.select((x > 0.0) & (x < width), 1.0 / (4.0 * math.pi * dr.sqrt(width * x)), 0.0)


def scatter_traced(mfa, mfs, w, side, eta_a, u_choice, u1, u2, u_mix, times_area=False):
    """``scatter`` for a differentiated walk, in the space of microfacet normals, whose support does not move
    with the parameters (docs/gradients.md, "The IOR of the glass walks"): m is drawn with the detached
    parameters from a mixture of the visible normals of the detached w, a density ∝ 1/√(w·m) at their edge
    w·m → 0 (share EDGE_SHARE, within EDGE_WIDTH of it) and, where the light can be totally reflected
    (η_f < 1), a density ∝ 1/√(w·m − c_crit) near the critical cone w·m = c_crit = √(1 − η_f²) (share
    CRITICAL_SHARE, within CRITICAL_WIDTH of it); the choice is drawn with a detached probability q_t of
    refraction that keeps a floor (REFRACT_FLOOR) wherever refraction is possible; the new direction is
    computed from m with the attached w and η (a reparameterization). Returns (d in the new frame, refracted,
    side, valid, weight, m), the weight D_w(m)/p(m) × (1 − F)/q_t or F/(1 − q_t), p the mixture's detached
    density. Near the critical cone 1 − F ~ cos θ_t and its derivative in η ~ 1/cos θ_t: the floor and the
    mixture bound what the choice's and the normal's weights make of it; at the edge of the visible normals,
    w·m → 0, the edge's share makes D_w(m)/p(m) vanish as √(w·m), so its derivative stays bounded.

    ``times_area``: the weight times L_w = A(w)/|w_z| (the state's L of w), computed without it: D_w(m)·L_w =
    ⟨w·m⟩·D(m)/|w_z|. After a step going up near the normal L_w is tiny (< 10⁻¹⁵), and the derivative of a
    factor 1/L_w, −dL_w/L_w², overflows in float32; a walk that carries its throughput in logs
    (``posfree_dielectric.eval_pt`` while directions move) subtracts ln L_w instead."""
    ws, es = dr.detach(w), dr.detach(eta_a)
    c_crit = dr.safe_sqrt(1.0 - es * es)
    width = dr.minimum(CRITICAL_WIDTH, 1.0 - c_crit)
    share = dr.select((es < 1.0) & (width > 0.0), CRITICAL_SHARE, 0.0)
    m_v, valid_v = mfs.sample_visible(ws, u1, u2)
    e1, e2 = mi.coordinate_system(ws)
    phi = 2.0 * math.pi * u2
    # The cones about w: w·m − c = width·u1², c = c_crit (critical) or 0 (the visible normals' edge).
    critical = u_mix < share
    edge = ~critical & (u_mix < share + EDGE_SHARE)
    x_drawn = dr.select(critical, width, EDGE_WIDTH) * u1 * u1
    c_g = dr.select(critical, c_crit, 0.0) + x_drawn
    s_g = dr.safe_sqrt(1.0 - c_g * c_g)
    m_g = dr.normalize(c_g * ws + s_g * (dr.cos(phi) * e1 + dr.sin(phi) * e2))
    cone = critical | edge
    m = dr.select(cone, m_g, m_v)
    valid = dr.select(cone, m_g[2] > 0.0, valid_v)
    cos_s = dot(ws, m)
    valid &= cos_s > 0.0
    # w·m − c_crit, for a critical-cone draw as drawn: recomputed from m it cancels in float32 (to 0 within
    # ~1e-7 of the cone, where the density is largest).
    x = dr.select(critical, x_drawn, cos_s - c_crit)
    x_e = dr.select(edge, x_drawn, cos_s)
    p_m = ((1.0 - share - EDGE_SHARE) * mfs.d_visible(ws, m) + share * cone_density(x, width)
           + EDGE_SHARE * cone_density(x_e, EDGE_WIDTH))
    f_s = mi.fresnel(cos_s, es)[0]
    q_t = dr.select(f_s < 1.0, REFRACT_FLOOR + (1.0 - REFRACT_FLOOR) * (1.0 - f_s), 0.0)
    refracted = u_choice >= 1.0 - q_t
    cos_wm = dot(w, m)
    f, cos_t, _, eta_ti = mi.fresnel(cos_wm, eta_a)
    d = dr.select(refracted, mi.refract(w, m, cos_t, eta_ti), reflect(w, m))
    choice = dr.select(refracted, (1.0 - f) / dr.select(refracted, q_t, 1.0),
                       f / dr.select(refracted, 1.0, 1.0 - q_t))
    if times_area:
        cos_a = dot(w, m)
        visible = dr.select((cos_a > 0.0) & (w[2] != 0.0), cos_a * mfa.d(m) / dr.abs(w[2]), 0.0)
    else:
        visible = mfa.d_visible(w, m)
    weight = choice * visible / dr.select(p_m > 0.0, p_m, 1.0)
    weight = dr.select(valid & (p_m > 0.0) & dr.isfinite(weight), weight, 0.0)
    d = dr.select(refracted, -d, d)
    side = dr.select(refracted, -side, side)
    return d, refracted, side, valid, weight, m


def eta_tangent_step(w, tw, m, eta_f, teta_f, refracted):
    """The tangent of the next w (the state's −d in the new frame) at a fixed normal m, from the tangent tw
    of w and teta_f of η_f (derivatives in the IOR η): a reflection gives w' = w − 2(w·m)m, a refraction
    w' = refract(w, m, η_f) = m(c·s − T) − s·w with c = w·m, s = 1/η_f, T = √(1 − s²(1 − c²))."""
    c = dot(w, m)
    dc = dot(tw, m)
    s = 1.0 / eta_f
    ds = -s * s * teta_f
    t = dr.safe_sqrt(1.0 - s * s * (1.0 - c * c))
    dt = (s * s * c * dc - s * (1.0 - c * c) * ds) / dr.select(t > 0.0, t, 1.0)
    t_refract = m * (dc * s + c * ds - dt) - ds * w - s * tw
    t_reflect = tw - 2.0 * dc * m
    return dr.select(refracted, t_refract, t_reflect)


def d_horizontal(mf, m):
    """D at a horizontal normal m, the limit from above: GGX's α_u³α_v³/(π(m_x²α_v² + m_y²α_u²)²) (α²/π
    isotropic); Beckmann's is 0."""
    if mf.dist == BECKMANN:
        return mi.Float(0.0)
    ax, ay = mf.alpha_u, mf.alpha_v
    u = m[0] * m[0] * ay * ay + m[1] * m[1] * ax * ax
    a = ax * ay
    v = a * a * a / (math.pi * u * u)
    return dr.select(dr.isfinite(v), v, 0.0)


def edge_vertex(mf, eta_f, w, o, transmit):
    """The next-event vertex value at a w where its half-vector is horizontal (w_z = −o_z for a reflection
    towards o, −η_f·o_z for a transmission), as the limit from the side where it is not 0, and whether that
    side is above (w_z larger). Reflection: h = (w + o)/|w + o|, valid above. Transmission: h = ±(w + η_f o)
    horizontal, the sign that makes w·h > 0 > o·h; the code's h is −(w + η_f o) flipped upward, so that
    sign is the one seen from the side where −(w + η_f o)_z has it: below for h = −(w + η_f o), else above."""
    pre = dr.select(transmit, -(w + eta_f * o), w + o)
    h = mi.Vector3f(pre[0], pre[1], 0.0)
    length = dr.norm(h)
    h = h / dr.select(length > 0.0, length, 1.0)
    flip = transmit & (dot(w, h) < 0.0)
    h = dr.select(flip, -h, h)
    cw, co = dot(w, h), dot(o, h)
    f = mi.fresnel(cw, eta_f)[0]
    denom = cw + eta_f * co
    v_t = cw * (-co) * eta_f * eta_f * (1.0 - f) * d_horizontal(mf, h) / (dr.abs(w[2]) * denom * denom)
    v_r = f * d_horizontal(mf, h) / (4.0 * dr.abs(w[2]))
    ok = (length > 0.0) & (cw > 0.0) & dr.select(transmit, (co < 0.0) & (f < 1.0), co > 0.0)
    v = dr.select(transmit, v_t, v_r)
    return dr.select(ok & dr.isfinite(v), dr.maximum(v, 0.0), 0.0), ~transmit | flip


def step_density(mf, eta_f, w, d, refracted):
    """The phase function of a vertex — the density of its new direction d (in the current frame, before a
    refraction switches it) from w when m ~ D_w and the choice follows F: reflection F·D_w(h)/(4 w·h), h = m,
    or refraction (1 − F)·D_w(h)·η_f²|d·h|/(w·h + η_f d·h)² (Walter's Jacobian), with Mitsuba's Fresnel term.
    The walks' edge terms weigh the next direction on an edge by it (the model's F, not the draw's q_t)."""
    h_r = dr.normalize(w + d)
    h_t = dr.normalize(transmit_half_vector(w, d, eta_f))
    h = dr.select(refracted, h_t, h_r)
    cw, cd = dot(w, h), dot(d, h)
    f = mi.fresnel(cw, eta_f)[0]
    denom = cw + eta_f * cd
    p_t = (1.0 - f) * mf.d_visible(w, h) * eta_f * eta_f * dr.abs(cd) / (denom * denom)
    p_r = f * mf.d_visible(w, h) / (4.0 * cw)
    p = dr.select(refracted, p_t, p_r)
    # (d on the far side of h for a refraction, the near side for a reflection: a drawn step always is; an
    # arbitrary d, as an edge term asks about, need not be)
    ok = (cw > 0.0) & dr.select(refracted, cd < 0.0, cd > 0.0)
    return dr.select(ok & dr.isfinite(p), p, 0.0)


def edge_point(mf, w, tw, o, eta_f, teta_f, refracted, u, to=None):
    """One point of the circle where the next vertex's next-event value jumps (docs/gradients.md, "The IOR of
    the glass walks"), for the event ``refracted`` (a Python bool) of the vertex at w: in the space of normals
    that value towards ω_o (``o``, in the next vertex's frame) jumps to 0 where its half-vector turns
    horizontal, on the circle w'_z = z* (z* = −o_z for a reflection, −η_b·o_z for a transmission, η_b the
    next frame's relative IOR), which moves with η. At the azimuth 2πu: the next w' on the circle, whether
    ω_o is across from it, this event's phase function there (``step_density``: the density of w'), the
    position-free next-event value's limit on the side where it is not 0 (``edge_vertex``), and the relative
    speed ±(u_z − ∂z*/∂η) of the next direction across the circle, u_z the speed of w'_z at the fixed normal
    that maps w to w' (``eta_tangent_step``, from the tangent ``tw`` of w and ``teta_f`` of η_f). Returns
    (w', transmit, density, value, speed, ok); a walk's edge term is 2π × their product × its own next-vertex
    factors (one uniform azimuth estimates the integral over the circle, dz dφ being the solid angle).

    ``to``: the tangent of o itself (in the same frame), when the derivative is along moving directions
    (docs/gradients.md, "Directions through the walks"): the circle then moves with o_z too, and ``tw`` is the
    tangent of w in that coordinate (``teta_f`` 0)."""
    eta_b = 1.0 / eta_f if refracted else eta_f
    teta_b = -teta_f / (eta_f * eta_f) if refracted else teta_f
    transmit = o[2] < 0.0
    z_star = dr.select(transmit, -eta_b * o[2], -o[2])
    dz_star = dr.select(transmit, -o[2] * teta_b, 0.0)
    if to is not None:
        dz_star = dz_star - dr.select(transmit, eta_b, 1.0) * to[2]
    ok = dr.abs(z_star) < 1.0
    r = dr.safe_sqrt(1.0 - z_star * z_star)
    phi = 2.0 * math.pi * u
    w_next = mi.Vector3f(r * dr.cos(phi), r * dr.sin(phi), z_star)
    refr = mi.Bool(refracted)
    d = w_next if refracted else -w_next  # the event's direction in this vertex's frame
    density = step_density(mf, eta_f, w, d, refr)
    value, above = edge_vertex(mf, eta_b, w_next, o, transmit)
    if refracted:
        m = dr.normalize(transmit_half_vector(w, d, eta_f))
    else:
        m = dr.normalize(w + d)
    u_z = eta_tangent_step(w, tw, m, eta_f, teta_f, refr)[2]
    speed = dr.select(above, u_z - dz_star, dz_star - u_z)
    return w_next, transmit, density, value, speed, ok
