"""The analytic conductor models of the Dr.Jit engine: twin of ``src/models/analytic/`` (``fastmsx.rs``:
Rosales 2023's second-bounce lobe; ``compensated.rs``: Turquin 2019 albedo scaling with the Kulla-Conty
Fresnel term). Both sample with ``single``'s sampler and report its density."""

import math

import drjit as dr
import mitsuba as mi

from . import single, tables
from .microfacet import dot
from .model import ConductorAnalytic, DielectricAnalytic

# ------------------------------------------------------------------ Fast-MSX (fastmsx.rs)


def fastmsx_eval_second(mf, fresnel, wi, wo):
    """The second-bounce term f_SI·cos θ_o alone (Rosales 2023, Alg. 1, eqs. 16–20)."""
    v, l = wi, wo
    h = dr.normalize(v + l)
    c = dr.normalize(h + mi.Vector3f(0.0, 0.0, 1.0))
    cos_cv = dr.clip(dot(c, v), -1.0, 1.0)
    theta_vc = dr.safe_acos(cos_cv)
    theta_m = (math.pi - dr.safe_acos(dr.clip(dot(v, l), -1.0, 1.0))) * 0.25
    denom = dr.sin(theta_vc + theta_m)
    op = dr.select(denom > 0.0, dr.sin(theta_vc - theta_m) / denom, 0.0)
    g_i = dr.clip(1.0 - dr.maximum(op, 0.0), 0.0, 1.0)
    a2 = mf.alpha_u * mf.alpha_v
    t = dr.square(dr.cos(theta_m)) * (a2 - 1.0) + 1.0
    d_i = a2 / (math.pi * t * t)
    f = fresnel.eval(dot(v, h))
    value = d_i * g_i / (2.0 * cos_cv) * wo[2]
    ok = (wi[2] > 0.0) & (wo[2] > 0.0) & (cos_cv > 0.0) & dr.isfinite(value)
    return dr.select(ok, f * f * value, 0.0)


def fastmsx_eval_pdf(mf, fresnel, wi, wo):
    value, pdf = single.eval_pdf(mf, fresnel, wi, wo)
    return value + fastmsx_eval_second(mf, fresnel, wi, wo), pdf


def fastmsx_sample(mf, fresnel, wi, u1, u2):
    wo, pdf, weight, valid = single.sample(mf, fresnel, wi, u1, u2)
    return wo, pdf, weight + fastmsx_eval_second(mf, fresnel, wi, wo) / pdf, valid


# ------------------------------------------------------------------ compensation (compensated.rs)

# 16-point Gauss-Legendre on [−1, 1] (the positive half of its nodes and their weights).
_GL_X = (0.0950125098376374, 0.2816035507792589, 0.4580167776572274, 0.6178762444026438,
         0.7554044083550030, 0.8656312023878318, 0.9445750230732326, 0.9894009349916499)
_GL_W = (0.1894506104550685, 0.1826034150449236, 0.1691565193950025, 0.1495959888165767,
         0.1246289712555339, 0.0951585116824928, 0.0622535239386479, 0.0271524594117541)


def fresnel_average(fresnel):
    """F_avg = 2∫F(μ)μ dμ per channel (16-point Gauss-Legendre in μ): 16 Fresnel evaluations, so a constant
    material's is computed once by the BSDF (``ConductorFresnel.average``)."""
    if fresnel.mirror:
        return mi.Spectrum(1.0)
    if fresnel.average is not None:
        return fresnel.average
    avg = 0.0
    for s in (-1.0, 1.0):
        for x, w in zip(_GL_X, _GL_W):
            mu = 0.5 * (1.0 + s * x)
            avg = avg + fresnel.eval(mi.Float(mu)) * (w * mu)
    return avg


def compensated_scale(mf, fresnel, wi):
    """Per-channel scale of ``single`` for incidence ω_i: 1 + (F_ms/F_avg)(1 − E)/E."""
    from .._native import lib

    alpha = dr.sqrt(mf.alpha_u * mf.alpha_v)
    e = tables.get(lib.MSX_TABLE_ALBEDO_SINGLE, mf.dist).at(alpha, wi[2])
    e_avg = tables.get(lib.MSX_TABLE_ALBEDO_AVG, mf.dist).at(alpha)
    fa = fresnel_average(fresnel)
    ratio = (1.0 - e) / e
    f_ms = fa * fa * e_avg / (1.0 - fa * (1.0 - e_avg))
    s = 1.0 + dr.select(fa > 0.0, f_ms / fa * ratio, 0.0)
    return dr.select(dr.isfinite(s), s, 1.0)


def compensated_eval_pdf(mf, fresnel, wi, wo):
    value, pdf = single.eval_pdf(mf, fresnel, wi, wo)
    return value * compensated_scale(mf, fresnel, wi), pdf


def compensated_sample(mf, fresnel, wi, u1, u2):
    wo, pdf, weight, valid = single.sample(mf, fresnel, wi, u1, u2)
    return wo, pdf, weight * compensated_scale(mf, fresnel, wi), valid


# The analytic conductor models, by model name (jit/bsdf.py collects them).
CONDUCTOR_ANALYTIC = {
    "single": ConductorAnalytic(single.eval_pdf, single.sample),
    "fastmsx": ConductorAnalytic(fastmsx_eval_pdf, fastmsx_sample),
    "compensated": ConductorAnalytic(compensated_eval_pdf, compensated_sample),
}


# ------------------------------------------------------------------ compensated dielectric (compensated_dielectric.rs)

# Lower clamp of the tabulated albedo (src/models/analytic/dielectric_albedo.rs, E_MIN).
E_MIN = 1e-3


def compensated_dielectric_scale(mf, eta, wi):
    """1/E(μ_i, α, η_r) of ``single`` on the dielectric (Importance mode), η_r = η outside, 1/η inside."""
    from .._native import lib

    alpha = dr.sqrt(mf.alpha_u * mf.alpha_v)
    mu = dr.minimum(dr.abs(wi[2]), 1.0)
    outside = wi[2] > 0.0
    # η_r = η outside, 1/η inside; η_r ≥ 1 reads the entering table at η_r, η_r < 1 the leaving one at
    # 1/η_r. Both read n = max(η, 1/η).
    n = dr.select(eta >= 1.0, eta, 1.0 / eta)
    enter = tables.get(lib.MSX_TABLE_DIELECTRIC_ENTER, mf.dist).at(alpha, n, mu)
    leave = tables.get(lib.MSX_TABLE_DIELECTRIC_LEAVE, mf.dist).at(alpha, n, mu)
    eta_r_at_least_one = outside == (eta >= 1.0)
    e = dr.select(eta_r_at_least_one, enter, leave)
    s = 1.0 / dr.clip(e, E_MIN, 1.0)
    ok = (wi[2] != 0.0) & dr.isfinite(wi[2]) & dr.isfinite(s)
    return dr.select(ok, s, 1.0)


def compensated_dielectric_eval(mf, eta, radiance, wi, wo):
    v = single.dielectric_eval(mf, eta, wi, wo, radiance)
    return dr.select(v > 0.0, v * compensated_dielectric_scale(mf, eta, wi), 0.0)


def compensated_dielectric_sample(mf, eta, radiance, wi, sample1, u1, u2):
    wo, pdf, weight, valid = single.dielectric_sample(mf, eta, wi, sample1, u1, u2, radiance)
    return wo, pdf, weight * compensated_dielectric_scale(mf, eta, wi), valid


def _single_dielectric_eval(mf, eta, radiance, wi, wo):
    return single.dielectric_eval(mf, eta, wi, wo, radiance)


def _single_dielectric_sample(mf, eta, radiance, wi, sample1, u1, u2):
    return single.dielectric_sample(mf, eta, wi, sample1, u1, u2, radiance)


# The analytic dielectric models, by model name (jit/bsdf.py collects them).
DIELECTRIC_ANALYTIC = {
    "single": DielectricAnalytic(_single_dielectric_eval, single.dielectric_pdf, _single_dielectric_sample),
    "compensated": DielectricAnalytic(compensated_dielectric_eval, single.dielectric_pdf,
                                      compensated_dielectric_sample),
}
