"""Shared helpers for the msx plugin tests.

The package must be installed (``pip install .``); tests run in Mitsuba's
scalar variants, which are switched per test with the ``variant`` helpers.
"""

import math
import random

import pytest

mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402  (installed with mitsuba)


def set_variant(name):
    mi.set_variant(name)
    import msx

    msx.register()
    return mi


@pytest.fixture
def rgb():
    dr.set_thread_count(1)
    return set_variant("scalar_rgb")


@pytest.fixture
def spectral():
    dr.set_thread_count(1)
    return set_variant("scalar_spectral")


# What msx_posfree's traverse lists per configuration, in order: the roughness, then the spectral textures
# the surface uses (README.md's parameter table). The test modules of each route check it.
TRAVERSE_CASES = [
    (dict(alpha=0.3), ("alpha", "eta", "k", "specular_reflectance")),
    (dict(alpha_u=0.2, alpha_v=0.4, material="Cu"), ("alpha_u", "alpha_v", "eta", "k", "specular_reflectance")),
    (dict(surface="dielectric", alpha=0.3), ("alpha", "specular_reflectance", "specular_transmittance")),
    (dict(surface="dielectric", alpha_u=0.2, alpha_v=0.4),
     ("alpha_u", "alpha_v", "specular_reflectance", "specular_transmittance")),
    (dict(surface="diffuse", alpha=0.3), ("alpha", "reflectance")),
]
# Roughness and a conductor's IOR are differentiable and discontinuous, as in Mitsuba's roughconductor.
_DISCONTINUOUS = ("alpha", "alpha_u", "alpha_v", "eta", "k")


def traverse_items(mi, bsdf):
    """(name, flags) of each parameter bsdf.traverse puts, in order; every value must be a texture."""
    items = []

    class Collect(mi.TraversalCallback):
        def put(self, name, value, flags):
            assert isinstance(value, mi.Texture), (name, value)
            items.append((name, int(flags)))

    bsdf.traverse(Collect())
    return items


def expected_traverse(mi, names):
    diff, disc = mi.ParamFlags.Differentiable, mi.ParamFlags.Discontinuous
    return [(n, int(diff | disc) if n in _DISCONTINUOUS else int(diff)) for n in names]


def hemisphere_dir(rng, cos_lo=0.0, cos_hi=1.0):
    """A unit vector with z = cos θ uniform in [cos_lo, cos_hi] and uniform φ."""
    z = rng.uniform(cos_lo, cos_hi)
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = rng.uniform(0.0, 2.0 * math.pi)
    return (r * math.cos(phi), r * math.sin(phi), z)


def direction_pairs(seed, n, grazing_fraction=0.1):
    """n (wi, wo) pairs in the upper hemisphere; a fraction is grazing-ish
    (cos θ in [0.002, 0.05]) for wi or wo."""
    rng = random.Random(seed)
    pairs = []
    for i in range(n):
        g = rng.random()
        wi = hemisphere_dir(rng, 0.002, 0.05) if g < grazing_fraction / 2 else hemisphere_dir(rng, 0.05, 1.0)
        wo = (
            hemisphere_dir(rng, 0.002, 0.05)
            if grazing_fraction / 2 <= g < grazing_fraction
            else hemisphere_dir(rng, 0.05, 1.0)
        )
        pairs.append((wi, wo))
    return pairs


def close(a, b, rtol=1e-4, atol=1e-6):
    """|a-b| <= rtol·max(|a|,|b|) + atol (atol: float32-level floor)."""
    return abs(a - b) <= rtol * max(abs(a), abs(b)) + atol
