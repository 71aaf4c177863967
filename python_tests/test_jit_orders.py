"""Order by order, the Dr.Jit engine's random walks equal the Rust core's (issue 29, item 4).

The cases come from the tables: every model that the engine runs on a surface (``ENGINE_MODELS``) and that
the core's table of names marks as a random walk whose value splits by scattering order (``per_order``),
except ``auto`` (``correlated`` with a cap). For each, the engine's ``eval`` with ``max_bounces = k``
(orders 1..k, in ``llvm_ad_rgb``) against the core's ``msx_eval_orders(1, k)`` (``msx.core.CoreBsdf``,
float64), k = 1, 2, 3, at fixed (ω_i, ω_o) pairs of each surface — for glass: reflected and transmitted,
from outside and from inside. Grey materials (a conductor with F = 1, glass of IOR 1.5, facets of albedo
0.8), GGX α 0.8, where the higher orders carry a few per cent each.

Both sides are independent Monte Carlo estimates (the engine's lanes hashed from si.p, the core's from its
batch key). z = Δ/√(σ₁² + σ₂²), σ of a mean the larger of the plain standard error and the replicate one
from two halves (the walks' estimates have heavy tails), two-sided, Šidák-corrected to a family-wise
false-alarm rate of 1e-3 over every comparison of this file. 2^17 lanes per side only set the power.
"""

import math
from statistics import NormalDist

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

LANES = 1 << 17
ALPHA = 0.8
ORDERS = (1, 2, 3)
# (θ_i, θ_o, φ_o − φ_i); θ > π/2 is below the surface (a refraction continues the ray: φ_o − φ_i near π).
PAIRS = {
    "conductor": ((0.4, 0.6, math.pi), (1.2, 0.5, 0.4)),
    "dielectric": ((0.4, 0.6, math.pi), (0.5, 2.6, math.pi - 0.3), (2.7, 2.4, math.pi), (2.5, 0.7, math.pi - 0.5)),
    "diffuse": ((0.4, 0.6, math.pi), (1.2, 0.9, 2.0)),
}
MATERIAL = {"conductor": ({"material": "none"}, {"eta": 0.0, "k": 1.0}),
            "dielectric": ({"int_ior": 1.5, "ext_ior": 1.0}, {"ior": 1.5}),
            "diffuse": ({"reflectance": 0.8}, {"reflectance": 0.8})}


def cases():
    mi.set_variant("llvm_ad_rgb")
    import jit_support

    return [(s, m, pair) for s, m, _ in jit_support.engine_cases(per_order=True) for pair in PAIRS[s]]


CASES = cases()
N_COMPARISONS = len(CASES) * len(ORDERS)
Z_MAX = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / N_COMPARISONS)) / 2.0)


@pytest.fixture(scope="module", autouse=True)
def engine():
    import jit_support

    with jit_support.engine_mode():
        yield


def direction(theta, phi=0.0):
    v = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
    return (v / np.linalg.norm(v)).astype(np.float32)


def mean_and_se(x):
    half = len(x) // 2
    plain = x.std(ddof=1) / math.sqrt(len(x))
    return x.mean(), max(plain, abs(x[:half].mean() - x[half:].mean()) / 2.0)


_CALL = [0]


def engine_values(surface, model, k, wi, wo):
    _CALL[0] += 1
    b = mi.load_dict({"type": "msx_posfree", "surface": surface, "model": model, "distribution": "ggx",
                      "alpha": ALPHA, "max_bounces": k, **MATERIAL[surface][0]})
    si = dr.zeros(mi.SurfaceInteraction3f, LANES)
    si.wi = mi.Vector3f(*[mi.Float(np.full(LANES, float(c), dtype=np.float32)) for c in wi])
    si.p = mi.Point3f(mi.Float(np.arange(LANES, dtype=np.float32)),
                      mi.Float(np.full(LANES, _CALL[0], dtype=np.float32)), mi.Float(np.zeros(LANES, np.float32)))
    ctx = mi.BSDFContext(mi.TransportMode.Radiance)
    value = b.eval(ctx, si, mi.Vector3f(*[mi.Float(np.full(LANES, float(c), dtype=np.float32)) for c in wo]))
    dr.eval(value)
    return np.array(value[0].numpy(), dtype=np.float64)


def core_values(surface, model, k, wi, wo):
    from msx.core import CoreBsdf

    b = CoreBsdf(surface=surface, distribution="ggx", model=model, alpha=ALPHA, seed=k,
                 **MATERIAL[surface][1])
    wis, wos = np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1))
    return b.eval(wis, wos, orders=(1, k))[0]


@pytest.mark.parametrize("surface,model,pair", CASES, ids=["%s-%s-%s" % (s, m, p) for s, m, p in CASES])
def test_orders_equal_the_core(surface, model, pair):
    ti, to, dphi = pair
    wi, wo = direction(ti), direction(to, dphi)
    lines, bad = [], []
    previous = None
    for k in ORDERS:
        a, sa = mean_and_se(engine_values(surface, model, k, wi, wo))
        c, sc = mean_and_se(core_values(surface, model, k, wi, wo))
        z = (a - c) / math.sqrt(sa * sa + sc * sc) if sa + sc > 0 else 0.0
        lines.append("orders 1..%d: engine %.6g ± %.2g, core %.6g ± %.2g, z %+.2f" % (k, a, sa, c, sc, z))
        if abs(z) > Z_MAX:
            bad.append(lines[-1])
        if k == 1:
            assert c > 0.0, "no single scattering at this pair: the comparison would be empty"
        previous = c
    print("%s %s %s\n  " % (surface, model, pair) + "\n  ".join(lines))
    assert previous is not None
    assert not bad, "beyond |z| %.2f:\n%s" % (Z_MAX, "\n".join(bad))
