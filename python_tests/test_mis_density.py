"""``mis_density`` (src/models/mis.rs, jit/mis.py): the conductor walks' MIS density, in llvm_ad_rgb.

- The Dr.Jit engine's density equals the Rust core's lane by lane for every conductor walk, every density and
  α from 0.02 to 1.5, grazing directions included (float32 against float64: 2e-3 relative, as the other
  deterministic comparisons in test_jit_engine.py).
- The parameter: a bad value is one line naming the allowed values; where it changes nothing (another surface,
  an analytic model) it is refused with one line.
- Render level: the density changes the noise, never the expected image. The same scene rendered with
  ``single_cosine`` and with ``cui`` from independent seeds has the same image mean within its Monte Carlo
  error: Welch's t of the two sets of per-render means against a two-sided false-alarm rate of 1e-3. A
  control renders with a BSDF whose ``sample`` reports ``cui`` while ``eval_pdf`` reports ``single_cosine``
  (MIS weights that no longer sum to 1) and asserts that the same statistic rejects it, so the test can fail.
"""

import math
import os

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
from msx.core import CoreBsdf  # noqa: E402

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
WALKS = ("uncorrelated", "correlated", "heitz", "invariance")
DENSITIES = ("single_cosine", "cui", "cui_typo")
FALSE_ALARM = 1e-3


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():
        yield


def directions(rng, n, lo=1e-3):
    z = np.concatenate([rng.uniform(lo, 1.0, n - 64), np.geomspace(lo, 0.05, 64)])
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], 1)


@pytest.mark.parametrize("model", WALKS)
@pytest.mark.parametrize("density", DENSITIES)
def test_engine_density_equals_the_core(model, density):
    """eval_pdf's and sample's density of the engine equal the core's ``pdf`` lane by lane."""
    rng = np.random.default_rng(5)
    n = 4096
    for dist, alpha_u, alpha_v in (("ggx", 0.02, 0.02), ("ggx", 0.5, 0.5), ("ggx", 1.5, 1.5), ("beckmann", 0.3, 0.9)):
        b = mi.load_dict({"type": "msx_posfree", "distribution": dist, "alpha_u": alpha_u, "alpha_v": alpha_v,
                          "model": model, "mis_density": density})
        c = CoreBsdf(surface="conductor", distribution=dist, model=model, alpha=alpha_u, alpha_v=alpha_v,
                     channels=3, mis_density=density)
        wi, wo = directions(rng, n).astype(np.float32), directions(rng, n).astype(np.float32)
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.wi = mi.Vector3f(*[mi.Float(wi[:, i]) for i in range(3)])
        wo_v = mi.Vector3f(*[mi.Float(wo[:, i]) for i in range(3)])
        ctx = mi.BSDFContext()
        p = np.array(b.pdf(ctx, si, wo_v), np.float64)
        rp = c.pdf(wi, wo)
        assert np.all(np.isfinite(p)) and np.all(p > 0), (dist, alpha_u, p.min())
        assert np.allclose(p, rp, rtol=2e-3, atol=1e-6), (dist, alpha_u, np.abs(p / rp - 1).max())
        # sample reports the same function at the direction it drew.
        u = rng.random((3, n)).astype(np.float32)
        bs, _ = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
        ok = np.array(bs.wo)[2] > 1e-3
        again = np.array(b.pdf(ctx, si, bs.wo), np.float64)
        assert np.allclose(np.array(bs.pdf)[ok], again[ok], rtol=1e-5), (dist, alpha_u)


def test_bad_value_names_the_allowed_values():
    with pytest.raises(Exception) as e:
        mi.load_dict({"type": "msx_posfree", "mis_density": "lambert"})
    line = str(e.value).strip().splitlines()[-1]
    assert "mis_density" in line and "single_cosine, cui, cui_typo" in line, line


@pytest.mark.parametrize("extra", ({"surface": "dielectric"}, {"surface": "diffuse"}, {"model": "single"},
                                   {"model": "compensated"}))
def test_refused_where_it_changes_nothing(extra):
    with pytest.raises(Exception) as e:
        mi.load_dict({"type": "msx_posfree", "mis_density": "cui", **extra})
    line = str(e.value).strip().splitlines()[-1]
    assert "mis_density" in line and "conductor walks only" in line, line


def test_core_refuses_unknown_value():
    with pytest.raises(msx.core.CoreError):
        CoreBsdf(mis_density="lambert")


# ------------------------------------------------------------------------------------------ render level

RES, SPP, RENDERS = 24, 32, 16


def scene_dict(density):
    """A rough copper sphere (correlated, GGX α = 0.8) under a constant environment and a small area light,
    path tracing with 5 bounces: MIS weighs both emitters."""
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": SPP},
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"}}},
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": 0.3}},
        "light": {"type": "rectangle",
                  "to_world": mi.ScalarTransform4f().look_at(origin=[2, 2, 2], target=[0, 0, 0], up=[0, 1, 0])
                  @ mi.ScalarTransform4f().scale([0.15, 0.15, 1]),
                  "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 60.0}}},
        "sphere": {"type": "sphere", "bsdf": {"type": "msx_posfree", "material": "Cu", "distribution": "ggx",
                                              "alpha": 0.8, "model": "correlated", "mis_density": density}},
    }


def image_means(density, first_seed):
    scene = mi.load_dict(scene_dict(density))
    return np.array([float(np.mean(np.array(mi.render(scene, seed=first_seed + k)))) for k in range(RENDERS)])


def welch_t(a, b):
    """(t, degrees of freedom) of the difference of two sample means."""
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    t = (a.mean() - b.mean()) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return t, df


def t_quantile(p, df):
    """The p-quantile of Student's t with ``df`` degrees of freedom: the Cornish-Fisher expansion in 1/df
    (Hill 1970), within 0.3 % of the exact quantile for p = 1 − 5e-4 and df ≥ 10 (slightly low: stricter)."""
    from statistics import NormalDist
    z = NormalDist().inv_cdf(p)
    g1 = (z ** 3 + z) / 4
    g2 = (5 * z ** 5 + 16 * z ** 3 + 3 * z) / 96
    g3 = (3 * z ** 7 + 19 * z ** 5 + 17 * z ** 3 - 15 * z) / 384
    return z + g1 / df + g2 / df ** 2 + g3 / df ** 3


def test_densities_render_the_same_expected_image(monkeypatch):
    base = 1000 + 100 * SEED_OFFSET
    a = image_means("single_cosine", base)
    b = image_means("cui", base + RENDERS)
    t, df = welch_t(a, b)
    limit = t_quantile(1 - FALSE_ALARM / 2, df)
    print("single_cosine %.5f ± %.5f, cui %.5f ± %.5f: t %.2f (df %.1f, limit %.2f)"
          % (a.mean(), a.std(ddof=1) / math.sqrt(RENDERS), b.mean(), b.std(ddof=1) / math.sqrt(RENDERS), t, df, limit))
    assert abs(t) <= limit

    # Control: sample() reports cui, eval_pdf() single_cosine. The MIS weights of the two strategies no longer sum
    # to one and the image mean moves; the same statistic must see it.
    from msx.jit import bsdf as jit_bsdf

    original = jit_bsdf.ConductorModel.sample

    def mismatched(self, call, wi, s1, u1, u2, key):
        wo, _, weight, valid = original(self, call, wi, s1, u1, u2, key)
        pdf = jit_bsdf.mis.conductor_pdf(self.walk.exit, self.walk.below, call.mf, wi, wo, "cui")
        return wo, pdf, weight, valid

    monkeypatch.setattr(jit_bsdf.ConductorModel, "sample", mismatched)
    c = image_means("single_cosine", base + 2 * RENDERS)
    t_bad, df_bad = welch_t(a, c)
    print("mismatched pdf: %.5f, t %.2f (df %.1f)" % (c.mean(), t_bad, df_bad))
    assert abs(t_bad) > t_quantile(1 - FALSE_ALARM / 2, df_bad)
