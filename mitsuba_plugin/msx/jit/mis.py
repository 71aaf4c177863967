"""Densities the random walks report for multiple importance sampling: twin of ``src/models/mis.rs``.

The walks have no closed-form sampling density; ``pdf`` and ``sample`` report the same proposal density,
close to the walk's, so MIS stays unbiased (docs/conventions.md).
"""

import drjit as dr

from . import tables
from .microfacet import INV_PI

SEPARABLE = "separable"  # order 1 leaves with G1(ω_o) (uncorrelated)
HEIGHT_CORRELATED = "height_correlated"  # leaves with L_0/(L_0 + Λ_o) (correlated, heitz, invariance)


def _e1_table(exit, dist):
    from .._native import lib

    kind = lib.MSX_TABLE_E1_UNCORRELATED if exit == SEPARABLE else lib.MSX_TABLE_E1_CORRELATED
    return tables.get(kind, dist)


def conductor_walk_pdf(exit, mf, wi, wo):
    """The exact density of leaving after one bounce plus a cosine lobe carrying the rest of the mass,
    1 − E_1(ω_i) from the core's order-1 albedo table, floored at 1e-3."""
    lambda_o = mf.lambda_(wo)
    e1 = _e1_table(exit, mf.dist).at(dr.sqrt(mf.alpha_u * mf.alpha_v), wi[2])
    if exit == SEPARABLE:
        p_exit = 1.0 / (1.0 + lambda_o)
    else:
        l0 = 1.0 + mf.lambda_(wi)
        p_exit = l0 / (l0 + lambda_o)
    return mf.reflect_pdf(wi, wo) * p_exit + dr.maximum(1.0 - e1, 1e-3) * wo[2] * INV_PI


CUI_ALBEDO_MAX = 0.975  # largest single-scattering albedo Cui's density maps a roughness to


def cui_pdf(mf, wi, wo, printed=False):
    """Cui et al. 2023's density (``cui_pdf`` in ``src/models/mis.rs``, docs/paper-notes.md): the
    visible-normal reflection density D(h) G1(ω_i)/(4 μ_i) plus (ϖ/4π)(H(μ_i) H(μ_o) − 1)/(μ_i + μ_o) with
    ϖ = min((α_u + α_v)/2, 0.975). ``printed=False``: the classic H = (1 + 2μ)/(1 + 2sμ), s = √(1 − ϖ), with
    H − 1 = 2μ(1 − s)/(1 + 2sμ) and 1 − s = ϖ/(1 + s), so the term is a sum of positive parts; ``True``: the
    H printed in the authors' code, (1 + 2μ)/(3 + sμ) < 1, floored at the 1e-3 cosine lobe."""
    mu_i, mu_o = wi[2], wo[2]
    albedo = dr.minimum(0.5 * (mf.alpha_u + mf.alpha_v), CUI_ALBEDO_MAX)
    s = dr.sqrt(1.0 - albedo)
    p1 = mf.reflect_pdf(wi, wo)
    scale = albedo * (0.25 * INV_PI)
    if not printed:
        one_minus_s = albedo / (1.0 + s)
        a = 2.0 * mu_i * one_minus_s / (1.0 + 2.0 * s * mu_i)
        b = 2.0 * mu_o * one_minus_s / (1.0 + 2.0 * s * mu_o)
        return p1 + scale * (a * b + a + b) / (mu_i + mu_o)
    h_i = (1.0 + 2.0 * mu_i) / (3.0 + s * mu_i)
    h_o = (1.0 + 2.0 * mu_o) / (3.0 + s * mu_o)
    return dr.maximum(p1 + scale * (h_i * h_o - 1.0) / (mu_i + mu_o), 1e-3 * mu_o * INV_PI)


SINGLE_COSINE, CUI, CUI_TYPO = "single_cosine", "cui", "cui_typo"  # the values of ``mis_density``


def conductor_pdf(exit, below, mf, wi, wo, density=SINGLE_COSINE):
    """``walk_pdf`` of a conductor: 0 for ω_o below; ω_i below the surface (normal mapping) gets a cosine
    lobe when the walk starts there (``below``, the position-free walks), else 0. ``density``: the
    ``mis_density`` parameter (``conductor_walk_pdf`` or ``cui_pdf``)."""
    if density == SINGLE_COSINE:
        pdf = conductor_walk_pdf(exit, mf, wi, wo)
    else:
        pdf = cui_pdf(mf, wi, wo, printed=density == CUI_TYPO)
    if below:
        pdf = dr.select(wi[2] < 0.0, wo[2] * INV_PI, pdf)
    else:
        pdf = dr.select(wi[2] < 0.0, 0.0, pdf)
    return dr.select((wo[2] <= 0.0) | (wi[2] == 0.0), 0.0, pdf)


def diffuse_fraction(mf):
    """Weight of the cosine lobe in the dielectric walks' density: min(α/(α + 2), 0.75), α = √(α_u α_v)."""
    a = dr.sqrt(mf.alpha_u * mf.alpha_v)
    return dr.minimum(a / (a + 2.0), 0.75)


def dielectric_pdf(mf, eta, wi, wo):
    """``walk_pdf`` of a dielectric: the single-scattering density mixed with a cosine lobe on both sides."""
    from .single import dielectric_pdf as single_pdf

    k = diffuse_fraction(mf)
    return (1.0 - k) * single_pdf(mf, eta, wi, wo) + k * dr.abs(wo[2]) * (0.5 * INV_PI)


def diffuse_pdf(wi, wo):
    """``walk_pdf`` of the diffuse microsurface: a cosine lobe."""
    return dr.select((wi[2] > 0.0) & (wo[2] > 0.0), wo[2] * INV_PI, 0.0)
