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


def conductor_pdf(exit, below, mf, wi, wo):
    """``walk_pdf`` of a conductor: 0 for ω_o below; ω_i below the surface (normal mapping) gets a cosine
    lobe when the walk starts there (``below``, the position-free walks), else 0."""
    pdf = conductor_walk_pdf(exit, mf, wi, wo)
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
