"""The dielectric interface in the Dr.Jit engine: twin of ``src/microfacet/dielectric.rs``.

``eta`` = η_int/η_ext, the exterior above the macro surface (z > 0), as Mitsuba's ``roughdielectric``.
Fresnel and refraction in Mitsuba's own arithmetic (``mi.fresnel``, ``mi.refract``), which the core's
``fresnel::dielectric_full`` and ``refract`` reproduce.
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


def reflect_or_refract(w, m, cos_wm, eta_rel, u):
    """Light from ``w`` (w·m = ``cos_wm`` > 0) at the facet m, relative IOR ``eta_rel``: reflected when
    u < F, refracted otherwise. Returns (direction, refracted, F)."""
    f, cos_t, _, eta_ti = mi.fresnel(cos_wm, eta_rel)
    refracted = u >= f
    o = dr.select(refracted, mi.refract(w, m, cos_t, eta_ti), reflect(w, m))
    return o, refracted, f
