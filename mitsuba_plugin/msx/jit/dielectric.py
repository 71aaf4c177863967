"""The dielectric interface in the Dr.Jit engine: twin of ``src/microfacet/dielectric.rs``.

``eta`` = η_int/η_ext, the exterior above the macro surface (z > 0), as Mitsuba's ``roughdielectric``.
Fresnel and refraction come in the core's two arithmetic forms of the same formulas: Mitsuba's own
(``mi.fresnel``, ``mi.refract``; the core's ``fresnel::dielectric_full`` and ``refract``), which ``single``
must reproduce bit for bit and the position-free walks use (``reflect_or_refract``), and the unit-vector form
of the height-based walks of Heitz 2016 and Cui 2023 (``fresnel_dielectric``, ``refract_unit``,
``reflect_or_refract_unit``; the core's ``fresnel::dielectric``). They round differently, and a walk moved
from one to the other draws other paths where a rounding flips a decision (docs/testing.md, "Heavy-tailed
estimators and fixed seeds"), so each walk keeps its form.

Walter's generalized half vector of a refraction is ``transmit_half_vector``; the Jacobian
η²|ω_o·h|/(ω_i·h + η ω_o·h)² stays written out where it is used, in the product each caller rounds in.
"""

import drjit as dr
import mitsuba as mi

from .microfacet import reflect

# Mitsuba's IOR of BK7 glass (the default int_ior of roughdielectric).
BK7_IOR = 1.5046


def eta_seen(eta, outside):
    """Relative IOR η_t/η_i seen by light on one side (``outside`` a mask): η outside, 1/η inside."""
    return dr.select(outside, eta, 1.0 / eta)


def radiance_scale(eta, radiance, wi_outside, wo_outside):
    """Mitsuba's Radiance-mode factor of a result that crossed the interface: 1/η_r² from ω_i's side to
    ω_o's; 1 for a reflection or in Importance mode (``radiance`` a Python bool)."""
    if not radiance:
        return mi.Float(1.0)
    e = eta_seen(eta, wi_outside)
    return dr.select(wi_outside != wo_outside, 1.0 / (e * e), 1.0)


def transmit_half_vector(w, o, eta_rel):
    """Walter's generalized half vector of a refraction from w (pointing away from the surface, on the near
    side) to o (on the far side), relative IOR ``eta_rel`` = η_far/η_near: −(w + η o), oriented upward,
    unnormalised."""
    h = -(w + eta_rel * o)
    return dr.select(h[2] < 0.0, -h, h)


def reflect_or_refract(w, m, cos_wm, eta_rel, u):
    """Light from ``w`` (w·m = ``cos_wm`` > 0) at the facet m, relative IOR ``eta_rel``: reflected when
    u < F, refracted otherwise. Returns (direction, refracted, F)."""
    f, cos_t, _, eta_ti = mi.fresnel(cos_wm, eta_rel)
    refracted = u >= f
    o = dr.select(refracted, mi.refract(w, m, cos_t, eta_ti), reflect(w, m))
    return o, refracted, f


# ------------------------------------------------------------------ the unit-vector form (height walks)


def fresnel_dielectric(cos_i, eta):
    """Unpolarised dielectric reflectance at |cos θ_i| = ``cos_i`` with relative IOR ``eta`` = η_t/η_i,
    1 under total internal reflection (the unit-vector form ``fresnel::dielectric``)."""
    ci = dr.minimum(dr.abs(cos_i), 1.0)
    s2t = (1.0 - ci * ci) / (eta * eta)
    ct = dr.sqrt(dr.maximum(1.0 - s2t, 0.0))
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return dr.select(s2t >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


def refract_unit(w, m, cos_i, eta):
    """Refraction of ``w`` (w·m = ``cos_i`` > 0) through the facet m, relative IOR ``eta``: (the unit
    direction on the far side in the same frame, valid); invalid under total internal reflection (Rust
    ``refract_unit``)."""
    sin2_t = dr.maximum(1.0 - cos_i * cos_i, 0.0) / (eta * eta)
    cos_t = dr.sqrt(dr.maximum(1.0 - sin2_t, 0.0))
    o = m * (cos_i / eta - cos_t) - w / eta
    length = dr.norm(o)
    valid = (sin2_t < 1.0) & (length > 0.0) & dr.isfinite(length)
    return o / length, valid


def reflect_or_refract_unit(w, m, cos_wm, eta, u):
    """Light from ``w`` (w·m = ``cos_wm`` > 0) at the facet m in the unit-vector form: refracted when
    u ≥ F and refraction is possible, reflected otherwise (also under total internal reflection). Returns (the
    refracted direction, the reflected direction, refracted), both in the current frame."""
    f = fresnel_dielectric(cos_wm, eta)
    o, ok_t = refract_unit(w, m, cos_wm, eta)
    return o, dr.normalize(reflect(w, m)), (u >= f) & ok_t


def scatter_unit(wi, m, cos_wm, eta, u):
    """``reflect_or_refract_unit`` as a height walk continues (Rust ``scatter`` of a dielectric): a refracted
    ray is returned in the new side's frame (the point reflection), where it travels upward. Returns
    (direction, crossed)."""
    o, r, crossed = reflect_or_refract_unit(wi, m, cos_wm, eta, u)
    return dr.select(crossed, -o, r), crossed
