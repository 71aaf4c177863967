"""The Dr.Jit engine's walks on the dielectric and the diffuse microsurface (jit/heitz.py: Heitz 2016;
jit/invariance_general.py: Cui 2023 on Lambertian facets) equal the Rust core in distribution, in llvm_ad_rgb.

Each configuration is built twice: ``msx_posfree`` through Mitsuba (the engine) and
``msx.core.CoreBsdf`` (the Rust core, float64), GGX. Both give independent Monte Carlo estimates (the
engine's lane streams are hashed from each lane's si.p, the core's from its seed; the samplers get
independent uniform numbers), so equal distributions mean equal expectations:

* dielectric (η = 1.5, untinted: channel 0): the mean of ``eval`` at fixed (ω_i, ω_o) pairs, ω_i outside
  and inside, reflection and transmission, in Radiance and Importance mode; the directional albedo (mean
  ``sample`` weight) and E[w·ω_o,z] (which separates reflection from transmission, the Importance-mode
  weights being all 1) at incidences from both sides;
* diffuse (reflectance (0.8, 0.5, 0.2)): eval means per channel and the albedo per channel plus E[w·ω_o,z];
* physics on the engine alone: the dielectric white furnace (Importance mode: ∫ f·|cos θ_o| dω_o over the
  sphere = 1, by uniform directions, 4π·mean) and, with reflectance 1, the diffuse one (∫ eval over the
  hemisphere = 1 and the sampled albedo = 1); the walks lose energy only to the bounce cap (64), far
  below the noise;
* below the macro surface the diffuse walks give 0 and invalid samples, as the core.

Statistics (as python_tests/test_jit_walks.py): z = Δ/√(σ₁² + σ₂²), σ of a mean the larger of the plain
standard error and the replicate one from four independent quarters (the walks' estimates are
heavy-tailed; a sample that missed its tail gets no small σ), two-sided, Šidák-corrected to a family-wise
false-alarm rate of 1e-3 over all N_COMPARISONS comparisons of this file. No tolerance is tuned; the lane
counts only set the power. ``MSX_TEST_SEED_OFFSET`` reruns the checks at other seeds (docs/testing.md).
"""

import math
import os
from statistics import NormalDist

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import msx  # noqa: E402
import jit_support  # noqa: E402
from jit_support import lanes_si  # noqa: E402
import msx.jit.bsdf  # noqa: E402

# The Lambertian invariance walk keeps its table in dr.alloc_local, which a render cannot compile (drjit 1.5,
# docs/engines.md) but direct calls of the BSDF's methods can: these tests call the methods directly.
msx.jit.bsdf.ALLOW_LOCAL_ARRAYS = True
from msx.core import CoreBsdf  # noqa: E402

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
LANES = 1 << 16
FURNACE_LANES = 1 << 19
REPLICATES = 4
IOR = 1.5
REFLECTANCE = (0.8, 0.5, 0.2)
CHANNELS = 3


def _dir(theta, phi=0.0):
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


# The models per surface (jit/bsdf.py's DIELECTRIC_WALKS / DIFFUSE_WALKS entries under test).
DIELECTRIC_MODELS = ("heitz", "invariance")
DIFFUSE_MODELS = ("heitz", "invariance")
ALPHAS = (0.3, 1.0)
RADIANCE = (True, False)  # Mitsuba's transport mode: Radiance, Importance
# (label, ω_i, ω_o): reflection and transmission from outside (the transmission near the refracted peak),
# from inside beyond the critical angle (asin(1/1.5) ≈ 0.73 rad) and a transmission out of the material.
DIELECTRIC_PAIRS = (("outside R", _dir(0.5), _dir(1.0, math.pi)),
                    ("outside T", _dir(0.5), _dir(math.pi - 0.4, math.pi)),
                    ("inside R (TIR)", _dir(math.pi - 0.9), _dir(math.pi - 0.8, math.pi + 0.3)),
                    ("inside T", _dir(math.pi - 0.3), _dir(0.8, math.pi)))
DIELECTRIC_INCIDENCES = (0.9, 0.3, -0.9, -0.3)  # cos θ_i of the sampled albedo: both sides
DIELECTRIC_FURNACE = (0.6, -0.6)
# Diffuse: near backscatter, a grazing ω_i, a grazing ω_o off the plane of incidence.
DIFFUSE_PAIRS = ((_dir(0.3), _dir(0.5, math.pi)), (_dir(1.25), _dir(0.4, 0.3)), (_dir(0.7), _dir(1.35, 2.2)))
DIFFUSE_INCIDENCES = (0.9, 0.25)
DIFFUSE_FURNACE = (0.6,)
# The bounce cap's check (max_bounces = 2): the walks truncate as the core does; on the dielectric this
# also exercises the invariance model's hand-over to Heitz's walk after a first-vertex refraction.
BOUNCE_CAP = 2
CAP_DIELECTRIC_PAIRS = (DIELECTRIC_PAIRS[1], DIELECTRIC_PAIRS[2])
CAP_DIELECTRIC_MU = -0.9

N_COMPARISONS = (
    len(DIELECTRIC_MODELS) * len(ALPHAS) * (
        len(RADIANCE) * (len(DIELECTRIC_PAIRS) + 2 * len(DIELECTRIC_INCIDENCES)) + len(DIELECTRIC_FURNACE))
    + len(DIFFUSE_MODELS) * len(ALPHAS) * (
        len(DIFFUSE_PAIRS) * CHANNELS + len(DIFFUSE_INCIDENCES) * (CHANNELS + 1) + 2 * len(DIFFUSE_FURNACE))
    + len(DIELECTRIC_MODELS) * (len(CAP_DIELECTRIC_PAIRS) + 2)  # bounce cap: eval pairs, albedo, E[w·ωo,z]
    + len(DIFFUSE_MODELS) * 2 * CHANNELS)  # bounce cap: one eval pair, the albedo
FAMILY_RATE = 1e-3
Z_MAX = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - FAMILY_RATE) ** (1.0 / N_COMPARISONS)) / 2.0)


@pytest.fixture(scope="module", autouse=True)
def engine():
    """The engine's msx_posfree for llvm_ad_rgb with drjit's default (symbolic) loops; what another test
    module registered and drjit's flags are put back afterwards."""
    previous = msx._REGISTERED.get("llvm_ad_rgb")
    flags = {f: dr.flag(f) for f in (dr.JitFlag.SymbolicLoops, dr.JitFlag.SymbolicCalls)}
    mi.set_variant("llvm_ad_rgb")
    msx.register(backend="jit")
    for f in flags:
        dr.set_flag(f, True)
    yield
    if previous is not None and previous[0] != "jit":
        msx.register(backend=previous[0])
    for f, v in flags.items():
        dr.set_flag(f, v)


def context(radiance):
    return mi.BSDFContext(mi.TransportMode.Radiance if radiance else mi.TransportMode.Importance)


def vec(a):
    """A (n, 3) float array as mi.Vector3f (float32: both engines get the same bits)."""
    return mi.Vector3f(*[mi.Float(np.ascontiguousarray(a[..., c], np.float32)) for c in range(3)])


def tile(w, n):
    return np.tile(np.asarray(w, np.float32), (n, 1))


def channels(v):
    """(channels, n) float64 of a Mitsuba spectrum over lanes."""
    return np.asarray(v, np.float64).reshape(CHANNELS, -1)


def stats(x):
    return jit_support.stats(x, REPLICATES)


def z_check(label, a, b):
    jit_support.z_check(label, a, b, Z_MAX)


def sample_uniforms(seed, n=LANES):
    return np.random.default_rng(seed).random((3, n))


def engine_sample(b, ctx, wi, seed, n=LANES):
    """(ω_o (3, n), weight (channels, n), pdf (n,)) of Mitsuba's sample() at ``wi``."""
    u = sample_uniforms(seed, n).astype(np.float32)
    bs, w = b.sample(ctx, lanes_si(wi, n, seed + 1), mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
    dr.eval(bs.wo, bs.pdf, w)
    return np.asarray(bs.wo, np.float64), channels(w), np.asarray(bs.pdf, np.float64)


def core_sample(c, wi, seed, n=LANES):
    """(ω_o (3, n), weight (channels, n)) of the core's sampler, invalid samples as weight 0."""
    wo, w, pdf = c.sample(tile(wi, n), sample_uniforms(seed, n))
    ok = pdf > 0.0
    return np.where(ok, wo.T, 0.0), np.where(ok, w, 0.0)


# ------------------------------------------------------------------ dielectric


def dielectric_engine(model, alpha, max_bounces=0):
    # ext_ior = 1 (Mitsuba's default is air, 1.000277): the relative IOR is the core's ``ior``.
    extra = {"max_bounces": max_bounces} if max_bounces else {}
    return mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "distribution": "ggx", "alpha": alpha,
                         "int_ior": IOR, "ext_ior": 1.0, "model": model, **extra})


def dielectric_core(model, alpha, radiance, max_bounces=0):
    # Another seed per mode: the two modes' estimates are independent samples, not one rescaled.
    return CoreBsdf(surface="dielectric", distribution="ggx", model=model, alpha=alpha, ior=IOR,
                    channels=CHANNELS, radiance=radiance, seed=SEED_OFFSET + (0 if radiance else 1000),
                    max_bounces=max_bounces)


@pytest.mark.parametrize("radiance", RADIANCE, ids=("radiance", "importance"))
@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIELECTRIC_MODELS)
def test_dielectric_eval_equals_core(model, alpha, radiance):
    b, c, ctx = dielectric_engine(model, alpha), dielectric_core(model, alpha, radiance), context(radiance)
    mode = "radiance" if radiance else "importance"
    for i, (label, wi, wo) in enumerate(DIELECTRIC_PAIRS):
        seed = 1000 * i + 17 + SEED_OFFSET + (0 if radiance else 500)
        e = channels(b.eval(ctx, lanes_si(wi, LANES, seed), vec(tile(wo, LANES))))
        r = c.eval(tile(wi, LANES), tile(wo, LANES))
        assert np.all(np.isfinite(e)) and np.all(e >= 0.0), label
        assert np.array_equal(e[0], e[1]) and np.array_equal(e[0], e[2])  # untinted: one value
        z_check("%s dielectric α=%g %s %s eval" % (model, alpha, mode, label), stats(e[0]), stats(r[0]))


@pytest.mark.parametrize("radiance", RADIANCE, ids=("radiance", "importance"))
@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIELECTRIC_MODELS)
def test_dielectric_sample_equals_core(model, alpha, radiance):
    """The directional albedo and E[w·ω_o,z] of the sampled walk equal the core's."""
    b, c, ctx = dielectric_engine(model, alpha), dielectric_core(model, alpha, radiance), context(radiance)
    mode = "radiance" if radiance else "importance"
    for i, mu in enumerate(DIELECTRIC_INCIDENCES):
        wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
        seed = 7 + 10 * i + SEED_OFFSET + (0 if radiance else 5000)
        wo_e, w_e, pdf_e = engine_sample(b, ctx, wi, seed)
        wo_r, w_r = core_sample(c, wi, seed + 3)
        assert np.all(np.isfinite(w_e)) and np.all(w_e >= 0.0) and np.all(np.isfinite(wo_e))
        assert np.all(pdf_e[w_e[0] > 0.0] > 0.0)
        if not radiance:
            assert np.all((w_e[0] == 0.0) | (w_e[0] == 1.0))  # Importance mode: every vertex weighs 1
        label = "%s dielectric α=%g %s μ=%+.2f" % (model, alpha, mode, mu)
        z_check(label + " albedo", stats(w_e[0]), stats(w_r[0]))
        z_check(label + " E[w·ωo,z]", stats(w_e[0] * wo_e[2]), stats(w_r[0] * wo_r[2]))


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIELECTRIC_MODELS)
def test_dielectric_white_furnace(model, alpha):
    """Importance mode: ∫ f·|cos θ_o| dω_o over the sphere (4π·mean over uniform directions) is 1."""
    b, ctx, n = dielectric_engine(model, alpha), context(False), FURNACE_LANES
    for i, mu in enumerate(DIELECTRIC_FURNACE):
        wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
        rng = np.random.default_rng(31 + i + SEED_OFFSET)
        z, phi = rng.uniform(-1.0, 1.0, n), rng.uniform(0.0, 2.0 * math.pi, n)
        r = np.sqrt(1.0 - z * z)
        wo = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        v = 4.0 * math.pi * channels(b.eval(ctx, lanes_si(wi, n, 77 + i + SEED_OFFSET), vec(wo)))[0]
        z_check("%s dielectric furnace α=%g μ=%+.2f ∫eval" % (model, alpha, mu), stats(v), (1.0, 0.0))


# ------------------------------------------------------------------ diffuse


def diffuse_engine(model, alpha, refl=REFLECTANCE, max_bounces=0):
    extra = {"max_bounces": max_bounces} if max_bounces else {}
    return mi.load_dict({"type": "msx_posfree", "surface": "diffuse", "distribution": "ggx", "alpha": alpha,
                         "model": model, "reflectance": {"type": "rgb", "value": list(refl)}, **extra})


def diffuse_core(model, alpha, refl=REFLECTANCE, max_bounces=0):
    return CoreBsdf(surface="diffuse", distribution="ggx", model=model, alpha=alpha, reflectance=list(refl),
                    channels=CHANNELS, seed=SEED_OFFSET, max_bounces=max_bounces)


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIFFUSE_MODELS)
def test_diffuse_eval_equals_core(model, alpha):
    b, c = diffuse_engine(model, alpha), diffuse_core(model, alpha)
    for i, (wi, wo) in enumerate(DIFFUSE_PAIRS):
        e = channels(b.eval(mi.BSDFContext(), lanes_si(wi, LANES, 300 + i + SEED_OFFSET), vec(tile(wo, LANES))))
        r = c.eval(tile(wi, LANES), tile(wo, LANES))
        assert np.all(np.isfinite(e)) and np.all(e >= 0.0)
        for ch in range(CHANNELS):
            z_check("%s diffuse α=%g pair %d eval ch%d" % (model, alpha, i, ch), stats(e[ch]), stats(r[ch]))


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIFFUSE_MODELS)
def test_diffuse_sample_equals_core(model, alpha):
    b, c, ctx = diffuse_engine(model, alpha), diffuse_core(model, alpha), mi.BSDFContext()
    for i, mu in enumerate(DIFFUSE_INCIDENCES):
        wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
        wo_e, w_e, pdf_e = engine_sample(b, ctx, wi, 400 + 10 * i + SEED_OFFSET)
        wo_r, w_r = core_sample(c, wi, 500 + 10 * i + SEED_OFFSET)
        assert np.all(np.isfinite(w_e)) and np.all(w_e >= 0.0)
        valid = w_e[0] > 0.0
        assert np.all(wo_e[2][valid] > 0.0) and np.all(pdf_e[valid] > 0.0)
        label = "%s diffuse α=%g μ=%.2f" % (model, alpha, mu)
        for ch in range(CHANNELS):
            z_check(label + " albedo ch%d" % ch, stats(w_e[ch]), stats(w_r[ch]))
        z_check(label + " E[w·ωo,z]", stats(w_e[0] * wo_e[2]), stats(w_r[0] * wo_r[2]))


@pytest.mark.parametrize("alpha", ALPHAS)
@pytest.mark.parametrize("model", DIFFUSE_MODELS)
def test_diffuse_white_furnace(model, alpha):
    """Reflectance 1: ∫ eval over the hemisphere (2π·mean over uniform directions) is 1, and every valid
    sample weighs exactly 1 with albedo 1."""
    b, ctx, n = diffuse_engine(model, alpha, (1.0, 1.0, 1.0)), mi.BSDFContext(), FURNACE_LANES
    for i, mu in enumerate(DIFFUSE_FURNACE):
        wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
        rng = np.random.default_rng(41 + i + SEED_OFFSET)
        z, phi = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 2.0 * math.pi, n)
        r = np.sqrt(1.0 - z * z)
        wo = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        v = 2.0 * math.pi * channels(b.eval(ctx, lanes_si(wi, n, 87 + i + SEED_OFFSET), vec(wo)))[0]
        z_check("%s diffuse furnace α=%g μ=%.2f ∫eval" % (model, alpha, mu), stats(v), (1.0, 0.0))
        _, w, _ = engine_sample(b, ctx, wi, 600 + i + SEED_OFFSET, n=LANES)
        assert np.all((w == 0.0) | (w == 1.0))
        z_check("%s diffuse furnace α=%g μ=%.2f albedo" % (model, alpha, mu), stats(w[0]), (1.0, 0.0))


@pytest.mark.parametrize("model", DIFFUSE_MODELS)
def test_diffuse_below_horizon_is_zero(model):
    """As the core (``valid_incidence``): Lambertian facets need ω_i (and, for eval, ω_o) above."""
    n = 64
    b, c = diffuse_engine(model, 0.5), diffuse_core(model, 0.5)
    up, down = _dir(0.5), _dir(math.pi - 0.5, 1.0)
    for wi, wo in ((down, up), (up, down), (down, down)):
        assert np.all(channels(b.eval(mi.BSDFContext(), lanes_si(wi, n, 1), vec(tile(wo, n)))) == 0.0)
        assert np.all(c.eval(tile(wi, n), tile(wo, n)) == 0.0)
    _, w, _ = engine_sample(b, mi.BSDFContext(), down, 9, n)
    assert np.all(w == 0.0)
    _, w_r, pdf_r = c.sample(tile(down, n), sample_uniforms(9, n))
    assert np.all(pdf_r == 0.0)


# ------------------------------------------------------------------ the bounce cap


@pytest.mark.parametrize("model", DIELECTRIC_MODELS)
def test_dielectric_bounce_cap_equals_core(model):
    """max_bounces = 2 (Importance mode, α = 1): eval keeps orders 1–2, sample invalidates longer paths."""
    b = dielectric_engine(model, 1.0, max_bounces=BOUNCE_CAP)
    c = dielectric_core(model, 1.0, False, max_bounces=BOUNCE_CAP)
    ctx = context(False)
    tag = "%s dielectric (≤%d)" % (model, BOUNCE_CAP)
    for i, (label, wi, wo) in enumerate(CAP_DIELECTRIC_PAIRS):
        e = channels(b.eval(ctx, lanes_si(wi, LANES, 700 + i + SEED_OFFSET), vec(tile(wo, LANES))))
        r = c.eval(tile(wi, LANES), tile(wo, LANES))
        z_check("%s %s eval" % (tag, label), stats(e[0]), stats(r[0]))
    mu = CAP_DIELECTRIC_MU
    wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
    wo_e, w_e, _ = engine_sample(b, ctx, wi, 710 + SEED_OFFSET)
    wo_r, w_r = core_sample(c, wi, 720 + SEED_OFFSET)
    z_check("%s μ=%+.2f albedo" % (tag, mu), stats(w_e[0]), stats(w_r[0]))
    z_check("%s μ=%+.2f E[w·ωo,z]" % (tag, mu), stats(w_e[0] * wo_e[2]), stats(w_r[0] * wo_r[2]))


@pytest.mark.parametrize("model", DIFFUSE_MODELS)
def test_diffuse_bounce_cap_equals_core(model):
    """max_bounces = 2 (α = 1): eval keeps orders 1–2, sample invalidates longer paths."""
    b = diffuse_engine(model, 1.0, max_bounces=BOUNCE_CAP)
    c = diffuse_core(model, 1.0, max_bounces=BOUNCE_CAP)
    tag = "%s diffuse (≤%d)" % (model, BOUNCE_CAP)
    wi, wo = DIFFUSE_PAIRS[0]
    e = channels(b.eval(mi.BSDFContext(), lanes_si(wi, LANES, 730 + SEED_OFFSET), vec(tile(wo, LANES))))
    r = c.eval(tile(wi, LANES), tile(wo, LANES))
    for ch in range(CHANNELS):
        z_check("%s eval ch%d" % (tag, ch), stats(e[ch]), stats(r[ch]))
    mu = DIFFUSE_INCIDENCES[0]
    wi = (math.sqrt(1.0 - mu * mu), 0.0, mu)
    _, w_e, _ = engine_sample(b, mi.BSDFContext(), wi, 740 + SEED_OFFSET)
    _, w_r = core_sample(c, wi, 750 + SEED_OFFSET)
    for ch in range(CHANNELS):
        z_check("%s μ=%.2f albedo ch%d" % (tag, mu, ch), stats(w_e[ch]), stats(w_r[ch]))
