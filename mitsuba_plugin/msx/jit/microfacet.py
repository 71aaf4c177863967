"""Microfacet primitives of the Dr.Jit engine: twin of ``src/microfacet/mod.rs`` (with ``ggx.rs`` and
``fresnel.rs``; Beckmann's Λ and visible normals are in ``beckmann.py``).

The same functions under the same names, on arrays of lanes in float32. Conventions
(docs/conventions.md): local frame, z = macro normal; Λ(−ω) = −1 − Λ(ω) on the whole sphere, so Λ ≥ 0
upward and Λ ≤ −1 downward; ``abs_lambda`` gives |Λ| without cancellation.
"""

import math

import drjit as dr
import mitsuba as mi

GGX = "ggx"
BECKMANN = "beckmann"

# The roughness range of the core (src/microfacet/mod.rs: ALPHA_MIN, ALPHA_MAX).
ALPHA_MIN = 1e-4
ALPHA_MAX = 1e4

INV_PI = 1.0 / math.pi


def clamp_alpha(a):
    """Roughness clamped into [ALPHA_MIN, ALPHA_MAX]; NaN becomes ALPHA_MIN (as ``Microfacet::new``)."""
    a = mi.Float(a)
    return dr.select(dr.isnan(a), ALPHA_MIN, dr.clip(a, ALPHA_MIN, ALPHA_MAX))


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def reflect(w, m):
    """Mirror reflection of ω about m (both pointing away from the surface)."""
    return 2.0 * dot(w, m) * m - w


def normalized(v):
    """(v/|v|, |v|): the division the walks' half vectors are rounded with (``dr.normalize`` multiplies by a
    reciprocal square root, other bits)."""
    length = dr.norm(v)
    return v / length, length


def half_vector(w, o):
    """The half vector of a reflection from w to o and |w + o| (``normalized``); Walter's half vector of a
    refraction is ``dielectric.transmit_half_vector``."""
    return normalized(w + o)


def ggx_lambda_up(alpha_tan2):
    """GGX Λ for an upward direction with (α tan θ)² = ``alpha_tan2``, without cancellation (ggx.rs)."""
    v = alpha_tan2 / (2.0 * (1.0 + dr.sqrt(1.0 + alpha_tan2)))
    return dr.select(dr.isinf(alpha_tan2), dr.inf, v)


def ggx_sample_visible_std(w, u1, u2):
    """Visible normal (unnormalised) for the stretched unit direction ``w`` on the whole sphere by the
    spherical-cap method (ggx.rs): (m, valid)."""
    phi = 2.0 * math.pi * u1
    z = (1.0 - u2) * (1.0 + w[2]) - w[2]
    sin_theta = dr.sqrt(dr.maximum(1.0 - z * z, 0.0))
    s, c = dr.sincos(phi)
    h = mi.Vector3f(sin_theta * c, sin_theta * s, z) + w
    return h, h[2] > 0.0


class Microfacet:
    """An anisotropic microfacet distribution (α_u along x, α_v along y) of one call per lane."""

    def __init__(self, dist, alpha_u, alpha_v):
        if dist not in (GGX, BECKMANN):
            raise ValueError("unknown distribution %r" % dist)
        self.dist = dist
        self.alpha_u = clamp_alpha(alpha_u)
        self.alpha_v = clamp_alpha(alpha_v)

    def alpha_tan2(self, w):
        """(α tan θ)² of a direction: the only quantity Λ depends on."""
        xy = dr.square(self.alpha_u * w[0]) + dr.square(self.alpha_v * w[1])
        return dr.select(xy == 0.0, 0.0, xy / dr.square(w[2]))

    def lambda_up(self, alpha_tan2):
        if self.dist == GGX:
            return ggx_lambda_up(alpha_tan2)
        from . import beckmann

        return beckmann.lambda_up(alpha_tan2)

    def lambda_(self, w):
        """Full-sphere Smith Λ(ω); +∞ for horizontal directions."""
        lam = self.lambda_up(self.alpha_tan2(w))
        return dr.select(w[2] >= 0.0, lam, -1.0 - lam)

    def abs_lambda(self, w):
        """|Λ(ω)| without cancellation: Λ upward, 1 + Λ(−ω) downward."""
        lam = self.lambda_up(self.alpha_tan2(w))
        return dr.select(w[2] >= 0.0, lam, 1.0 + lam)

    def g1_dist(self, w):
        """Distant masking |1/(1 + Λ(ω))| (exceeds 1 downward; never clamped)."""
        lam = self.lambda_up(self.alpha_tan2(w))
        return dr.select(w[2] >= 0.0, 1.0 / (1.0 + lam), 1.0 / lam)

    def projected_area(self, w, lam_up=None):
        """A(ω) = cos θ (1 + Λ(ω)), stable on the whole sphere. ``lam_up``: ``lambda_up(alpha_tan2(±ω))`` when
        the caller has it (of −ω: (α tan θ)² is even in ω, so the same value and bits)."""
        lam = self.lambda_up(self.alpha_tan2(w)) if lam_up is None else lam_up
        return dr.select(w[2] >= 0.0, w[2] * (1.0 + lam), -w[2] * lam)

    def d(self, m):
        """Normal distribution D(m), zero in the lower hemisphere and where it is not finite."""
        ax, ay = self.alpha_u, self.alpha_v
        z2 = dr.square(m[2])
        if self.dist == BECKMANN:
            sx, sy = m[0] / ax, m[1] / ay
            v = dr.exp(-(sx * sx + sy * sy) / z2) / (math.pi * ax * ay * z2 * z2)
        else:
            ax2, ay2 = ax * ax, ay * ay
            u = m[0] * m[0] * ay2 + m[1] * m[1] * ax2 + z2 * ax2 * ay2
            a = ax * ay
            v = a * a * a / (math.pi * u * u)
        return dr.select((m[2] > 0.0) & dr.isfinite(v), v, 0.0)

    def d_horizon(self, m):
        """The limit of D at a horizontal normal m (m_z → 0⁺): GGX's (α_u α_v)³/(π (m_x² α_v² + m_y² α_u²)²),
        α²/π when isotropic; Beckmann's is 0."""
        if self.dist == BECKMANN:
            return dr.zeros(mi.Float, dr.width(m))
        ax, ay = self.alpha_u, self.alpha_v
        u = m[0] * m[0] * ay * ay + m[1] * m[1] * ax * ax
        a = ax * ay
        v = a * a * a / (math.pi * u * u)
        return dr.select(dr.isfinite(v), v, 0.0)

    def d_visible(self, w, m, lam_up=None):
        """D_ω(m) = ⟨ω, m⟩ D(m) / A(ω) (``lam_up``: as ``projected_area``'s)."""
        cos = dot(w, m)
        area = self.projected_area(w, lam_up)
        ok = (cos > 0.0) & (area > 0.0) & dr.isfinite(area)
        return dr.select(ok, cos * self.d(m) / area, 0.0)

    def reflect_pdf(self, w, wo):
        """Density of reflecting ω into ``wo`` with m ~ D_ω: D_ω(h) / (4 ω·h)."""
        h, length = half_vector(w, wo)
        c = dot(w, h)
        ok = (length > 0.0) & (c > 0.0)
        return dr.select(ok, self.d_visible(w, h) / (4.0 * c), 0.0)

    def sample_visible(self, w, u1, u2):
        """A visible normal m ~ D_ω for ω on the whole sphere: (m, valid)."""
        ax, ay = self.alpha_u, self.alpha_v
        ws = mi.Vector3f(ax * w[0], ay * w[1], w[2])
        length = dr.norm(ws)
        ok = (length > 0.0) & dr.isfinite(length)
        ws = ws / length
        if self.dist == GGX:
            m, valid = ggx_sample_visible_std(ws, u1, u2)
        else:
            from . import beckmann

            m, valid = beckmann.sample_visible_std(ws, u1, u2)
        m = mi.Vector3f(ax * m[0], ay * m[1], m[2])
        length = dr.norm(m)
        valid = valid & ok & (length > 0.0) & dr.isfinite(length) & (m[2] > 0.0)
        return m / length, valid


# ------------------------------------------------------------------ Fresnel (fresnel.rs)


def fresnel_conductor(cos_i, eta, k):
    """Unpolarised conductor reflectance per channel at incidence cosine ``cos_i`` (> 0), the closed form
    of fresnel.rs (one division); ``eta``, ``k``: mi.Spectrum (or mi.Float)."""
    c2 = dr.minimum(cos_i * cos_i, 1.0)
    s2 = 1.0 - c2
    t = eta * eta - k * k - s2
    a2b2 = dr.sqrt(dr.maximum(t * t + 4.0 * eta * eta * k * k, 0.0))
    a = dr.sqrt(dr.maximum(0.5 * (a2b2 + t), 0.0))
    t1 = a2b2 + c2
    t2 = 2.0 * cos_i * a
    t3 = a2b2 * c2 + s2 * s2
    t4 = t2 * s2
    f = (t1 - t2) * t3 / ((t1 + t2) * (t3 + t4))
    # type(f)(…): in spectral variants a select on the mask of a mi.Spectrum returns drjit's plain Array4f, which
    # a walk's loop state (a mi.Spectrum) refuses; the cast keeps the spectrum's type (no arithmetic).
    return type(f)(dr.select(dr.isfinite(f), dr.clip(f, 0.0, 1.0), 1.0))


class ConductorFresnel:
    """Per-channel conductor Fresnel term; the perfect mirror (η = 0, k = 1, Mitsuba's
    ``material="none"``) is F = 1 without arithmetic (decided at construction: a constant material).
    ``average``: the hemispherical average F_avg when the caller computed it once (a constant material),
    else None (``analytic.fresnel_average`` then computes it per lane)."""

    def __init__(self, eta, k, mirror=False, average=None):
        self.eta, self.k, self.mirror, self.average = eta, k, mirror, average

    def eval(self, cos_i):
        if self.mirror:
            return mi.Spectrum(1.0)
        return fresnel_conductor(cos_i, self.eta, self.k)


def max_channel(s):
    """The largest channel of a spectrum (or the value of a Float)."""
    if dr.depth_v(s) <= 1 or dr.size_v(s) == 1:
        return s[0] if dr.depth_v(s) > 1 else s
    m = s[0]
    for c in range(1, dr.size_v(s)):
        m = dr.maximum(m, s[c])
    return m
