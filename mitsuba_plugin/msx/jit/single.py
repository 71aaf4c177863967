"""Single scattering, Walter et al. 2007, exactly as Mitsuba's built-in ``roughconductor`` computes it:
twin of ``src/models/single/conductor.rs``. Mitsuba's own ``mi.MicrofacetDistribution`` supplies D, the
separable G1·G1 (with Mitsuba's rational G1 for Beckmann) and its visible-normal sampler, as in the
core's ``microfacet/mitsuba.rs``."""

import drjit as dr
import mitsuba as mi

from .microfacet import BECKMANN, dot, reflect


def visible(mf):
    """Whether normals are drawn from the visible normals (the default) or from D·cos θ_m — the built-ins'
    ``sample_visible=false``, set on the call's microfacet statistics as ``sample_all_normals``)."""
    return not getattr(mf, "sample_all_normals", False)


def distribution(mf, scale=None):
    """Mitsuba's distribution for ``mf``; ``scale``: roughdielectric's widening of α for sampling all normals
    (Walter et al.'s 1.2 − 0.2·√|cos θ_i|)."""
    kind = mi.MicrofacetType.Beckmann if mf.dist == BECKMANN else mi.MicrofacetType.GGX
    au, av = (mf.alpha_u, mf.alpha_v) if scale is None else (mf.alpha_u * scale, mf.alpha_v * scale)
    return mi.MicrofacetDistribution(kind, au, av, visible(mf))


def _all_normals_weight(distr, wi, wo, m):
    """The sample weight's G term when normals are drawn from D·cos θ_m: G(ω_i, ω_o)·(ω_i·m)/(cos θ_i cos θ_m)."""
    return distr.G(wi, wo, m) * dr.dot(wi, m) / (wi[2] * m[2])


def eval_pdf(mf, fresnel, wi, wo):
    """(f·cos θ_o = F·D·G/(4 cos θ_i), the density of ``sample``): conductor.rs ``eval_pdf``."""
    distr = distribution(mf)
    h = dr.normalize(wi + wo)
    d = distr.eval(h)
    g1_i = distr.smith_g1(wi, h)
    ok = (wi[2] > 0.0) & (wo[2] > 0.0) & (d > 0.0)
    value = fresnel.eval(dot(wi, h)) * (d * g1_i * distr.smith_g1(wo, h) / (4.0 * wi[2]))
    pdf_ok = ok & (dot(wi, h) > 0.0) & (dot(wo, h) > 0.0)
    pdf = d * g1_i / (4.0 * wi[2]) if visible(mf) else distr.pdf(wi, h) / (4.0 * dot(wo, h))
    return dr.select(ok, value, 0.0), dr.select(pdf_ok, pdf, 0.0)


def sample(mf, fresnel, wi, u1, u2):
    """(ω_o, pdf, weight = f·cos θ_o/pdf, valid): conductor.rs ``sample``."""
    distr = distribution(mf)
    m, pdf_m = distr.sample(wi, mi.Point2f(u1, u2))
    wo = reflect(wi, m)
    if visible(mf):
        pdf = distr.eval(m) * distr.smith_g1(wi, m) * dr.abs(dot(wi, m)) / wi[2] / (4.0 * dot(wo, m))
        g = distr.smith_g1(wo, m)
    else:
        pdf, g = pdf_m / (4.0 * dot(wo, m)), _all_normals_weight(distr, wi, wo, m)
    valid = (wi[2] > 0.0) & (pdf > 0.0) & dr.isfinite(pdf) & (wo[2] > 0.0)
    weight = fresnel.eval(dot(wi, m)) * g
    return wo, pdf, weight, valid


# ------------------------------------------------------------------ dielectric (single/dielectric.rs)
# Dot products and the half vector in Mitsuba's arithmetic (dr.dot: a chain of FMAs; dr.normalize): the
# transmission Jacobian cancels near grazing, where a plain sum of products differs from roughdielectric by
# more than float32 rounding.


def _half_vector(eta, wi, wo):
    """(m flipped into the upper hemisphere, η_r, reflection?, valid) of a dielectric pair."""
    reflect_pair = wi[2] * wo[2] > 0.0
    eta_r = dr.select(wi[2] > 0.0, eta, 1.0 / eta)
    m = wi + wo * dr.select(reflect_pair, 1.0, eta_r)
    length = dr.norm(m)
    valid = (length > 0.0) & dr.isfinite(length)
    m = dr.normalize(m)
    return dr.mulsign(m, m[2]), eta_r, reflect_pair, valid


def dielectric_eval(mf, eta, wi, wo, radiance):
    """f(ω_i, ω_o)·|cos θ_o| of Mitsuba's roughdielectric (single/dielectric.rs ``eval``)."""
    distr = distribution(mf)
    m, eta_r, reflect_pair, valid = _half_vector(eta, wi, wo)
    d = distr.eval(m)
    wim, wom = dr.dot(wi, m), dr.dot(wo, m)
    f = mi.fresnel(wim, eta)[0]
    g = distr.smith_g1(wi, m) * distr.smith_g1(wo, m)
    scale = 1.0 / (eta_r * eta_r) if radiance else 1.0
    denom = wim + eta_r * wom
    value = dr.select(reflect_pair, f * d * g / (4.0 * dr.abs(wi[2])),
                      dr.abs(scale * (1.0 - f) * d * g * eta_r * eta_r * wim * wom / (wi[2] * denom * denom)))
    ok = valid & (wi[2] != 0.0) & dr.isfinite(value)
    return dr.select(ok, value, 0.0)


def dielectric_pdf(mf, eta, wi, wo):
    """Density of ``dielectric_sample`` (single/dielectric.rs ``pdf``)."""
    distr = distribution(mf)
    m, eta_r, reflect_pair, valid = _half_vector(eta, wi, wo)
    wim, wom = dr.dot(wi, m), dr.dot(wo, m)
    denom = wim + eta_r * wom
    dwh_dwo = dr.select(reflect_pair, 1.0 / (4.0 * wom), eta_r * eta_r * wom / (denom * denom))
    wi_up = dr.mulsign(wi, wi[2])
    if visible(mf):
        prob = distr.eval(m) * distr.smith_g1(wi_up, m) * dr.abs(dr.dot(wi_up, m)) / dr.abs(wi[2])
    else:
        prob = distribution(mf, 1.2 - 0.2 * dr.sqrt(dr.abs(wi[2]))).pdf(wi_up, m)
    f = mi.fresnel(wim, eta)[0]
    p = prob * dr.select(reflect_pair, f, 1.0 - f) * dr.abs(dwh_dwo)
    ok = valid & (wi[2] != 0.0) & (wim * wi[2] > 0.0) & (wom * wo[2] > 0.0) & dr.isfinite(p)
    return dr.select(ok, p, 0.0)


def dielectric_sample(mf, eta, wi, sample1, u1, u2, radiance):
    """Mitsuba's roughdielectric sampler (single/dielectric.rs ``sample``): (ω_o, pdf, weight, valid)."""
    distr = distribution(mf)
    cos_i = wi[2]
    wi_up = dr.mulsign(wi, cos_i)
    if visible(mf):
        m, _ = distr.sample(wi_up, mi.Point2f(u1, u2))
        pdf = distr.eval(m) * distr.smith_g1(wi_up, m) * dr.abs(dr.dot(wi_up, m)) / dr.abs(cos_i)
    else:
        widened = distribution(mf, 1.2 - 0.2 * dr.sqrt(dr.abs(cos_i)))
        m, pdf = widened.sample(wi_up, mi.Point2f(u1, u2))
    valid = (cos_i != 0.0) & dr.isfinite(cos_i) & (pdf != 0.0) & dr.isfinite(pdf)
    wim = dr.dot(wi, m)
    if not visible(mf):
        # A normal drawn from all normals may face away from ω_i: no lobe scatters there (dielectric.rs: no sample).
        valid &= wim * cos_i > 0.0
    f, cos_t, eta_it, eta_ti = mi.fresnel(wim, eta)
    selected_r = sample1 <= f
    # The lobe is chosen with probability F (detached, as roughdielectric does): its weight F/F is 1, and while
    # F carries a gradient (a moving ω_i or η) that weight keeps F's derivative, dF/F (or −dF/(1 − F)).
    pdf = pdf * dr.detach(dr.select(selected_r, f, 1.0 - f))
    lobe = mi.Float(1.0)
    if dr.grad_enabled(f):
        lobe = dr.select(selected_r, dr.replace_grad(mi.Float(1.0), f / dr.detach(f)),
                         dr.replace_grad(mi.Float(1.0), (1.0 - f) / (1.0 - dr.detach(f))))
    wo_r = reflect(wi, m)
    wo_t = mi.refract(wi, m, cos_t, eta_ti)
    wo = dr.select(selected_r, wo_r, wo_t)
    wom = dr.dot(wo, m)
    denom = wim + eta_it * wom
    dwh_dwo = dr.select(selected_r, 1.0 / (4.0 * wom), eta_it * eta_it * wom / (denom * denom))
    if visible(mf):
        g = distr.smith_g1(wo, m)
    else:
        # f·|cos θ_o|/pdf with m drawn from the widened D'·cos θ_m: roughdielectric's G term times D(m)/D'(m),
        # which roughdielectric 3.9.1 leaves out (its weights' mean is then off: docs/mitsuba.md).
        g = _all_normals_weight(distr, wi, wo, m) * distr.eval(m) / widened.eval(m)
    weight = lobe * dr.select(selected_r | (not radiance), 1.0, eta_ti * eta_ti) * g
    pdf = pdf * dr.abs(dwh_dwo)
    valid &= (pdf > 0.0) & dr.isfinite(pdf) & dr.isfinite(weight)
    return wo, pdf, weight, valid
