"""The Dr.Jit engine's bidirectional estimators (Wang 2022 eqs. 27–29; ``msx/jit/bdpt.py`` and the conductor's
vertex terms in ``msx/jit/posfree.py``; Cui 2023's with the whole path's exit probability, ``WholePath`` in
``msx/jit/invariance_conductor.py``) against the Rust core's BDPT and the engine's own PT, in ``llvm_ad_rgb``.

The BDPT estimate has the expectation of the PT estimate (both are unbiased estimates of f·cos θ_o), so:
- the mean of ``eval`` at fixed (ω_i, ω_o) pairs equals the core's BDPT mean and the engine's PT mean within
  their noise, for both segment models and ``invariance``, α ∈ {0.3, 1}, the default bounce cap (orders above K_b = 3 by the
  PT tail) and the caps 2 and 3 (K_b = the cap: no tail); z = Δ/√(σ₁² + σ₂²) with σ the larger of the plain
  and the replicate standard error, against a Šidák-corrected family-wise false-alarm rate of 1e-3 over
  every comparison of this file (the method of test_jit_engine.py);
- cap 1 (order 1 only: the single connection s = t = 0, deterministic) equals the core and the engine's PT
  lane by lane (float32 against float64);
- ω_i below the macro surface (normal mapping) takes the PT estimator, in the tail's loop (cap 64) or on
  its own (cap 2): its mean equals the engine's PT;
- off-specular at α = 1 the BDPT has a lower variance per lane than the PT (ratios measured below);
- white furnace: material='none' (F = 1), ∫ eval dω_o = 1 within noise.
``MSX_TEST_SEED_OFFSET`` reruns the statistical checks at other seeds (docs/testing.md).
"""

import math
import os
import statistics

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import jit_support  # noqa: E402
from jit_support import lanes_si  # noqa: E402

# The conductor invariance walk keeps its run in registers: it loads (and renders) without
# msx.jit.bsdf.ALLOW_LOCAL_ARRAYS, which only the Lambertian invariance walk needs.
from msx.core import CoreBsdf  # noqa: E402

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
LANES = 1 << 16
CAP_LANES = 1 << 15  # the bounce-cap cases (cheaper orders, more configurations)
REPLICATES = 4

SEGMENTS = ("correlated", "uncorrelated")
MODELS = SEGMENTS + ("invariance",)  # invariance: Cui 2023's BDPT, on CAP_LANES (its walk is dearer)
ALPHAS = (0.3, 1.0)
CAPS = (2, 3)


def _dir(x, y):
    return (x, y, math.sqrt(1 - x * x - y * y))


PAIRS = [(_dir(0.3, 0.0), _dir(-0.5, 0.2)), (_dir(0.8, 0.1), _dir(0.1, -0.3)), (_dir(0.95, 0.0), _dir(-0.9, 0.0))]
# Off-specular pairs of the variance comparison: ω_i = n with ω_o at 53°, and PAIRS[0].
VARIANCE_PAIRS = [(_dir(0.0, 0.0), _dir(0.8, 0.0)), PAIRS[0]]
# ω_i below the macro surface (a tilted shading normal), ω_o above.
BELOW = ((0.5, 0.1, -math.sqrt(1 - 0.26)), _dir(-0.3, 0.2))
BELOW_CAPS = (64, 2)
FURNACE_ALPHAS = (0.3, 1.0)
FURNACE_INCIDENCES = (0.3, 0.9)

# Every z-test of this file, for the Šidák correction (3 channels each except the furnace).
COMPARISONS = (len(MODELS) * len(ALPHAS) * len(PAIRS) * 2 * 3            # cap 64: vs core, vs PT
               + len(CAPS) * len(MODELS) * len(ALPHAS) * 2 * 3            # caps 2, 3: vs core, vs PT
               + len(BELOW_CAPS) * 3                                      # ω_i below vs PT
               + len(FURNACE_ALPHAS) * len(FURNACE_INCIDENCES))           # furnace
FAMILY_RATE = 1e-3
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - FAMILY_RATE) ** (1 / COMPARISONS)) / 2)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():  # backend="jit", not whatever route an earlier module registered
        yield


def cu_rgb():
    """Mitsuba's RGB (η, k) of copper in this variant."""
    p = mi.traverse(mi.load_dict({"type": "roughconductor", "material": "Cu"}))
    return [float(x) for x in np.array(p["eta.value"]).ravel()], [float(x) for x in np.array(p["k.value"]).ravel()]


def stats(x):
    return jit_support.stats(x, REPLICATES)


def z_check(label, a, b):
    jit_support.z_check(label, a, b, Z_MAX)


def as_channels(a):
    a = np.asarray(a, np.float64)
    return a.T if a.shape[-1] == 3 and a.shape[0] != 3 else a


def engine_bsdf(segments, alpha, estimator="bdpt", max_bounces=None, **extra):
    d = {"type": "msx_posfree", "material": "Cu", "distribution": "ggx", "alpha": alpha, "model": segments,
         "estimator": estimator, **extra}
    if max_bounces is not None:
        d["max_bounces"] = max_bounces
    return mi.load_dict(d)


def core_bsdf(segments, alpha, max_bounces=0):
    eta, k = cu_rgb()
    return CoreBsdf(surface="conductor", distribution="ggx", model=segments, estimator="bdpt", alpha=alpha,
                    eta=eta, k=k, channels=3, seed=SEED_OFFSET, max_bounces=max_bounces)


def engine_eval(b, wi, wo, n, seed):
    """(channels, n) values of eval at one pair; the lanes' hit positions (hence streams) from ``seed``."""
    si = lanes_si(wi, n, seed)
    wo_v = mi.Vector3f(*[mi.Float(np.full(n, c, np.float32)) for c in wo])
    return as_channels(np.array(b.eval(mi.BSDFContext(), si, wo_v)))


def core_eval(c, wi, wo, n):
    return as_channels(c.eval(np.tile(wi, (n, 1)), np.tile(wo, (n, 1))))


@pytest.mark.parametrize("segments", MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_eval_means_equal_core_bdpt_and_engine_pt(segments, alpha):
    """Default bounce cap (64): orders 1–3 bidirectionally, 4–64 by the PT tail."""
    b, p, c = engine_bsdf(segments, alpha), engine_bsdf(segments, alpha, "pt"), core_bsdf(segments, alpha)
    n = CAP_LANES if segments == "invariance" else LANES
    for i, (wi, wo) in enumerate(PAIRS):
        seed = 1000 * i + 23 + SEED_OFFSET
        e = stats(engine_eval(b, wi, wo, n, seed))
        z_check("%s α %.1f pair %d: engine bdpt vs core bdpt" % (segments, alpha, i), e,
                stats(core_eval(c, wi, wo, n)))
        z_check("%s α %.1f pair %d: engine bdpt vs engine pt" % (segments, alpha, i), e,
                stats(engine_eval(p, wi, wo, n, seed + 500)))


@pytest.mark.parametrize("cap", CAPS)
@pytest.mark.parametrize("segments", MODELS)
def test_bounce_caps_equal_core_bdpt_and_engine_pt(cap, segments):
    """max_bounces = K_b (3) and below (2): every order bidirectional, no PT tail."""
    for j, alpha in enumerate(ALPHAS):
        i = (j + cap) % len(PAIRS)
        wi, wo = PAIRS[i]
        b, p = engine_bsdf(segments, alpha, max_bounces=cap), engine_bsdf(segments, alpha, "pt", max_bounces=cap)
        seed = 3000 + 100 * cap + 10 * j + SEED_OFFSET
        e = stats(engine_eval(b, wi, wo, CAP_LANES, seed))
        z_check("%s α %.1f cap %d pair %d: engine bdpt vs core bdpt" % (segments, alpha, cap, i), e,
                stats(core_eval(core_bsdf(segments, alpha, cap), wi, wo, CAP_LANES)))
        z_check("%s α %.1f cap %d pair %d: engine bdpt vs engine pt" % (segments, alpha, cap, i), e,
                stats(engine_eval(p, wi, wo, CAP_LANES, seed + 1)))


@pytest.mark.parametrize("segments", MODELS)
def test_order_one_equals_core_and_pt_per_lane(segments):
    """max_bounces = 1: the one strategy s = t = 0 (the single-scattering connection, no random number)
    equals the core's BDPT and the engine's PT (next event at vertex 0) lane by lane, at random pairs."""
    n = 2048
    rng = np.random.default_rng(41 + SEED_OFFSET)
    z_i, z_o = rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
    phi = rng.uniform(0, 2 * np.pi, (2, n))
    wi = np.stack([np.sqrt(1 - z_i ** 2) * np.cos(phi[0]), np.sqrt(1 - z_i ** 2) * np.sin(phi[0]), z_i], 1)
    wo = np.stack([np.sqrt(1 - z_o ** 2) * np.cos(phi[1]), np.sqrt(1 - z_o ** 2) * np.sin(phi[1]), z_o], 1)
    wi, wo = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(wi[:, i].astype(np.float32)) for i in range(3)])
    wo_v = mi.Vector3f(*[mi.Float(wo[:, i].astype(np.float32)) for i in range(3)])
    for alpha in ALPHAS:
        e = as_channels(np.array(engine_bsdf(segments, alpha, max_bounces=1).eval(mi.BSDFContext(), si, wo_v)))
        p = as_channels(np.array(engine_bsdf(segments, alpha, "pt", max_bounces=1).eval(mi.BSDFContext(), si, wo_v)))
        c = as_channels(core_bsdf(segments, alpha, 1).eval(wi, wo))
        assert np.all(e > 0)
        # float32 against float64 (D and Λ in float32; directions normalised in float32)
        assert np.allclose(e, c, rtol=2e-4, atol=1e-6), (alpha, np.abs(e / c - 1).max())
        assert np.allclose(e, p, rtol=2e-4, atol=1e-6), (alpha, np.abs(e / p - 1).max())


@pytest.mark.parametrize("cap", BELOW_CAPS)
def test_incidence_below_takes_the_pt_estimator(cap):
    """ω_i below the macro surface with ω_o above: the PT estimator (the core does the same), in the PT
    tail's loop (cap 64) or in a walk of its own (cap 2 ≤ K_b)."""
    wi, wo = BELOW
    b, p = engine_bsdf("correlated", 0.6, max_bounces=cap), engine_bsdf("correlated", 0.6, "pt", max_bounces=cap)
    e = engine_eval(b, wi, wo, LANES, 5100 + cap + SEED_OFFSET)
    assert np.all(np.isfinite(e)) and e.mean() > 0
    z_check("ω_i below, cap %d: engine bdpt vs engine pt" % cap, stats(e),
            stats(engine_eval(p, wi, wo, LANES, 5200 + cap + SEED_OFFSET)))


# The smallest PT/BDPT variance ratio asserted per model (see the test).
VARIANCE_RATIO_MIN = {"correlated": 1.5, "uncorrelated": 1.5, "invariance": 1.15}


@pytest.mark.parametrize("segments", MODELS)
def test_variance_lower_than_pt_off_specular(segments):
    """α = 1, off-specular: the per-lane variance of the BDPT is below the PT's. Measured (engine, 2¹⁶
    lanes, cap 64, 10 seeds; the core's ratios agree within 2 %), PT/BDPT per channel, mean (seed-to-seed
    σ ≤ 0.018): Wang correlated 2.25/2.76/2.94 (ω_i = n, ω_o at 53°) and 1.87/2.14/2.24 (PAIRS[0]);
    uncorrelated 2.05/2.72/2.97 and 1.66/1.99/2.11; invariance (whose PT already has a connection for
    orders 2–3) 1.29/1.34/1.32 and 1.31/1.41/1.42. Asserted: > 1.5 (Wang) and > 1.15 (invariance), ≥ 8σ
    below every measured mean."""
    b, p = engine_bsdf(segments, 1.0), engine_bsdf(segments, 1.0, "pt")
    for i, (wi, wo) in enumerate(VARIANCE_PAIRS):
        seed = 7000 + 10 * i + SEED_OFFSET
        e, q = engine_eval(b, wi, wo, LANES, seed), engine_eval(p, wi, wo, LANES, seed + 1)
        ratio = q.var(axis=1) / e.var(axis=1)
        print("%s α 1 variance pair %d: PT/BDPT %s" % (segments, i, np.round(ratio, 2)))
        assert np.all(ratio > VARIANCE_RATIO_MIN[segments]), (segments, i, ratio)


@pytest.mark.parametrize("alpha", FURNACE_ALPHAS)
def test_white_furnace(alpha):
    """material='none' (F = 1): ∫ eval dω_o over the hemisphere, by uniform directions (2π·mean), is 1
    within noise for the correlated BDPT (every order up to 64: the loss beyond is negligible)."""
    b = mi.load_dict({"type": "msx_posfree", "distribution": "ggx", "alpha": alpha, "model": "correlated",
                      "estimator": "bdpt"})
    for mu in FURNACE_INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        rng = np.random.default_rng(37 + SEED_OFFSET + int(100 * mu))
        z, phi = rng.random(LANES), rng.uniform(0, 2 * np.pi, LANES)
        r = np.sqrt(1 - z * z)
        wo = mi.Vector3f(mi.Float(r * np.cos(phi)), mi.Float(r * np.sin(phi)), mi.Float(z))
        v = np.array(b.eval(mi.BSDFContext(), lanes_si(wi, LANES, 79 + SEED_OFFSET), wo), np.float64)
        m, s = stats(2 * np.pi * as_channels(v)[:1])
        print("bdpt furnace α %.1f μ %.2f: albedo %.5f ± %.5f" % (alpha, mu, m[0], s[0]))
        assert abs(m[0] - 1.0) <= Z_MAX * s[0], (alpha, mu, m[0], s[0])
