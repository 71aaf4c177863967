"""The Dr.Jit engine's dielectric walks (msx/jit/posfree_dielectric.py) against the Rust core and Mitsuba's
``roughdielectric``, in ``llvm_ad_rgb``.

One truth (docs/engines.md): the core is the reference; the engine must equal it in distribution.
- The walks (``uncorrelated``, ``correlated``): the mean of ``eval`` at fixed (ω_i, ω_o) pairs, ω_i outside
  and inside, reflection and transmission, Radiance and Importance mode; the directional albedo (mean
  ``sample`` weight) and the first moment E[w·ω_o,z] of the sampled direction at incidences from both sides
  (the moment separates reflection from transmission, which the Importance-mode weights, all 1, do not).
  Each comparison is z = Δ/√(σ₁² + σ₂²) against a threshold set by a Šidák-corrected family-wise
  false-alarm rate of 1e-3 over all comparisons of this file. σ of a mean is the larger of the plain
  standard error and the one from four independent replicates (the walks' estimates are heavy-tailed; a
  sample that missed its tail gets no small σ).
- A white furnace: a dielectric conserves energy, so in Importance mode ∫ f·|cos θ_o| dω_o over the whole
  sphere, by uniform directions (4π·mean), is 1 within noise (up to the bounce cap's loss, far below it) —
  a check of the engine's eval by physics, independent of the core.
- Anisotropic GGX (both segment models) and anisotropic Beckmann (correlated), Radiance mode: eval means
  and the albedo and three first moments of the samples against the core.
- ``ln_l_beta`` (the correlated refraction factors, float32 without lgamma) against mpmath.
- ``single`` equals Mitsuba's ``roughdielectric`` value for value (float32 rounding only).
The materials are untinted, so the three channels are one value: channel 0 is compared.
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
from msx.core import CoreBsdf  # noqa: E402

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
LANES = 1 << 16
FURNACE_LANES = 1 << 20
REPLICATES = 4
IOR = 1.5


def _dir(theta, phi):
    return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))


WALK_MODELS = ("uncorrelated", "correlated")
ALPHAS = (0.3, 1.0)
RADIANCE = (True, False)  # Mitsuba's transport mode: Radiance, Importance
# (label, ω_i, ω_o): reflection and transmission from outside (the transmission near the refracted peak),
# from inside beyond the critical angle (asin(1/1.5) ≈ 0.73 rad: total internal reflection at the macro
# normal) and a transmission out of the material.
PAIRS = (("outside R", _dir(0.5, 0.0), _dir(1.0, math.pi)),
         ("outside T", _dir(0.5, 0.0), _dir(math.pi - 0.4, math.pi)),
         ("inside R (TIR)", _dir(math.pi - 0.9, 0.0), _dir(math.pi - 0.8, math.pi + 0.3)),
         ("inside T", _dir(math.pi - 0.3, 0.0), _dir(0.8, math.pi)))
INCIDENCES = (0.9, 0.3, -0.9, -0.3)  # cos θ_i of the sampled albedo: both sides
FURNACE_INCIDENCES = (0.6, -0.6)

# Other microsurfaces (Radiance mode): anisotropic roughness (the inside frame is the point reflection, under
# which D(−m) = D(m) holds for anisotropic α too) with both segment models, and Beckmann (its float32 Λ and
# visible normals, jit/beckmann.py, in a refracting walk) with the correlated one: eval at the PAIRS plus a
# pair off the plane of incidence, and the albedo and three first moments of the sampled ω_o at two incidences.
OTHER_SURFACES = (("uncorrelated", "ggx", 0.2, 0.8), ("correlated", "ggx", 0.2, 0.8),
                  ("correlated", "beckmann", 0.9, 0.3))
OFF_PLANE_PAIR = ("off-plane T", _dir(1.0, 0.4), _dir(math.pi - 0.6, 0.4 + math.pi + 0.6))
OTHER_INCIDENCES = (0.7, -0.7)

COMPARISONS = (len(WALK_MODELS) * len(ALPHAS) * len(RADIANCE) * (len(PAIRS) + 2 * len(INCIDENCES))
               + len(WALK_MODELS) * len(ALPHAS) * len(FURNACE_INCIDENCES)
               + len(OTHER_SURFACES) * (len(PAIRS) + 1 + 4 * len(OTHER_INCIDENCES)))
FAMILY_RATE = 1e-3
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - FAMILY_RATE) ** (1 / COMPARISONS)) / 2)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():  # backend="jit", not whatever route an earlier module registered
        yield


def context(radiance):
    return mi.BSDFContext(mi.TransportMode.Radiance if radiance else mi.TransportMode.Importance)


def engine_bsdf(model, alpha):
    # ext_ior = 1 (Mitsuba's default is air, 1.000277): the relative IOR is the core's ``ior``.
    return mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "distribution": "ggx", "alpha": alpha,
                         "int_ior": IOR, "ext_ior": 1.0, "model": model})


def core_bsdf(model, alpha, radiance):
    # Another seed per mode: the two modes' estimates are independent samples, not one rescaled.
    return CoreBsdf(surface="dielectric", distribution="ggx", model=model, alpha=alpha, ior=IOR, channels=3,
                    radiance=radiance, seed=SEED_OFFSET + (0 if radiance else 1000))


def vec(a):
    """A (n, 3) or (3,)-per-lane float array as mi.Vector3f."""
    return mi.Vector3f(*[mi.Float(np.ascontiguousarray(a[..., c], np.float32)) for c in range(3)])


def channel0(v):
    """Channel 0 of a Mitsuba spectrum over lanes (drjit gives (3, n))."""
    return np.asarray(v, np.float64)[0]


def stats(x):
    return jit_support.stats(x, REPLICATES)


def z_check(label, a, b):
    jit_support.z_check(label, a, b, Z_MAX)


@pytest.mark.parametrize("radiance", RADIANCE, ids=("radiance", "importance"))
@pytest.mark.parametrize("model", WALK_MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_eval_means_equal_the_core(model, alpha, radiance):
    b = engine_bsdf(model, alpha)
    c = core_bsdf(model, alpha, radiance)
    ctx = context(radiance)
    for i, (label, wi, wo) in enumerate(PAIRS):
        seed = 1000 * i + 17 + SEED_OFFSET + (0 if radiance else 500)
        e = channel0(b.eval(ctx, lanes_si(wi, LANES, seed), vec(np.tile(wo, (LANES, 1)))))
        r = c.eval(np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1)))[0]
        assert np.all(np.isfinite(e)) and np.all(e >= 0), label
        z_check("%s α %.1f %s %s eval" % (model, alpha, "radiance" if radiance else "importance", label),
                stats(e), stats(r))


@pytest.mark.parametrize("radiance", RADIANCE, ids=("radiance", "importance"))
@pytest.mark.parametrize("model", WALK_MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_sampled_albedo_equals_the_core(model, alpha, radiance):
    """The directional albedo (mean sample weight) and E[w·ω_o,z] of the engine's walk equal the core's."""
    b = engine_bsdf(model, alpha)
    c = core_bsdf(model, alpha, radiance)
    ctx = context(radiance)
    mode = "radiance" if radiance else "importance"
    for mu in INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        seed = 7 + SEED_OFFSET + int(100 * (mu + 1)) + (0 if radiance else 5000)
        rng = np.random.default_rng(seed + 1)
        s1 = mi.Float(rng.random(LANES).astype(np.float32))
        s2 = mi.Point2f(*[mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(2)])
        bs, w = b.sample(ctx, lanes_si(wi, LANES, seed), s1, s2)
        w, pdf, wo = channel0(w), np.asarray(bs.pdf, np.float64), np.asarray(bs.wo, np.float64)
        assert np.all(np.isfinite(w)) and np.all(w >= 0) and np.all(np.isfinite(pdf))
        assert np.all(pdf[w > 0] > 0)
        rng = np.random.default_rng(99 + SEED_OFFSET + int(100 * (mu + 1)) + (0 if radiance else 5000))
        rwo, rw, rpdf = c.sample(np.tile(wi, (LANES, 1)), rng.random((3, LANES)))
        rw = np.where(rpdf > 0, rw[0], 0.0)
        label = "%s α %.1f %s μ %+.2f" % (model, alpha, mode, mu)
        z_check(label + " albedo", stats(w), stats(rw))
        z_check(label + " E[w·ωo.z]", stats(w * wo[2]), stats(rw * np.where(rpdf > 0, rwo[:, 2], 0.0)))


@pytest.mark.parametrize("model", WALK_MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_white_furnace(model, alpha):
    """Importance mode: ∫ f·|cos θ_o| dω_o over the sphere (4π·mean over uniform directions) is 1."""
    b = engine_bsdf(model, alpha)
    ctx = context(False)
    n = FURNACE_LANES
    for mu in FURNACE_INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        rng = np.random.default_rng(31 + SEED_OFFSET + int(100 * (mu + 1)))
        z, phi = rng.uniform(-1.0, 1.0, n), rng.uniform(0.0, 2.0 * np.pi, n)
        r = np.sqrt(1 - z * z)
        wo = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        v = 4.0 * np.pi * channel0(b.eval(ctx, lanes_si(wi, n, 77 + SEED_OFFSET), vec(wo)))
        m, s = stats(v)
        print("furnace %s α %.1f μ %+.2f: albedo %.5f ± %.5f z %+.2f" % (model, alpha, mu, m, s, (m - 1) / s))
        assert abs(m - 1.0) <= Z_MAX * s, (model, alpha, mu, m, s)


@pytest.mark.parametrize("model,dist,alpha_u,alpha_v", OTHER_SURFACES)
def test_other_microsurfaces_equal_the_core(model, dist, alpha_u, alpha_v):
    """Beckmann and anisotropic GGX (Radiance mode): eval means, the albedo and E[w·ω_o] of the samples."""
    params = {"type": "msx_posfree", "surface": "dielectric", "distribution": dist, "int_ior": IOR,
              "ext_ior": 1.0, "model": model}
    if alpha_u == alpha_v:
        params["alpha"] = alpha_u
    else:
        params["alpha_u"], params["alpha_v"] = alpha_u, alpha_v
    b = mi.load_dict(params)
    c = CoreBsdf(surface="dielectric", distribution=dist, model=model, alpha=alpha_u, alpha_v=alpha_v, ior=IOR,
                 channels=3, seed=SEED_OFFSET + 2000)
    ctx = context(True)
    name = "%s %s α (%.1f, %.1f)" % (model, dist, alpha_u, alpha_v)
    for i, (label, wi, wo) in enumerate(PAIRS + (OFF_PLANE_PAIR,)):
        e = channel0(b.eval(ctx, lanes_si(wi, LANES, 3000 + 10 * i + SEED_OFFSET), vec(np.tile(wo, (LANES, 1)))))
        r = c.eval(np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1)))[0]
        z_check("%s %s eval" % (name, label), stats(e), stats(r))
    for mu in OTHER_INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        seed = 4000 + SEED_OFFSET + int(100 * (mu + 1))
        rng = np.random.default_rng(seed)
        s1 = mi.Float(rng.random(LANES).astype(np.float32))
        s2 = mi.Point2f(*[mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(2)])
        bs, w = b.sample(ctx, lanes_si(wi, LANES, seed), s1, s2)
        w, wo = channel0(w), np.asarray(bs.wo, np.float64)
        rwo, rw, rpdf = c.sample(np.tile(wi, (LANES, 1)), np.random.default_rng(seed + 1).random((3, LANES)))
        ok = rpdf > 0
        rw, rwo = np.where(ok, rw[0], 0.0), np.where(ok[:, None], rwo, 0.0).T
        z_check("%s μ %+.2f albedo" % (name, mu), stats(w), stats(rw))
        for k, axis in enumerate("xyz"):
            z_check("%s μ %+.2f E[w·ωo.%s]" % (name, mu, axis), stats(w * wo[k]), stats(rw * rwo[k]))


def test_ln_l_beta_in_float32():
    """ln(L·B(L, 1+Λ)) = ln Γ(L+1) + ln Γ(Λ+1) − ln Γ(L+Λ+1), which the correlated walk's refraction factors
    c = 1 − L·B(L, 1+Λ) and L·B(L, 1+Λ_o)/L rest on, is written in float32 without cancellation (the core
    takes it from three ln Γ in float64, which cancel for Λ → 0). Against mpmath on a log grid
    L, Λ ∈ [1e-7, 1e7]: relative error of the value and of c at most 1e-5 (≈ 170 float32 ulps: about 30
    operations on terms up to a few times the result; measured ≈ 7e-7). The edges are the core's: 0 when L
    or Λ is 0, −∞ when one is infinite, and L·B ≤ 1."""
    mpmath = pytest.importorskip("mpmath")
    from msx.jit import special

    mpmath.mp.dps = 30
    grid = np.float32(10.0) ** np.linspace(-7, 7, 43, dtype=np.float32)
    ll, lam = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    got = np.asarray(special.ln_l_beta(mi.Float(ll), mi.Float(lam)), np.float64)
    c = -np.asarray(special.expm1_ratio(mi.Float(got.astype(np.float32))), np.float64)

    def ref(a, b):
        a, b = mpmath.mpf(float(a)), mpmath.mpf(float(b))
        return float(mpmath.loggamma(a + 1) + mpmath.loggamma(b + 1) - mpmath.loggamma(a + b + 1))

    want = np.array([ref(a, b) for a, b in zip(ll, lam)])
    assert np.all(np.abs(got - want) <= 1e-5 * np.abs(want)), np.max(np.abs(got - want) / np.abs(want))
    c_want = -np.expm1(want)
    assert np.all(np.abs(c - c_want) <= 1e-5 * c_want), np.max(np.abs(c - c_want) / c_want)
    edge = np.asarray(special.ln_l_beta(mi.Float([0.0, 2.0, np.inf, 3.0]), mi.Float([2.0, 0.0, 1.0, np.inf])))
    assert edge[0] == 0.0 and edge[1] == 0.0 and edge[2] == -np.inf and edge[3] == -np.inf
    lb = np.asarray(special.l_beta(mi.Float(ll), mi.Float(lam)))
    assert np.all((lb >= 0.0) & (lb <= 1.0))


def test_ln_l_beta_per_packet_forms_same_bits():
    """``ln_l_beta(branch=True)`` (each form only in packets with lanes of it, docs/engines.md) gives the
    bits of the plain form, inside a symbolic loop as the walks call it: on the grid of
    ``test_ln_l_beta_in_float32`` (series and Stirling lanes mixed in packets), in packets of one form only
    (sorted), and at the edges (0, ∞)."""
    from msx.jit import special

    grid = np.float32(10.0) ** np.linspace(-7, 7, 43, dtype=np.float32)
    ll, lam = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    order = np.argsort(ll + lam, kind="stable")
    ll = np.concatenate([ll, ll[order], [0.0, 2.0, np.inf, 3.0, 0.1]]).astype(np.float32)
    lam = np.concatenate([lam, lam[order], [2.0, 0.0, 1.0, np.inf, 0.2]]).astype(np.float32)

    def in_loop(branch):
        def body(i, a, b, out):
            return i + 1, a, b, special.ln_l_beta(a, b, branch)

        state = (mi.UInt32(0), mi.Float(ll), mi.Float(lam), dr.zeros(mi.Float, len(ll)))
        return np.asarray(dr.while_loop(state, lambda i, a, b, out: i < 1, body)[3])

    plain, branched = in_loop(False), in_loop(True)
    assert np.array_equal(plain, branched, equal_nan=True)
    assert np.array_equal(branched, np.asarray(special.ln_l_beta(mi.Float(ll), mi.Float(lam))), equal_nan=True)


def test_single_equals_roughdielectric():
    """model='single' is Mitsuba's roughdielectric: eval, pdf and sample agree to float32 rounding, in both
    transport modes, for ω_i and ω_o on the whole sphere."""
    rng = np.random.default_rng(5 + SEED_OFFSET)
    n = 1 << 14

    def unit(count):
        z, phi = rng.uniform(-1.0, 1.0, count), rng.uniform(0.0, 2.0 * np.pi, count)
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)

    def close(a, b):
        return np.allclose(np.asarray(a, np.float64), np.asarray(b, np.float64), rtol=2e-4, atol=1e-6)

    for dist, alpha in (("ggx", 0.2), ("ggx", 0.9), ("beckmann", 0.4)):
        params = {"distribution": dist, "alpha": alpha, "int_ior": IOR}
        ours = mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "model": "single", **params})
        theirs = mi.load_dict({"type": "roughdielectric", **params})
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = vec(unit(n))
        wo = vec(unit(n))
        for radiance in RADIANCE:
            ctx = context(radiance)
            assert close(ours.eval(ctx, si, wo), theirs.eval(ctx, si, wo)), (dist, alpha, radiance, "eval")
            assert close(ours.pdf(ctx, si, wo), theirs.pdf(ctx, si, wo)), (dist, alpha, radiance, "pdf")
            s1 = mi.Float(rng.random(n).astype(np.float32))
            s2 = mi.Point2f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(2)])
            (bo, w_o), (bt, w_t) = ours.sample(ctx, si, s1, s2), theirs.sample(ctx, si, s1, s2)
            ok = np.asarray(bt.pdf) > 0
            assert np.array_equal(ok, np.asarray(bo.pdf) > 0), (dist, alpha, radiance)
            assert np.allclose(np.asarray(bo.wo)[:, ok], np.asarray(bt.wo)[:, ok], atol=1e-5)
            assert close(np.asarray(bo.pdf)[ok], np.asarray(bt.pdf)[ok]), (dist, alpha, radiance, "sample pdf")
            assert close(np.asarray(w_o)[:, ok], np.asarray(w_t)[:, ok]), (dist, alpha, radiance, "weight")
            # The lobe and η of the sample: Mitsuba labels a sample by the branch it chose, the engine by
            # the side ω_o ends on; they differ only where ω_o left the facet's side (weight 0 in both).
            live = ok & (np.asarray(w_t)[0] > 0)
            assert np.array_equal(np.asarray(bo.sampled_type)[live], np.asarray(bt.sampled_type)[live])
            assert close(np.asarray(bo.eta)[live], np.asarray(bt.eta)[live])
