"""The Dr.Jit engine (``msx/jit/``) against the Rust core and Mitsuba's built-ins, in ``llvm_ad_rgb``.

One truth (docs/engines.md): the core is the reference; the engine must equal it in distribution.
- ``single`` equals Mitsuba's ``roughconductor`` value for value (float32 rounding only).
- Every stochastic model: the mean of ``eval`` at fixed (ω_i, ω_o) pairs and the directional albedo (mean
  ``sample`` weight) equal the core's within their noise: z = Δ/√(σ₁² + σ₂²) against a threshold set by a
  Šidák-corrected family-wise false-alarm rate of 1e-3 over all comparisons of this file. σ is the larger
  of the plain standard error and the one from four independent replicates (a heavy-tailed estimator that
  missed its tail gets no small σ).
- ``sample`` against ``pdf``: the engine's sampled directions follow... no closed form for a walk; the
  walks' weights are checked through the albedo, the reported density through MIS-unbiased renders
  (the Fig. 9 image mean against the native scalar route).
- ``msx.register()`` leaves drjit's flags as they were, before and after a render.
``MSX_TEST_SEED_OFFSET`` reruns the statistical checks at other seeds (docs/testing.md).
"""

import math
import os
import statistics
import subprocess
import sys
import textwrap

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
from msx.core import CoreBsdf  # noqa: E402

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
LANES = 1 << 16
REPLICATES = 4

# Every statistical comparison of this file, for the Šidák correction: (models × α × pairs × channels) for
# eval, (models × α × incidences × channels) for the albedo.
WALK_MODELS = ("uncorrelated", "correlated", "auto")
ALPHAS = (0.3, 1.0)
PAIRS = [((0.3, 0.0, math.sqrt(1 - 0.09)), (-0.5, 0.2, math.sqrt(1 - 0.29))),
         ((0.8, 0.1, math.sqrt(1 - 0.65)), (0.1, -0.3, math.sqrt(1 - 0.10))),
         ((0.95, 0.0, math.sqrt(1 - 0.9025)), (-0.9, 0.0, math.sqrt(1 - 0.81)))]
INCIDENCES = (0.2, 0.6, 0.95)  # cos θ_i
COMPARISONS = (len(WALK_MODELS) * len(ALPHAS) * (len(PAIRS) + len(INCIDENCES)) * 3 + len(ALPHAS) * len(INCIDENCES)
               + len(WALK_MODELS) * (len(PAIRS) + 2) * 3 + 3 * 3)
FAMILY_RATE = 1e-3
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - FAMILY_RATE) ** (1 / COMPARISONS)) / 2)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():
        yield


def cu_rgb():
    """Mitsuba's RGB (η, k) of copper in this variant."""
    p = mi.traverse(mi.load_dict({"type": "roughconductor", "material": "Cu"}))
    return [float(x) for x in np.array(p["eta.value"]).ravel()], [float(x) for x in np.array(p["k.value"]).ravel()]


def stats(x):
    return jit_support.stats(x, REPLICATES)


def z_check(label, a, b):
    jit_support.z_check(label, a, b, Z_MAX)


def engine_bsdf(model, alpha, **extra):
    return mi.load_dict({"type": "msx_posfree", "material": "Cu", "distribution": "ggx", "alpha": alpha,
                         "model": model, **extra})


def core_bsdf(model, alpha, eta, k, seed):
    return CoreBsdf(surface="conductor", distribution="ggx", model=model, alpha=alpha, eta=eta, k=k,
                    channels=3, seed=seed)


def engine_eval(b, wi, wo, seed):
    si = lanes_si(wi, LANES, seed)
    wo_v = mi.Vector3f(*[mi.Float(np.full(LANES, c, np.float32)) for c in wo])
    v = b.eval(mi.BSDFContext(), si, wo_v)
    return np.array(v).reshape(LANES, 3).T if np.array(v).shape == (LANES, 3) else np.array(v)


def engine_sample(b, wi, seed):
    si = lanes_si(wi, LANES, seed)
    rng = np.random.default_rng(seed + 1)
    s1 = mi.Float(rng.random(LANES).astype(np.float32))
    s2 = mi.Point2f(*[mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(2)])
    bs, w = b.sample(mi.BSDFContext(), si, s1, s2)
    return np.array(w), np.array(bs.pdf), np.array(bs.wo)


def as_channels(a):
    a = np.asarray(a, np.float64)
    return a.T if a.shape[-1] == 3 and a.shape[0] != 3 else a


@pytest.mark.parametrize("model", WALK_MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_eval_means_equal_the_core(model, alpha):
    eta, k = cu_rgb()
    b = engine_bsdf(model, alpha)
    c = core_bsdf(model, alpha, eta, k, seed=SEED_OFFSET)
    for i, (wi, wo) in enumerate(PAIRS):
        seed = 1000 * i + 17 + SEED_OFFSET
        e = as_channels(engine_eval(b, wi, wo, seed))
        r = c.eval(np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1)))
        z_check("%s α %.1f pair %d eval" % (model, alpha, i), stats(e), stats(r))


@pytest.mark.parametrize("model", WALK_MODELS)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_albedo_equals_the_core(model, alpha):
    """The directional albedo (mean sample weight) of the engine's walk equals the core's."""
    eta, k = cu_rgb()
    b = engine_bsdf(model, alpha)
    c = core_bsdf(model, alpha, eta, k, seed=SEED_OFFSET)
    for mu in INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        w, pdf, wo = engine_sample(b, wi, 7 + SEED_OFFSET + int(100 * mu))
        w = as_channels(w)
        assert np.all(np.isfinite(w)) and np.all(w >= 0) and np.all(np.isfinite(pdf))
        rng = np.random.default_rng(99 + SEED_OFFSET + int(100 * mu))
        _, rw, _ = c.sample(np.tile(wi, (LANES, 1)), rng.random((3, LANES)))
        z_check("%s α %.1f μ %.2f albedo" % (model, alpha, mu), stats(w), stats(rw))


def test_beckmann_walk_equals_the_core():
    """The walks on Beckmann microsurfaces (full-sphere visible normals in float32, jit/beckmann.py): eval
    means and albedos of ``correlated`` equal the core's."""
    eta, k = cu_rgb()
    b = mi.load_dict({"type": "msx_posfree", "material": "Cu", "distribution": "beckmann", "alpha": 0.7,
                      "model": "correlated"})
    c = CoreBsdf(surface="conductor", distribution="beckmann", model="correlated", alpha=0.7, eta=eta, k=k,
                 channels=3, seed=SEED_OFFSET)
    for i, (wi, wo) in enumerate(PAIRS[:2]):
        e = as_channels(engine_eval(b, wi, wo, 600 + i + SEED_OFFSET))
        r = c.eval(np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1)))
        z_check("beckmann correlated pair %d eval" % i, stats(e), stats(r))
    mu = 0.4
    wi = (math.sqrt(1 - mu * mu), 0.0, mu)
    w, _, _ = engine_sample(b, wi, 700 + SEED_OFFSET)
    _, rw, _ = c.sample(np.tile(wi, (LANES, 1)), np.random.default_rng(701 + SEED_OFFSET).random((3, LANES)))
    z_check("beckmann correlated μ %.2f albedo" % mu, stats(as_channels(w)), stats(rw))


@pytest.mark.parametrize("alpha", ALPHAS)
def test_white_furnace(alpha):
    """material='none' (F = 1): the correlated walk conserves energy. ∫ eval dω_o over the hemisphere, by
    uniform directions (2π·mean), is 1 within noise — a check of the engine's eval by physics, independent
    of the core and of the sampler (whose weights are 1 by construction)."""
    b = mi.load_dict({"type": "msx_posfree", "distribution": "ggx", "alpha": alpha, "model": "correlated"})
    for mu in INCIDENCES:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        rng = np.random.default_rng(31 + SEED_OFFSET + int(100 * mu))
        z, phi = rng.random(LANES), rng.uniform(0, 2 * np.pi, LANES)
        r = np.sqrt(1 - z * z)
        wo = mi.Vector3f(mi.Float(r * np.cos(phi)), mi.Float(r * np.sin(phi)), mi.Float(z))
        v = np.array(b.eval(mi.BSDFContext(), lanes_si(wi, LANES, 77 + SEED_OFFSET), wo), np.float64)
        m, s = stats(2 * np.pi * as_channels(v)[:1])
        print("furnace α %.1f μ %.2f: albedo %.5f ± %.5f" % (alpha, mu, m[0], s[0]))
        assert abs(m[0] - 1.0) <= Z_MAX * s[0], (alpha, mu, m[0], s[0])


def test_single_equals_roughconductor():
    """model='single' is Mitsuba's roughconductor: eval, pdf and sample agree to float32 rounding."""
    rng = np.random.default_rng(5 + SEED_OFFSET)
    n = 4096
    for dist, alpha in (("ggx", 0.2), ("ggx", 0.9), ("beckmann", 0.4)):
        params = {"material": "Au", "distribution": dist, "alpha": alpha}
        ours = mi.load_dict({"type": "msx_posfree", "model": "single", **params})
        theirs = mi.load_dict({"type": "roughconductor", **params})
        z_i, z_o = rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
        phi_i, phi_o = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2 * np.pi, n)

        def vec(z, phi):
            r = np.sqrt(1 - z * z)
            return mi.Vector3f(mi.Float(r * np.cos(phi)), mi.Float(r * np.sin(phi)), mi.Float(z))

        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = vec(z_i, phi_i)
        wo = vec(z_o, phi_o)
        ctx = mi.BSDFContext()
        for a, b in ((ours.eval(ctx, si, wo), theirs.eval(ctx, si, wo)),
                     (ours.pdf(ctx, si, wo), theirs.pdf(ctx, si, wo))):
            a, b = np.array(a, np.float64), np.array(b, np.float64)
            assert np.allclose(a, b, rtol=2e-4, atol=1e-6), (dist, alpha, np.abs(a - b).max())
        s1 = mi.Float(rng.random(n).astype(np.float32))
        s2 = mi.Point2f(mi.Float(rng.random(n).astype(np.float32)), mi.Float(rng.random(n).astype(np.float32)))
        (bo, wo_), (bt, wt) = ours.sample(ctx, si, s1, s2), theirs.sample(ctx, si, s1, s2)
        # Mitsuba keeps a density for a direction below the horizon with weight 0; the engine, like the
        # core, reports such a sample as invalid.
        ok = (np.array(bt.pdf) > 0) & (np.array(bt.wo)[2] > 0)
        assert np.array_equal(ok, np.array(bo.pdf) > 0)
        assert np.allclose(np.array(bo.wo)[:, ok], np.array(bt.wo)[:, ok], atol=1e-5)
        assert np.allclose(np.array(bo.pdf)[ok], np.array(bt.pdf)[ok], rtol=2e-4, atol=1e-6)
        assert np.allclose(np.array(wo_)[:, ok], np.array(wt)[:, ok], rtol=2e-4, atol=1e-6)


@pytest.mark.parametrize("model", ("fastmsx", "compensated"))
@pytest.mark.parametrize("alpha", (0.1, 0.5, 1.2))
def test_analytic_models_equal_the_core(model, alpha):
    """The deterministic conductor models: eval, pdf and the sample weight per lane equal the core's (float32
    against float64, and the tables interpolated in float32)."""
    eta, k = cu_rgb()
    b = engine_bsdf(model, alpha)
    c = core_bsdf(model, alpha, eta, k, seed=0)
    rng = np.random.default_rng(11)
    n = 4096
    z_i, z_o = rng.uniform(0.05, 1, n), rng.uniform(0.05, 1, n)
    phi = rng.uniform(0, 2 * np.pi, (2, n))
    wi = np.stack([np.sqrt(1 - z_i ** 2) * np.cos(phi[0]), np.sqrt(1 - z_i ** 2) * np.sin(phi[0]), z_i], 1)
    wo = np.stack([np.sqrt(1 - z_o ** 2) * np.cos(phi[1]), np.sqrt(1 - z_o ** 2) * np.sin(phi[1]), z_o], 1)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(wi[:, i].astype(np.float32)) for i in range(3)])
    wo_v = mi.Vector3f(*[mi.Float(wo[:, i].astype(np.float32)) for i in range(3)])
    ctx = mi.BSDFContext()
    v, p = b.eval_pdf(ctx, si, wo_v)
    v, p = np.array(v, np.float64), np.array(p, np.float64)
    rv, rp = c.eval(wi.astype(np.float32), wo.astype(np.float32)), c.pdf(wi.astype(np.float32), wo.astype(np.float32))
    assert np.allclose(v, rv, rtol=2e-3, atol=1e-5), np.abs(v - rv).max()
    assert np.allclose(p, rp, rtol=2e-3, atol=1e-5), np.abs(p - rp).max()
    u = rng.random((3, n)).astype(np.float32)
    bs, w = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
    rwo, rw, rpdf = c.sample(wi.astype(np.float32), u)
    e_ok, r_ok = np.array(bs.pdf) > 0, rpdf > 0
    # The same samples are valid, but for directions within float32 rounding of the horizon.
    disagree = e_ok != r_ok
    assert np.all(np.abs(rwo[disagree, 2]) < 1e-4), rwo[disagree][:5]
    ok = e_ok & r_ok
    assert np.allclose(np.array(w, np.float64)[:, ok], rw[:, ok], rtol=2e-3, atol=1e-4)


@pytest.mark.parametrize("alpha", (0.1, 0.6))
@pytest.mark.parametrize("mode", ("radiance", "importance"))
def test_compensated_dielectric_equals_the_core(alpha, mode):
    """Energy compensation on a dielectric (the core's E_r + E_t tables as textures): the compensation
    factor, compensated/single per lane, equals the core's, from both sides, reflection and transmission.
    (The single-scattering lobe itself equals Mitsuba's roughdielectric: test_jit_dielectric.py. Against
    the float64 core its far tails differ by float32 conditioning — up to 10 % at α = 0.1 where
    m = normalize(ω_i + η ω_o) nearly cancels — so the factor is what is compared here.)"""
    params = {"type": "msx_posfree", "surface": "dielectric", "distribution": "ggx", "alpha": alpha, "int_ior": 1.5}
    rng = np.random.default_rng(21)
    n = 4096
    wi, wo = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    wo /= np.linalg.norm(wo, axis=1)[:, None]
    keep = (np.abs(wi[:, 2]) > 0.05) & (np.abs(wo[:, 2]) > 0.05)
    wi, wo = wi[keep].astype(np.float32), wo[keep].astype(np.float32)
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(*[mi.Float(wi[:, i]) for i in range(3)])
    wo_v = mi.Vector3f(*[mi.Float(wo[:, i]) for i in range(3)])
    ctx = mi.BSDFContext(mi.TransportMode.Radiance if mode == "radiance" else mi.TransportMode.Importance)
    values = {}
    for model in ("single", "compensated"):
        v, p = mi.load_dict({**params, "model": model}).eval_pdf(ctx, si, wo_v)
        c = CoreBsdf(surface="dielectric", distribution="ggx", model=model, alpha=alpha, ior=1.5, channels=3,
                     radiance=mode == "radiance")
        values[model] = (np.array(v, np.float64)[0], np.array(p, np.float64), c.eval(wi, wo)[0])
    (s_v, s_p, s_r), (c_v, c_p, c_r) = values["single"], values["compensated"]
    ok = (s_v > 1e-6) & (s_r > 1e-6)
    assert ok.mean() > 0.3
    factor, core_factor = c_v[ok] / s_v[ok], c_r[ok] / s_r[ok]
    assert np.all(factor >= 1.0 - 1e-6)
    assert np.allclose(factor, core_factor, rtol=2e-3), np.abs(factor / core_factor - 1).max()
    assert np.array_equal(c_p, s_p)  # compensation samples with single's sampler and density


@pytest.mark.parametrize("model", WALK_MODELS)
def test_diffuse_microsurface_equals_the_core(model):
    """Position-free walks on Lambertian facets: eval means and albedos equal the core's; with albedo 1 the
    walk conserves energy (sample weights are Π albedo: the albedo is the fraction of valid samples)."""
    refl = [0.8, 0.5, 0.2]
    b = mi.load_dict({"type": "msx_posfree", "surface": "diffuse", "distribution": "ggx", "alpha": 0.8,
                      "model": model, "reflectance": {"type": "rgb", "value": refl}})
    c = CoreBsdf(surface="diffuse", distribution="ggx", model=model, alpha=0.8, reflectance=refl, channels=3,
                 seed=SEED_OFFSET)
    for i, (wi, wo) in enumerate(PAIRS):
        e = as_channels(engine_eval(b, wi, wo, 300 + i + SEED_OFFSET))
        r = c.eval(np.tile(wi, (LANES, 1)), np.tile(wo, (LANES, 1)))
        z_check("diffuse %s pair %d eval" % (model, i), stats(e), stats(r))
    for mu in INCIDENCES[:2]:
        wi = (math.sqrt(1 - mu * mu), 0.0, mu)
        w, _, _ = engine_sample(b, wi, 400 + SEED_OFFSET + int(100 * mu))
        rng = np.random.default_rng(500 + SEED_OFFSET + int(100 * mu))
        _, rw, _ = c.sample(np.tile(wi, (LANES, 1)), rng.random((3, LANES)))
        z_check("diffuse %s μ %.2f albedo" % (model, mu), stats(as_channels(w)), stats(rw))


def test_auto_runs_order_one_where_the_core_does():
    """``auto`` on a smooth conductor: the core's rule says order 1 suffices, so both engines evaluate the
    deterministic order 1 (every lane the same value) and agree to float32 rounding."""
    eta, k = cu_rgb()
    alpha = 0.03
    b = engine_bsdf("auto", alpha)
    c = core_bsdf("auto", alpha, eta, k, seed=0)
    wi = (0.5, 0.0, math.sqrt(0.75))
    wo = (-0.49, 0.01, math.sqrt(1 - 0.49 ** 2 - 0.01 ** 2))
    e = as_channels(engine_eval(b, wi, wo, 5))
    r = c.eval(np.tile(wi, (64, 1)), np.tile(wo, (64, 1)))
    assert np.all(e.std(axis=1) == 0) and np.all(r.std(axis=1) == 0), (e.std(axis=1), r.std(axis=1))
    assert np.allclose(e[:, 0], r[:, 0], rtol=2e-3), (e[:, 0], r[:, 0])
    # At α = 0.8 the full walk runs: the estimates vary between lanes.
    assert np.all(as_channels(engine_eval(engine_bsdf("auto", 0.8), wi, wo, 5)).std(axis=1) > 0)


def test_reproducible_streams():
    """The same inputs give the same estimate whatever the lane order (each lane's stream is hashed from
    its own inputs and the seed); another seed gives other estimates."""
    b = engine_bsdf("correlated", 0.6)
    wi, wo = PAIRS[0]
    n = 2048
    si = lanes_si(wi, n, 3)
    wo_v = mi.Vector3f(*[mi.Float(np.full(n, c, np.float32)) for c in wo])
    v1 = np.array(b.eval(mi.BSDFContext(), si, wo_v))
    perm = np.random.default_rng(4).permutation(n)
    si2 = dr.zeros(mi.SurfaceInteraction3f, n)
    si2.wi = si.wi
    si2.p = mi.Point3f(*[mi.Float(np.array(si.p[i])[perm]) for i in range(3)])
    si2.uv = mi.Point2f(*[mi.Float(np.array(si.uv[i])[perm]) for i in range(2)])
    v2 = np.array(b.eval(mi.BSDFContext(), si2, wo_v))
    assert np.array_equal(np.asarray(v1)[:, perm], np.asarray(v2))
    v3 = np.array(engine_bsdf("correlated", 0.6, seed=7).eval(mi.BSDFContext(), si, wo_v))
    assert not np.array_equal(v1, v3)


def test_bad_parameter_same_message_as_scalar():
    """A bad parameter gives the same one-line message in llvm_ad_rgb (engine) as in scalar_rgb."""
    bad = {"type": "msx_posfree", "alpha": 0.3, "model": "corelated"}
    messages = []
    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        mi.set_variant(variant)
        msx.register(backend="jit" if variant.startswith("llvm") else None)
        with pytest.raises(Exception) as e:
            mi.load_dict(bad)
        messages.append([ln for ln in str(e.value).splitlines() if "msx_posfree:" in ln][-1].strip())
    mi.set_variant("llvm_ad_rgb")
    assert messages[0] == messages[1] and "corelated" in messages[0], messages


def test_models_outside_the_engine_are_named():
    """A model the engine does not run yet is refused at load with the parameter, the models it runs and
    the alternatives."""
    with pytest.raises(Exception, match="estimator='bdpt' on surface 'diffuse'.*backend='batched'"):
        mi.load_dict({"type": "msx_posfree", "surface": "diffuse", "alpha": 0.3, "model": "correlated",
                      "estimator": "bdpt"})


def test_local_array_walks_are_refused_in_scenes(monkeypatch):
    """The invariance walks keep per-path arrays (dr.alloc_local), which drjit 1.5's LLVM backend cannot
    compile inside Mitsuba's BSDF calls (it aborts the process): a scene asking for one is refused at load
    with a message, instead of a crash at render time."""
    import msx.jit.bsdf

    monkeypatch.setattr(msx.jit.bsdf, "ALLOW_LOCAL_ARRAYS", False)
    with pytest.raises(Exception, match="model='invariance' on surface 'diffuse'.*alloc_local.*scalar_rgb"):
        mi.load_dict({"type": "msx_posfree", "surface": "diffuse", "alpha": 0.3, "model": "invariance"})


# A fresh process: the flags a user had stay untouched; a built-in scene renders in the same mode.
_FLAGS_SCRIPT = textwrap.dedent("""
    import drjit as dr, mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import msx
    before = (dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls))
    msx.register()
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 16, "height": 16},
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])},
        "s": {"type": "sphere", "bsdf": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx",
                                         "alpha": 0.5, "model": "correlated"}},
        "e": {"type": "constant"}})
    img = mi.render(scene, spp=8)
    after = (dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls))
    import numpy as np
    print(before, after, float(np.array(img).mean()), msx.backend())
""")


def test_register_leaves_drjit_flags_alone():
    r = subprocess.run([sys.executable, "-c", _FLAGS_SCRIPT], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    out = r.stdout.strip()
    assert out.startswith("(True, True) (True, True) "), out
    mean, backend = out.split()[-2:]
    assert float(mean) > 0 and backend == "jit", out
