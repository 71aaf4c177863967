"""``auto``'s order-1 calls on a dielectric, in both engines (src/models/posfree/dielectric.rs and
jit/posfree_dielectric.py ``order_one_*``; jit/bsdf.py ``DielectricModel``): where the rule reduces a call to
order 1 — from either side, at the relative IOR seen from ω_i — ``eval`` is the walk's first next event and
``pdf`` / ``sample`` the density of the walk's first vertex (the visible normal, then reflection or refraction
by the Fresnel choice) and its direction with the weight eval/pdf; elsewhere ``auto`` is ``correlated``.

- ``eval`` and ``pdf`` of the engine equal the core's lane by lane (float32 against float64: relative 2e-3
  where the value is above 1e-4 of its peak and the transmission's Fresnel factor is well conditioned,
  cos²θ_t ≥ 0.01 as tests/common/dielectric.rs; elsewhere within 1e-4 of the peak), Radiance and Importance
  mode, ω_o spread over the sphere and drawn in the lobe.
- In the engine, bit for bit: the walk lanes are ``correlated``'s (``eval``, ``pdf``, ``sample``, in packets
  mixed with reduced lanes), a reduced lane's ``eval`` is ``correlated``'s capped at one vertex, its sampled
  direction is that capped walk's wherever the walk left there; its ``sample`` reports ``pdf``'s density and
  the weight ``eval``/``pdf``.
- ``sample`` in distribution: the means of g(ω_o)·[valid] (the density's mass in g) and of g·weight (∫ g·f cos
  θ_o) of the engine equal the core's (whose sampler tests/auto.rs holds to its pdf by χ² and to the capped
  walk's expectation); z-tests, Šidák over the checks of the module, σ the larger of the plain and the
  replicate standard errors.
"""

import math
import statistics

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import jit_support  # noqa: E402
from msx.core import CoreBsdf  # noqa: E402

IOR = 1.5
# (distribution, α, auto_tolerance): reduced from both sides at the incidences below (asserted).
CASES = (("beckmann", 0.1, 0.01), ("ggx", 0.08, 0.05))
MODES = ("radiance", "importance")
WI = (0.9, 0.6, -0.9, -0.6)  # cos θ_i of the sampled cases
N_SAMPLE = 1 << 18
REPLICATES = 4
N_G = 5  # test functions
CHECKS = len(CASES) * len(WI) * N_G * 2
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - 1e-3) ** (1 / CHECKS)) / 2)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():
        yield


def jit_bsdf(model, dist, alpha, tolerance, **more):
    extra = {"auto_tolerance": tolerance} if model == "auto" else {}
    return mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "int_ior": IOR, "ext_ior": 1.0,
                         "model": model, "distribution": dist, "alpha": alpha, **extra, **more})


def core_bsdf(dist, alpha, tolerance, mode):
    return CoreBsdf(surface="dielectric", distribution=dist, model="auto", alpha=alpha, ior=IOR, channels=3,
                    seed=3, auto_tolerance=tolerance, radiance=mode == "radiance")


def context(mode):
    return mi.BSDFContext(mi.TransportMode.Radiance if mode == "radiance" else mi.TransportMode.Importance)


def vec(rows):
    return mi.Vector3f(*[mi.Float(np.asarray(rows[:, j], np.float32)) for j in range(3)])


def si_of(wi_rows, seed):
    si = jit_support.lanes_si((0, 0, 1), len(wi_rows), seed)
    si.wi = vec(wi_rows)
    return si


def f32(rows):
    return np.asarray(np.asarray(rows, np.float32), np.float64)


def sphere(n, seed):
    rng = np.random.default_rng(seed)
    z, phi = rng.uniform(-1, 1, n), rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def reduced(dist, alpha, tolerance, cos_i):
    """Whether the rule reduces each (signed) cos θ_i (the thresholds both engines read)."""
    from msx.jit import auto

    rule = auto.SidedRule(dist, tolerance, IOR)
    return np.array(rule.order_one_suffices(mi.Float(alpha), mi.Float(np.asarray(cos_i, np.float32))))


def well_conditioned(wi, wo):
    """Reflections, and transmissions whose Fresnel factor is well conditioned: cos²θ_t ≥ 0.01 at Walter's half
    vector (1 − F cancels next to the critical angle; tests/common/dielectric.rs ``well_conditioned``)."""
    across = wi[:, 2] * wo[:, 2] < 0
    ni = np.where(wi[:, 2] > 0, 1.0, IOR)
    no = np.where(wo[:, 2] > 0, 1.0, IOR)
    h = -(ni[:, None] * wi + no[:, None] * wo)
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    h = np.where(h[:, 2:3] < 0, -h, h)
    c = np.sum(wi * h, axis=1)
    n = np.where(c > 0, IOR, 1.0 / IOR)
    return ~across | (1.0 - (1.0 - c * c) / (n * n) >= 0.01)


def test_every_case_is_reduced():
    for dist, alpha, tolerance in CASES:
        assert np.all(reduced(dist, alpha, tolerance, WI)), (dist, alpha)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("case", CASES)
def test_eval_and_pdf_equal_the_core(case, mode):
    dist, alpha, tolerance = case
    n = 1 << 15
    wi = f32(sphere(n, 1))
    one = reduced(dist, alpha, tolerance, wi[:, 2])
    assert np.mean(one[wi[:, 2] > 0]) > 0.4 and np.mean(one[wi[:, 2] < 0]) > 0.2, "both sides reduce"
    core = core_bsdf(dist, alpha, tolerance, mode)
    # ω_o: half spread over the sphere, half drawn in the lobe (the core's sampler: reflections and refractions).
    drawn, _, pdf = core.sample(wi, np.random.default_rng(2).random((3, n)))
    wo = np.where((pdf > 0)[:, None], drawn, sphere(n, 3))
    wo = np.concatenate([sphere(n, 4), wo])
    wo = f32(wo / np.linalg.norm(wo, axis=1, keepdims=True))
    wi = np.concatenate([wi, wi])
    one = np.concatenate([one, one])
    b = jit_bsdf("auto", dist, alpha, tolerance)
    value, density = b.eval_pdf(context(mode), si_of(wi, 5), vec(wo))
    value, density = np.array(value, np.float64)[0], np.array(density, np.float64)
    ref_value, ref_density = core.eval(wi, wo)[0], core.pdf(wi, wo)
    good = well_conditioned(wi, wo)
    assert np.all(np.isfinite(value)) and np.all(np.isfinite(density))
    for got, ref, what in ((value, ref_value, "eval"), (density, ref_density, "pdf")):
        got, ref = got[one], ref[one]
        peak = ref.max()
        big = (ref > 1e-4 * peak) & good[one]
        rel = np.abs(got - ref)[big] / ref[big]
        assert rel.max() < 2e-3, (case, mode, what, rel.max())
        assert np.all(np.abs(got - ref)[~big] <= 1e-4 * peak), (case, mode, what)
        across = (wi[one, 2] * wo[one, 2] < 0) & big
        assert across.sum() > 1000 and (big & ~across).sum() > 1000, "reflections and refractions reached"


@pytest.mark.parametrize("case", CASES)
def test_engine_lanes_bit_for_bit(case):
    """Lanes of every incidence, both sides, mixed in the same packets."""
    dist, alpha, tolerance = case
    n = 1 << 14
    rng = np.random.default_rng(7)
    wi = f32(sphere(n, 8))
    wo = f32(sphere(n, 9))
    walks = ~reduced(dist, alpha, tolerance, wi[:, 2])
    assert 0.05 < walks.mean() < 0.95, walks.mean()
    a, c, c1 = (jit_bsdf("auto", dist, alpha, tolerance), jit_bsdf("correlated", dist, alpha, tolerance),
                jit_bsdf("correlated", dist, alpha, tolerance, max_bounces=1))
    out = [tuple(np.array(x) for x in b.eval_pdf(mi.BSDFContext(), si_of(wi, 5), vec(wo))) for b in (a, c, c1)]
    (va, pa), (vc, pc), (v1, _) = out
    assert np.array_equal(va[:, walks], vc[:, walks]) and np.array_equal(pa[walks], pc[walks])
    assert np.array_equal(va[:, ~walks], v1[:, ~walks]) and np.any(va[:, ~walks] > 0)
    u = rng.random((3, n)).astype(np.float32)
    out = []
    for b in (a, c, c1):
        bs, w = b.sample(mi.BSDFContext(), si_of(wi, 9), mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
        out.append((np.array(bs.wo).T, np.array(w), np.array(bs.pdf)))
    (wa, weight, pdf), walk, capped = out
    for x, y in zip((wa, weight.T, pdf), (walk[0], walk[1].T, walk[2])):
        assert np.array_equal(x[walks], y[walks])
    left = ~walks & (capped[2] > 0) & (capped[1][0] > 0)
    assert left.sum() > 1000 and np.array_equal(wa[left], capped[0][left])
    ok = ~walks & (pdf > 0)
    assert ok.sum() > left.sum()  # the closed form also returns the directions where the walk went on
    value, density = (np.array(x, np.float64) for x in a.eval_pdf(mi.BSDFContext(), si_of(wi[ok], 5), vec(wa[ok])))
    assert np.allclose(pdf[ok], density, rtol=1e-5, atol=0.0)
    assert np.allclose(weight[:, ok] * pdf[ok], value, rtol=1e-5, atol=1e-7 * value.max())
    assert np.all(weight[:, ~walks & ~(pdf > 0)] == 0.0)


def g_values(wo, wi):
    """N_G bounded test functions of ω_o, rows (N_G, n): 1, x, y, z, and whether ω_o crossed the surface."""
    x, y, z = wo[:, 0], wo[:, 1], wo[:, 2]
    return np.stack([np.ones_like(z), x, y, z, (z * wi[2] < 0).astype(float)])


@pytest.mark.parametrize("case", CASES)
def test_sample_equals_the_core_in_distribution(case):
    dist, alpha, tolerance = case
    b = jit_bsdf("auto", dist, alpha, tolerance)
    core = core_bsdf(dist, alpha, tolerance, "radiance")
    for i, mu in enumerate(WI):
        wi = f32([math.sqrt(1 - mu * mu) * math.cos(0.4), math.sqrt(1 - mu * mu) * math.sin(0.4), mu])
        rows = np.tile(wi, (N_SAMPLE, 1))
        results = []
        for engine, seed in (("jit", 300 + i), ("core", 400 + i)):
            u = np.random.default_rng(seed).random((3, N_SAMPLE)).astype(np.float32)
            if engine == "core":
                wo, w, pdf = core.sample(rows, u)
                wo, w = wo.reshape(N_SAMPLE, 3), w.reshape(3, N_SAMPLE)[0]
            else:
                bs, w = b.sample(mi.BSDFContext(), si_of(rows, seed), mi.Float(u[0]),
                                 mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
                wo, w, pdf = np.array(bs.wo, np.float64).T, np.array(w, np.float64)[0], np.array(bs.pdf, np.float64)
            valid = pdf > 0
            g = np.where(valid[None, :], g_values(np.where(valid[:, None], wo, 0.0), wi), 0.0)
            results.append((g, g * np.where(valid, w, 0.0)[None, :]))
        label = "%s α %.2f cos θ_i %.1f" % (dist, alpha, mu)
        (g_j, f_j), (g_c, f_c) = results
        jit_support.z_check(label + " E[g]", jit_support.stats(g_j, REPLICATES), jit_support.stats(g_c, REPLICATES),
                            Z_MAX)
        jit_support.z_check(label + " E[g·weight]", jit_support.stats(f_j, REPLICATES),
                            jit_support.stats(f_c, REPLICATES), Z_MAX)
