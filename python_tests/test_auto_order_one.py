"""``auto``'s order-1 calls on a conductor, in both engines (src/models/auto/mod.rs ``order_one_*``, jit/auto.py):
where the rule reduces a call to order 1, ``eval`` is the closed form of ``correlated``'s order 1 and ``pdf`` /
``sample`` the visible-normal reflection density and its sampler; elsewhere ``auto`` is ``correlated``.

- ``eval`` and ``pdf`` against a float64 reference written here from the formulas (Beckmann D and Λ through
  erfc, the conductor's Fresnel term from the complex IOR), both engines, to float32 rounding.
- ``sample`` draws from the ``pdf`` it reports and weighs by ``eval``/``pdf``: for test functions g of ω_o,
  the sample means of g and of g·weight equal ∫ g·pdf dω and ∫ g·f cos θ_o dω, the integrals estimated with
  Mitsuba's own GGX sampler and density (a wider lobe: its density bounds the ratio); z-tests, Šidák over the
  checks of the module, σ from the larger of the plain and the replicate standard errors.
- The walk lanes (the rule does not reduce them) are ``correlated``'s, bit for bit in the Dr.Jit engine, in
  packets mixed with order-1 lanes (the symbolic if of jit/bsdf.py ``auto_eval_pdf``).
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

ALPHAS = (0.05, 0.1)
WI = ((0.4, 0.2), (0.7, 0.5), (0.95, 1.3))  # (cos θ_i, φ_i): reduced to order 1 at both α (asserted)
ENGINES = ("jit", "core")
N_SAMPLE = 1 << 18
N_REF = 1 << 20
REPLICATES = 4
N_G = 6  # test functions
CHECKS = len(ENGINES) * len(ALPHAS) * len(WI) * N_G * (1 + 3)  # g; g·weight per channel
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - 1e-3) ** (1 / CHECKS)) / 2)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():
        yield


def cu_rgb():
    p = mi.traverse(mi.load_dict({"type": "roughconductor", "material": "Cu"}))
    return [float(x) for x in np.array(p["eta.value"]).ravel()], [float(x) for x in np.array(p["k.value"]).ravel()]


def direction(mu, phi):
    s = math.sqrt(1 - mu * mu)
    return np.array([s * math.cos(phi), s * math.sin(phi), mu])


# ------------------------------------------------------------------ the float64 reference


def lambda_beckmann(w, alpha):
    """Smith Λ of Beckmann for upward w: (e^{−a²}/(a√π) − erfc(a))/2, a = 1/(α tan θ)."""
    z = w[..., 2]
    t = np.sqrt(np.maximum(1 - z * z, 0)) / z
    with np.errstate(divide="ignore"):
        a = np.where(t > 0, 1.0 / (alpha * np.where(t > 0, t, 1)), np.inf)
    erfc = np.vectorize(math.erfc)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        v = 0.5 * (np.exp(-a * a) / (a * math.sqrt(math.pi)) - erfc(np.minimum(a, 30.0)))
    return np.where(a > 26.0, 0.0, np.maximum(v, 0.0))


def d_beckmann(h, alpha):
    z = h[..., 2]
    t2 = (1 - z * z) / (z * z)
    return np.where(z > 0, np.exp(-t2 / (alpha * alpha)) / (math.pi * alpha * alpha * z ** 4), 0.0)


def fresnel_conductor(cos_i, eta, k):
    """Unpolarised reflectance of the complex IOR η + ik (s and p amplitudes), per channel: (3, n)."""
    n = np.asarray(eta)[:, None] + 1j * np.asarray(k)[:, None]
    c = cos_i[None, :].astype(complex)
    ct = np.sqrt(1 - (1 - c * c) / (n * n))
    rs = (c - n * ct) / (c + n * ct)
    rp = (ct - n * c) / (ct + n * c)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def reference(wi, wo, alpha, eta, k):
    """(f·cos θ_o = F·D·G2/(4 cos θ_i) per channel (3, n), pdf = D/(4 cos θ_i (1 + Λ_i)) (n)) of order 1."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    d = d_beckmann(h, alpha)
    li, lo = lambda_beckmann(wi, alpha), lambda_beckmann(wo, alpha)
    up = (wo[:, 2] > 0) & (np.sum(wi * h, -1) > 0) & (np.sum(wo * h, -1) > 0)
    f = fresnel_conductor(np.sum(wi * h, -1), eta, k)
    value = np.where(up, f * d / (4 * wi[:, 2] * (1 + li + lo)), 0.0)
    pdf = np.where(up, d / (4 * wi[:, 2] * (1 + li)), 0.0)
    return value, pdf


# ------------------------------------------------------------------ both engines


def jit_bsdf(model, alpha):
    return mi.load_dict({"type": "msx_posfree", "model": model, "distribution": "beckmann", "alpha": alpha,
                         "material": "Cu"})


def si_of(wi_rows, seed):
    n = len(wi_rows)
    si = jit_support.lanes_si((0, 0, 1), n, seed)
    si.wi = mi.Vector3f(*[mi.Float(np.asarray(wi_rows[:, j], np.float32)) for j in range(3)])
    return si


def f32(rows):
    return np.asarray(np.asarray(rows, np.float32), np.float64)


class Engine:
    """eval, pdf and sample of ``model`` in one engine on rows of directions (inputs rounded to float32)."""

    def __init__(self, engine, model, alpha):
        self.engine, self.model, self.alpha = engine, model, alpha
        if engine == "jit":
            self.b = jit_bsdf(model, alpha)
        else:
            eta, k = cu_rgb()
            self.b = CoreBsdf(surface="conductor", distribution="beckmann", model=model, alpha=alpha, eta=eta, k=k,
                              channels=3, seed=3)

    def eval_pdf(self, wi, wo):
        if self.engine == "core":
            return self.b.eval(wi, wo), self.b.pdf(wi, wo)
        si = si_of(wi, 5)
        wo_v = mi.Vector3f(*[mi.Float(np.asarray(wo[:, j], np.float32)) for j in range(3)])
        v, p = self.b.eval_pdf(mi.BSDFContext(), si, wo_v)
        return np.array(v, np.float64), np.array(p, np.float64)

    def sample(self, wi, n, seed):
        """(ω_o (n, 3), weight (3, n), pdf (n)); invalid samples have pdf 0 and weight 0."""
        u = np.random.default_rng(seed).random((3, n)).astype(np.float32)
        rows = np.tile(wi, (n, 1))
        if self.engine == "core":
            wo, w, pdf = self.b.sample(rows, u)
            return wo.reshape(n, 3), w.reshape(3, n), pdf
        bs, w = self.b.sample(mi.BSDFContext(), si_of(rows, seed), mi.Float(u[0]), mi.Point2f(mi.Float(u[1]),
                                                                                                 mi.Float(u[2])))
        return np.array(bs.wo, np.float64).T, np.array(w, np.float64), np.array(bs.pdf, np.float64)


def reduced(alpha, mus):
    """Whether the rule reduces each μ_i at ``alpha`` (the thresholds both engines read)."""
    from msx.jit import auto

    rule = auto.OrderOneRule("conductor", "beckmann", 0.01)
    return np.array(rule.order_one_suffices(mi.Float(alpha), mi.Float(np.asarray(mus, np.float32))))


def test_every_case_is_reduced():
    for alpha in ALPHAS:
        assert np.all(reduced(alpha, [mu for mu, _ in WI])), alpha


def random_wo(n, seed):
    rng = np.random.default_rng(seed)
    u, phi = rng.random(n), rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(u)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.sqrt(1 - u)], axis=1)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_eval_and_pdf_are_order_one_in_closed_form(engine, alpha):
    """Random ω_o (and mirror-near ones, where the lobe is), each case's ω_i: the float64 reference to float32
    rounding (relative 2e-4 where the value is above 1e-6 of the lobe's peak)."""
    eta, k = cu_rgb()
    e = Engine(engine, "auto", alpha)
    for i, (mu, phi) in enumerate(WI):
        wi = direction(mu, phi)
        mirror = np.array([-wi[0], -wi[1], wi[2]])
        near = mirror + 0.05 * np.random.default_rng(i).normal(size=(4096, 3))
        wo = np.concatenate([random_wo(4096, 10 + i), near])
        wo = f32(wo / np.linalg.norm(wo, axis=1, keepdims=True))
        rows = f32(np.tile(wi, (len(wo), 1)))
        value, pdf = e.eval_pdf(rows, wo)
        rv, rp = reference(rows, wo, alpha, eta, k)
        assert np.all(np.isfinite(value)) and np.all(np.isfinite(pdf))
        for got, ref, what in ((value, rv, "eval"), (pdf, rp, "pdf")):
            big = ref > 1e-6 * ref.max()
            rel = np.abs(got - ref)[big] / ref[big]
            assert rel.max() < 2e-4, (engine, alpha, mu, what, rel.max())
            assert np.all(np.abs(got - ref)[~big] <= 1e-6 * ref.max() * 1.001), (engine, alpha, mu, what)
        assert np.sum(rp > 0) > 4096, "the lobe is reached"


def g_values(wo, wi):
    """N_G bounded test functions of ω_o, rows (N_G, n): 1, x, y, z, x², and whether ω_o lies within ≈ 5.7° of
    ω_i's mirror direction (about half of the lobe at α = 0.05)."""
    x, y, z = wo[:, 0], wo[:, 1], wo[:, 2]
    cone = (-wi[0] * x - wi[1] * y + wi[2] * z) > 0.995
    return np.stack([np.ones_like(z), x, y, z, x * x, cone.astype(float)])


def reference_integrals(wi, alpha, seed):
    """∫ g·pdf dω and ∫ g·f cos θ_o dω by Mitsuba's GGX sampler (α × 1.5), per lane (for
    ``jit_support.stats``): rows (N_G, n) and (N_G, 3, n)."""
    eta, k = cu_rgb()
    b = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 1.5 * alpha, "material": "none"})
    rows = np.tile(wi, (N_REF, 1))
    u = np.random.default_rng(seed).random((3, N_REF)).astype(np.float32)
    bs, _ = b.sample(mi.BSDFContext(), si_of(rows, seed), mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
    x = np.array(bs.wo, np.float64).T  # drjit arrays convert to (3, n)
    q = np.array(bs.pdf, np.float64)
    ok = (q > 0) & (x[:, 2] > 0)
    x = np.where(ok[:, None], x, np.array([0.0, 0.0, 1.0]))
    value, pdf = reference(f32(rows), x, alpha, eta, k)
    w = np.where(ok, 1.0 / np.where(ok, q, 1.0), 0.0)
    g = g_values(x, wi)
    return g * (pdf * w), g[:, None, :] * (value * w)[None, :, :]


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("alpha", ALPHAS)
def test_sample_draws_from_its_pdf(engine, alpha):
    e = Engine(engine, "auto", alpha)
    for i, (mu, phi) in enumerate(WI):
        wi = f32(direction(mu, phi))
        wo, weight, pdf = e.sample(wi, N_SAMPLE, 100 + i)
        valid = pdf > 0
        assert np.all(np.isfinite(weight)) and np.all(weight[:, ~valid] == 0)
        # The density sample reports is the one pdf reports.
        _, p = e.eval_pdf(np.tile(wi, (int(valid.sum()), 1)), f32(wo[valid]))
        assert np.allclose(pdf[valid], p, rtol=1e-4), (engine, alpha, mu)
        g = np.where(valid[None, :], g_values(np.where(valid[:, None], wo, 0.0), wi), 0.0)
        ref_p, ref_f = reference_integrals(wi, alpha, 200 + i)
        label = "%s α %.2f μ %.2f" % (engine, alpha, mu)
        z_check(label + " ∫g·pdf", stats(g), stats(ref_p))
        z_check(label + " ∫g·f", stats(g[:, None, :] * weight[None, :, :]), stats(ref_f))


def stats(x):
    return jit_support.stats(x, REPLICATES)


def z_check(label, a, b):
    jit_support.z_check(label, a, b, Z_MAX)


@pytest.mark.parametrize("alpha", (0.1, 0.3))
def test_walk_lanes_are_correlated_bit_for_bit(alpha):
    """Lanes of every incidence, mixed in the same packets: where the rule does not reduce, ``auto``'s eval,
    pdf and sample are ``correlated``'s (same streams), where it does, order 1 in closed form; a quarter of the
    ω_o below the surface (``eval`` takes the closed form there: 0, as the walk)."""
    n = 1 << 14
    rng = np.random.default_rng(7)
    mu = rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - mu * mu)
    wi = f32(np.stack([s * np.cos(phi), s * np.sin(phi), mu], axis=1))
    wo = random_wo(n, 8)
    below = rng.random(n) < 0.25  # emitter samples below the surface: 0 from both branches (jit/bsdf.py)
    wo[below, 2] *= -1.0
    wo = f32(wo)
    walks = ~reduced(alpha, wi[:, 2])
    assert 0.05 < walks.mean() < 0.95, walks.mean()
    a, c = Engine("jit", "auto", alpha), Engine("jit", "correlated", alpha)
    (va, pa), (vc, pc) = a.eval_pdf(wi, wo), c.eval_pdf(wi, wo)
    assert np.array_equal(va[:, walks], vc[:, walks]) and np.array_equal(pa[walks], pc[walks])
    assert np.all(va[:, below] == 0.0) and np.all(pa[below] == 0.0) and np.any(vc[:, ~below] > 0.0)
    eta, k = cu_rgb()
    rv, rp = reference(wi[~walks], wo[~walks], alpha, eta, k)
    assert np.allclose(va[:, ~walks], rv, rtol=2e-4, atol=1e-6 * rv.max())
    assert np.allclose(pa[~walks], rp, rtol=2e-4, atol=1e-6 * rp.max())
    u = rng.random((3, n)).astype(np.float32)
    out = []
    for b in (a.b, c.b):
        bs, w = b.sample(mi.BSDFContext(), si_of(wi, 9), mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
        out.append((np.array(bs.wo).T, np.array(w).T, np.array(bs.pdf)))
    for x, y in zip(*out):
        assert np.array_equal(x[walks], y[walks])


@pytest.mark.parametrize("alpha", (0.1, 0.3))
def test_sample_is_the_capped_walk_bit_for_bit(alpha):
    """jit/auto.py ``sample`` (the first vertex on every lane, the walk taken up at vertex 1 behind a per-packet
    branch) gives the bits of its definition: ``correlated``'s walk sampler capped at one vertex on the lanes
    the rule reduces, their weight F·L_0/(L_0 + Λ(ω_o)) and density ``order_one_pdf``, and the full walk with
    the walks' MIS density elsewhere. Lanes of every incidence mixed in the same packets, below and at the
    horizon too; a cap of one vertex for every lane as well."""
    import drjit as dr
    from msx.jit import auto, mis, posfree
    from msx.jit.microfacet import BECKMANN, ConductorFresnel, Microfacet

    n = 1 << 14
    rng = np.random.default_rng(11)
    mu = rng.uniform(-0.3, 1.0, n)
    mu[:64] = 0.0
    phi = rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - mu * mu)
    wi = mi.Vector3f(*[mi.Float(np.asarray(c, np.float32)) for c in (s * np.cos(phi), s * np.sin(phi), mu)])
    s1, u1, u2 = (mi.Float(rng.random(n).astype(np.float32)) for _ in range(3))
    key = mi.UInt32(rng.integers(0, 2 ** 32, n, dtype=np.uint64).astype(np.uint32))
    eta, k = cu_rgb()
    fresnel = ConductorFresnel(mi.Spectrum(*eta), mi.Spectrum(*k))
    mf = Microfacet(BECKMANN, mi.Float(alpha), mi.Float(alpha))
    walker = posfree.CONDUCTOR_WALKS["correlated"]

    def walk_pdf(wo):
        return mis.conductor_pdf(walker.exit, walker.below, mf, wi, wo)

    rule = auto.OrderOneRule("conductor", "beckmann", 0.01)
    one = auto.order_one(rule, mf, wi[2], full=wi[2] > 0.0)
    walks = ~np.array(one)
    assert 0.05 < walks.mean() < 0.95, walks.mean()
    for max_bounces in (64, 1):
        got = auto.sample(mf, fresnel, wi, s1, u1, u2, one, max_bounces, key, walk_pdf)
        wo, weight, valid = walker.sample_walk(mf, fresnel, wi, s1, u1, u2,
                                               dr.select(one, mi.UInt32(1), mi.UInt32(max_bounces)), key)
        pdf = auto.order_one_pdf(mf, wi, wo)
        l0 = mf.abs_lambda(-wi)
        ok = (pdf > 0.0) & dr.isfinite(pdf) & dr.all(dr.isfinite(wo))
        ref = (wo, dr.select(one, pdf, walk_pdf(wo)),
               dr.select(one, dr.select(ok, weight * (l0 / (l0 + mf.lambda_(wo))), 0.0), weight),
               dr.select(one, ok, valid))
        for x, y, what in zip(got, ref, ("wo", "pdf", "weight", "valid")):
            a, b = np.array(x), np.array(y)
            assert np.array_equal(a, b, equal_nan=a.dtype != bool), (alpha, max_bounces, what)
        assert np.array(got[3])[walks].any() and np.array(got[3])[~walks].any()


@pytest.mark.parametrize("surface", ["conductor", "dielectric"])
def test_direct_calls_with_single_directions(surface):
    """A direct call from evaluated code may give ``auto`` one ω_i, one ω_o and a constant α beside per-lane
    keys (here from ``si.p``): its per-packet branches then take the call's width (``auto.order_one``'s
    ``lanes``) — before, drjit aborted the process ("jit_assemble(): schedule contains variable … with
    incompatible size"). ``eval``, ``pdf`` and ``sample`` must give the same call's values with every direction
    as wide as the keys, on lanes where the rule reduces and where it walks — to float32 rounding, not bit for
    bit: drjit folds arithmetic on single values at trace time in its own order (1 ulp seen), the kernel
    vectorizes it. 10⁻⁵ relative bounds the rounding of the ≈ 50 operations of a closed form (50·2⁻²⁴ ≈ 3·10⁻⁶)."""
    import drjit as dr

    n = 1 << 12
    props = ({"material": "Cu"} if surface == "conductor" else {"surface": "dielectric", "int_ior": 1.5})
    ctx = mi.BSDFContext()
    u = np.random.default_rng(5).uniform(0.0, 1.0, (3, n)).astype(np.float32)
    for alpha, mu_i in ((0.05, 0.9), (0.05, 0.1), (0.8, 0.9)):  # reduced, walking near grazing, rough (walking)
        b = mi.load_dict({"type": "msx_posfree", "model": "auto", "distribution": "beckmann", "alpha": alpha, **props})
        wi = direction(mu_i, 0.3)
        wo = direction(0.6, 2.5) * (1.0 if surface == "conductor" else -1.0)
        out = []
        for wide in (False, True):
            si = dr.zeros(mi.SurfaceInteraction3f, n)
            si.p = mi.Point3f(mi.Float(np.arange(n, dtype=np.float32)), 0.0, 0.0)
            if wide:
                si.wi = mi.Vector3f(*(mi.Float(np.full(n, x, dtype=np.float32)) for x in wi))
                w = mi.Vector3f(*(mi.Float(np.full(n, x, dtype=np.float32)) for x in wo))
            else:
                si.wi = mi.Vector3f(*(float(x) for x in wi))
                w = mi.Vector3f(*(float(x) for x in wo))
            value, pdf = b.eval_pdf(ctx, si, w)
            bs, weight = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
            out.append([np.broadcast_to(np.array(x, dtype=np.float32), (np.array(x).shape[0], n)) if np.array(x).ndim > 1
                        else np.broadcast_to(np.array(x, dtype=np.float32), (n,))
                        for x in (value, pdf, bs.wo, weight)])
        for name, a, c in zip(("eval", "pdf", "sample ω_o", "sample weight"), *out):
            assert np.all(np.isfinite(a)), (surface, alpha, mu_i, name)
            assert np.allclose(a, c, rtol=1e-5, atol=0.0), (surface, alpha, mu_i, name, np.max(np.abs(a - c)))
        assert np.any(out[0][3] != 0.0), (surface, alpha, mu_i, "no sample: the test shows nothing")
