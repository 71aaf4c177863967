"""Single scattering, Walter et al. 2007, exactly as Mitsuba's built-in ``roughconductor`` computes it:
twin of ``src/models/single/conductor.rs``. Mitsuba's own ``mi.MicrofacetDistribution`` supplies D, the
separable G1·G1 (with Mitsuba's rational G1 for Beckmann) and its visible-normal sampler, as in the
core's ``microfacet/mitsuba.rs``."""

import drjit as dr
import mitsuba as mi

from .microfacet import BECKMANN, dot, reflect


def distribution(mf):
    kind = mi.MicrofacetType.Beckmann if mf.dist == BECKMANN else mi.MicrofacetType.GGX
    return mi.MicrofacetDistribution(kind, mf.alpha_u, mf.alpha_v, True)


def eval_pdf(mf, fresnel, wi, wo):
    """(f·cos θ_o = F·D·G/(4 cos θ_i), the density of ``sample``): conductor.rs ``eval_pdf``."""
    distr = distribution(mf)
    h = dr.normalize(wi + wo)
    d = distr.eval(h)
    g1_i = distr.smith_g1(wi, h)
    ok = (wi[2] > 0.0) & (wo[2] > 0.0) & (d > 0.0)
    value = fresnel.eval(dot(wi, h)) * (d * g1_i * distr.smith_g1(wo, h) / (4.0 * wi[2]))
    pdf_ok = ok & (dot(wi, h) > 0.0) & (dot(wo, h) > 0.0)
    pdf = d * g1_i / (4.0 * wi[2])
    return dr.select(ok, value, 0.0), dr.select(pdf_ok, pdf, 0.0)


def sample(mf, fresnel, wi, u1, u2):
    """(ω_o, pdf, weight = f·cos θ_o/pdf, valid): conductor.rs ``sample``."""
    distr = distribution(mf)
    m, _ = distr.sample(wi, mi.Point2f(u1, u2))
    wo = reflect(wi, m)
    pdf = distr.eval(m) * distr.smith_g1(wi, m) * dr.abs(dot(wi, m)) / wi[2] / (4.0 * dot(wo, m))
    valid = (wi[2] > 0.0) & (pdf > 0.0) & dr.isfinite(pdf) & (wo[2] > 0.0)
    weight = fresnel.eval(dot(wi, m)) * distr.smith_g1(wo, m)
    return wo, pdf, weight, valid
