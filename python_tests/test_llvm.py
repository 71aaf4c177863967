"""msx_posfree in Mitsuba's LLVM variants (batched native calls).

The whole module is skipped when no LLVM variant can be initialised (needs
libLLVM >= 19, see README.md; DRJIT_LIBLLVM_PATH is pointed at libLLVM 19 when that file
exists and the variable is unset — it must be set before drjit initialises
its LLVM backend, hence at import time of this module).
"""

import math
import os
import time
import warnings

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402

from conftest import TRAVERSE_CASES, direction_pairs, expected_traverse, traverse_items  # noqa: E402

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)
mi.set_variant("llvm_ad_rgb")

import msx  # noqa: E402

RTOL, ATOL = 1e-4, 1e-6
GRAZING_COS = 1e-2
EDGE_SAMPLE = 1e-3
MAX_EXCLUDED_FRACTION = 0.02
# Float32 conditioning of Mitsuba's sampler: inputs perturbed by this many
# float32 ulps (Mitsuba's sampling path rounds ~30 times; 16 ulps bounds the
# accumulated input-level error) — a mismatch no larger than the change this
# causes in our own float64 result is explained by float32 arithmetic.
COND_ULPS = 16
N_PAIRS = 1000


def llvm(variant="llvm_ad_rgb"):
    mi.set_variant(variant)
    msx.register(backend="batched")
    # register() switched drjit to evaluated mode (see test_plain_render_matches_scalar); the tests below
    # choose their mode themselves, starting from drjit's default.
    for f in (dr.JitFlag.SymbolicLoops, dr.JitFlag.SymbolicCalls):
        dr.set_flag(f, True)
    return mi


@pytest.fixture(autouse=True)
def symbolic_flags():
    """Each test starts in drjit's default (symbolic) mode; creating an msx_posfree instance switches it off."""
    for f in (dr.JitFlag.SymbolicLoops, dr.JitFlag.SymbolicCalls):
        dr.set_flag(f, True)
    yield


@pytest.fixture(scope="module", autouse=True)
def threads():
    old = dr.thread_count()
    dr.set_thread_count(os.cpu_count() or 1)
    yield
    dr.set_thread_count(old)


def np_of(x):
    """(channels, n) float64 array of a Float / Color / Vector (n lanes)."""
    if dr.depth_v(x) > 1:
        return np.stack([np.array(x[i].numpy(), dtype=np.float64) for i in range(len(x))])
    return np.array(x.numpy(), dtype=np.float64)[None, :]


def batch(pairs):
    wi = np.array([p[0] for p in pairs], dtype=np.float32)
    wo = np.array([p[1] for p in pairs], dtype=np.float32)
    return wi, wo


class Check:
    def __init__(self, label):
        self.label, self.checked, self.excluded, self.failures = label, 0, 0, []
        self.max_rel = 0.0

    def compare(self, what, a, b, excl, spread=None):
        """a, b: (c, n); excl: (n,) bool mask of float32-ill-conditioned lanes;
        spread: (c, n) change of our own result under float32-level input
        perturbations (see `f32_spread`): mismatches within it are excluded."""
        a, b = np.atleast_2d(a), np.atleast_2d(b)
        tol = RTOL * np.maximum(np.abs(a), np.abs(b)) + ATOL
        ok = np.abs(a - b) <= tol
        if spread is not None:
            excl = excl[None, :] | (np.abs(a - b) <= tol + np.atleast_2d(spread))
        self.checked += ok.size
        big = np.minimum(np.abs(a), np.abs(b)) > 1e-3
        with np.errstate(divide="ignore", invalid="ignore"):
            self.max_rel = max(self.max_rel, float(np.max((np.abs(a - b) / np.maximum(np.abs(a), np.abs(b)))[big])))
        bad = ~ok
        excl = np.broadcast_to(excl if excl.ndim == 2 else excl[None, :], bad.shape)
        self.excluded += int((bad & excl).sum())
        idx = np.argwhere(bad & ~excl)
        for c, i in idx[:5]:
            self.failures.append((what, int(i), float(a[c, i]), float(b[c, i])))
        if len(idx) > 5:
            self.failures.append((what, "... %d more" % (len(idx) - 5)))

    def report(self):
        print("\n[%s] %d comparisons, max rel. diff %.2e, excluded %d, unexplained %d"
              % (self.label, self.checked, self.max_rel, self.excluded, len(self.failures)))
        assert not self.failures, "%s: %s" % (self.label, self.failures[:6])
        assert self.excluded <= MAX_EXCLUDED_FRACTION * self.checked


def f32_spread(run, arrays):
    """Largest change of run(*arrays) (a tuple of (c, n) float64 arrays) when
    one input array at a time is scaled by 1 ± COND_ULPS float32 ulps: the
    float32 conditioning of each output, lane by lane."""
    base = run(*arrays)
    spread = [np.zeros_like(x) for x in base]
    for k in range(len(arrays)):
        for sign in (-1.0, 1.0):
            pert = list(arrays)
            pert[k] = (arrays[k] * (1.0 + sign * COND_ULPS * 2.0 ** -24)).astype(np.float32)
            for sp, x, y in zip(spread, base, run(*pert)):
                np.maximum(sp, np.abs(x - y), out=sp)
    return spread


def compare_with_roughconductor(mi, common, seed, label, spectral=False):
    ours = mi.load_dict(dict(type="msx_posfree", model="single", **common))
    ref = mi.load_dict(dict(type="roughconductor", **common))
    assert ours.flags() == ref.flags()
    wi_np, wo_np = batch(direction_pairs(seed, N_PAIRS))
    n = len(wi_np)
    rng = np.random.default_rng(seed)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(wi_np[:, i]) for i in range(3)])
    if spectral:
        si.wavelengths = mi.Spectrum(*[mi.Float(rng.uniform(360, 830, n).astype(np.float32)) for _ in range(4)])
    wo = mi.Vector3f(*[mi.Float(wo_np[:, i]) for i in range(3)])
    ctx = mi.BSDFContext()
    excl = (wi_np[:, 2] < GRAZING_COS) | (wo_np[:, 2] < GRAZING_COS)
    chk = Check(label)
    chk.compare("eval", np_of(ours.eval(ctx, si, wo)), np_of(ref.eval(ctx, si, wo)), excl)
    chk.compare("pdf", np_of(ours.pdf(ctx, si, wo)), np_of(ref.pdf(ctx, si, wo)), excl)
    (v1, p1), (v2, p2) = ours.eval_pdf(ctx, si, wo), ref.eval_pdf(ctx, si, wo)
    chk.compare("eval_pdf.value", np_of(v1), np_of(v2), excl)
    chk.compare("eval_pdf.pdf", np_of(p1), np_of(p2), excl)

    s = rng.random((3, n)).astype(np.float32)
    s1, s2 = mi.Float(s[0]), mi.Point2f(mi.Float(s[1]), mi.Float(s[2]))
    bs1, w1 = ours.sample(ctx, si, s1, s2)
    bs2, w2 = ref.sample(ctx, si, s1, s2)
    pdf1, pdf2 = np_of(bs1.pdf)[0], np_of(bs2.pdf)[0]
    wo1, wo2 = np_of(bs1.wo), np_of(bs2.wo)
    ww1, ww2 = np_of(w1), np_of(w2)
    below = (pdf2 > 0) & (wo2[2] <= 0)  # Mitsuba: zero weight; msx: invalid sample
    assert np.all(pdf1[below] == 0) and np.all(ww1[:, below] == 0) and np.all(ww2[:, below] == 0)
    s_excl = excl | (np.minimum(np.minimum(s[1], s[2]), np.minimum(1 - s[1], 1 - s[2])) < EDGE_SAMPLE)
    s_excl |= (pdf2 > 0) & (wo2[2] < GRAZING_COS)
    s_excl |= below
    both = (pdf1 > 0) & (pdf2 > 0)

    def run_ours(u1, u2, wx, wy, wz):
        si.wi = mi.Vector3f(mi.Float(wx), mi.Float(wy), mi.Float(wz))
        bs, w = ours.sample(ctx, si, s1, mi.Point2f(mi.Float(u1), mi.Float(u2)))
        return np_of(bs.wo), np_of(bs.pdf), np_of(w)

    sp_wo, sp_pdf, sp_w = f32_spread(run_ours, (s[1], s[2], wi_np[:, 0], wi_np[:, 1], wi_np[:, 2]))
    chk.compare("sample.wo", wo1[:, both], wo2[:, both], s_excl[both], sp_wo[:, both])
    chk.compare("sample.pdf", pdf1, pdf2, s_excl, sp_pdf)
    chk.compare("sample.weight", ww1, ww2, s_excl, sp_w)
    for x in (ww1, pdf1, np_of(v1)):
        assert np.all(np.isfinite(x))
    valid = pdf1 > 0
    assert np.all(np_of(bs1.sampled_type)[0][valid] == int(mi.BSDFFlags.GlossyReflection))
    assert np.all(np_of(bs1.eta)[0][valid] == 1.0)
    chk.report()


CONFIGS = [(d, a, m) for d in ("beckmann", "ggx") for a in ("iso", "aniso") for m in ("none", "Cu")]


@pytest.mark.parametrize("config", CONFIGS, ids=["-".join(c) for c in CONFIGS])
def test_single_equals_roughconductor_llvm_rgb(config):
    mi = llvm()
    d, a, m = config
    alpha = {"alpha": 0.2} if a == "iso" else {"alpha_u": 0.3, "alpha_v": 0.1}
    compare_with_roughconductor(mi, dict(distribution=d, material=m, **alpha), 1234, "llvm_ad_rgb " + "-".join(config))


def test_single_equals_roughconductor_llvm_spectral():
    mi = llvm("llvm_ad_spectral")
    compare_with_roughconductor(mi, dict(distribution="ggx", material="Au", alpha=0.25), 4321,
                                "llvm_ad_spectral ggx-Au", spectral=True)


def test_specular_reflectance_and_texture_llvm():
    mi = llvm()
    common = dict(distribution="beckmann", material="Cu",
                  alpha={"type": "checkerboard", "color0": 0.05, "color1": 0.5},
                  specular_reflectance={"type": "rgb", "value": [0.2, 0.5, 0.9]})
    ours = mi.load_dict(dict(type="msx_posfree", model="single", **common))
    ref = mi.load_dict(dict(type="roughconductor", **common))
    wi_np, wo_np = batch(direction_pairs(5, 2000, grazing_fraction=0.0))
    n = len(wi_np)
    rng = np.random.default_rng(5)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(wi_np[:, i]) for i in range(3)])
    si.uv = mi.Point2f(mi.Float(rng.random(n).astype(np.float32)), mi.Float(rng.random(n).astype(np.float32)))
    wo = mi.Vector3f(*[mi.Float(wo_np[:, i]) for i in range(3)])
    chk = Check("llvm_ad_rgb textured alpha + specular_reflectance")
    ctx = mi.BSDFContext()
    chk.compare("eval", np_of(ours.eval(ctx, si, wo)), np_of(ref.eval(ctx, si, wo)), np.zeros(n, bool))
    chk.report()


def test_masking_and_errors():
    mi = llvm()
    b = mi.load_dict(dict(type="msx_posfree", model="correlated", alpha=0.5))
    n = 64
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(0.0, 0.6, 0.8)  # width-1 literal: broadcast (len = 1)
    wo = mi.Vector3f(mi.Float(np.full(n, np.nan, np.float32)), 0.0, 1.0)  # garbage in some lanes
    active = mi.Bool(np.arange(n) % 2 == 0)
    ctx = mi.BSDFContext()
    v = np_of(b.eval(ctx, si, wo, active))
    assert np.all(np.isfinite(v)) and np.all(v[:, 1::2] == 0)
    wo = mi.Vector3f(0.0, -0.6, 0.8)
    v, p = b.eval_pdf(ctx, si, wo, active)
    v, p = np_of(v), np_of(p)[0]
    assert np.all(v[:, 1::2] == 0) and np.all(p[1::2] == 0) and np.all(v[:, ::2] > 0) and np.all(p[::2] > 0)
    with pytest.raises(Exception, match="model"):
        mi.load_dict(dict(type="msx_posfree", model="nope"))
    with pytest.raises(Exception, match="alpha"):
        mi.load_dict(dict(type="msx_posfree", alpha=-1.0))


def test_batched_route_refuses_inputs_that_carry_a_gradient():
    """The batched route computes on the Rust core: a direction or parameter that carries a gradient stops the
    call with one line (eval, pdf, sample; the way out named) instead of a silent zero gradient — here on
    ``invariance`` on the diffuse surface, which the Dr.Jit engine does not run. Detached inputs still run."""
    mi = llvm()
    b = mi.load_dict(dict(type="msx_posfree", surface="diffuse", model="invariance", alpha=0.5))
    n = 64
    ctx = mi.BSDFContext()
    t = mi.Float(0.2)
    dr.enable_grad(t)
    frame = mi.Frame3f(mi.Vector3f(dr.sin(t), 0.0 * t, dr.cos(t)))
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = frame.to_local(mi.Vector3f(0.3, 0.1, 0.9))
    wo = frame.to_local(mi.Vector3f(-0.2, 0.1, 0.95))
    calls = (lambda: b.eval(ctx, si, wo), lambda: b.pdf(ctx, si, wo),
             lambda: b.sample(ctx, si, mi.Float(0.3), mi.Point2f(0.4, 0.6)))
    for call in calls:
        with pytest.raises(ValueError) as e:
            call()
        message = str(e.value)
        assert "batched route" in message and "carry a gradient (wi" in message and "\n" not in message, message
    si.wi, wo = dr.detach(si.wi), dr.detach(wo)
    params = mi.traverse(b)
    dr.enable_grad(params["alpha.value"])
    params.update()
    with pytest.raises(ValueError, match=r"carry a gradient \(alpha_u"):
        b.eval(ctx, si, wo)
    dr.disable_grad(params["alpha.value"])
    params.update()
    v = np_of(b.eval(ctx, si, wo))
    assert np.all(np.isfinite(v)) and np.all(v > 0)


def test_traverse_lists_the_surfaces_textures():
    """traverse lists exactly the textures the configured surface uses, as in the scalar variants."""
    mi = llvm()
    for params, names in TRAVERSE_CASES:
        b = mi.load_dict(dict(type="msx_posfree", **params))
        assert traverse_items(mi, b) == expected_traverse(mi, names), params


def test_dielectric_sample_record():
    mi = llvm()
    b = mi.load_dict(dict(type="msx_posfree", surface="dielectric", model="correlated", alpha=0.3, int_ior=1.5, ext_ior=1.0))
    n = 20000
    rng = np.random.default_rng(2)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(0.3, 0.0, math.sqrt(1 - 0.09))
    s = rng.random((3, n)).astype(np.float32)
    ctx = mi.BSDFContext()
    bs, w = b.sample(ctx, si, mi.Float(s[0]), mi.Point2f(mi.Float(s[1]), mi.Float(s[2])))
    z, pdf = np_of(bs.wo)[2], np_of(bs.pdf)[0]
    eta, st, comp = np_of(bs.eta)[0], np_of(bs.sampled_type)[0], np_of(bs.sampled_component)[0]
    tr = (pdf > 0) & (z < 0)
    rf = (pdf > 0) & (z > 0)
    assert tr.sum() > n // 4 and rf.sum() > 0
    assert np.allclose(eta[tr], 1.5) and np.all(eta[rf] == 1.0)
    assert np.all(st[tr] == int(mi.BSDFFlags.GlossyTransmission)) and np.all(comp[tr] == 1)
    assert np.all(st[rf] == int(mi.BSDFFlags.GlossyReflection)) and np.all(comp[rf] == 0)
    assert np.all(np.isfinite(np_of(w)))
    ctx.mode = mi.TransportMode.Importance
    bs2, w2 = b.sample(ctx, si, mi.Float(s[0]), mi.Point2f(mi.Float(s[1]), mi.Float(s[2])))
    assert np.all(np.isfinite(np_of(w2)))


@pytest.mark.parametrize("cos_i", [0.8, 0.3])
def test_white_furnace_llvm(cos_i):
    mi = llvm()
    b = mi.load_dict(dict(type="msx_posfree", model="correlated", material="none", distribution="ggx",
                          alpha=0.6, seed=3))
    n = 100_000
    rng = np.random.default_rng(11)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(math.sqrt(1 - cos_i * cos_i), 0.0, cos_i)
    s = rng.random((3, n)).astype(np.float32)
    bs, w = b.sample(mi.BSDFContext(), si, mi.Float(s[0]), mi.Point2f(mi.Float(s[1]), mi.Float(s[2])))
    x = np_of(w)[0]
    assert np.all(np.isfinite(x)) and np.all(x >= 0)
    mean, se = x.mean(), x.std() / math.sqrt(n)
    print("\n[llvm furnace correlated ggx α=0.6 cosθi=%g] mean weight %.5f ± %.5f" % (cos_i, mean, se))
    assert abs(mean - 1.0) <= 3.0 * se + 0.003


def scene_dict(bsdf):
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {
            "type": "perspective", "fov": 40,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 4},
        },
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "sun": {"type": "directional", "direction": [-0.4, -0.3, -1.0], "irradiance": 3.0},
        "sky": {"type": "constant", "radiance": 0.3},
    }


MS_BSDF = dict(type="msx_posfree", model="correlated", material="Cu", alpha=0.5)


def test_plain_render_matches_scalar():
    """A user's plain mi.render() (no wrapper) renders the right image: creating the instance switched drjit to
    evaluated mode, with one warning; the mean equals the scalar variant's within noise."""
    mi.set_variant("llvm_ad_rgb")
    from msx.plugin import vectorized

    vectorized._switched = False  # as in a new process: the first switch warns
    msx._REGISTERED.pop("llvm_ad_rgb", None)
    with pytest.warns(RuntimeWarning, match="symbolic loops and calls are now off"):
        msx.register(backend="batched")
    scene = mi.load_dict(scene_dict(MS_BSDF))
    assert not dr.flag(dr.JitFlag.SymbolicLoops) and not dr.flag(dr.JitFlag.SymbolicCalls)
    t0 = time.time()
    img_llvm = np.array(mi.render(scene, seed=1), dtype=np.float64)
    t_llvm = time.time() - t0
    assert msx.check_fallback() == 0
    mi.set_variant("scalar_rgb")
    msx.register()
    t0 = time.time()
    img_s = np.array(mi.render(mi.load_dict(scene_dict(MS_BSDF)), seed=2), dtype=np.float64)
    t_s = time.time() - t0
    assert np.all(np.isfinite(img_llvm)) and img_llvm.mean() > 0
    d = (img_llvm - img_s).ravel()
    se = d.std() / math.sqrt(d.size)
    print("\n[render 32x32x4spp] llvm plain mi.render mean %.5f (%.2fs), scalar_rgb mean %.5f (%.2fs), diff %.5f, SE %.5f"
          % (img_llvm.mean(), t_llvm, img_s.mean(), t_s, d.mean(), se))
    assert abs(d.mean()) <= 4 * se + 1e-4


def test_evaluated_mode_context_restores_flags(monkeypatch):
    monkeypatch.setenv("MSX_KEEP_SYMBOLIC", "1")
    mi = llvm()
    scene = mi.load_dict(scene_dict(MS_BSDF))
    assert dr.flag(dr.JitFlag.SymbolicLoops) and dr.flag(dr.JitFlag.SymbolicCalls)  # kept on request
    with msx.evaluated_mode():
        img = np.array(mi.render(scene, seed=1), dtype=np.float64)
    assert dr.flag(dr.JitFlag.SymbolicLoops) and dr.flag(dr.JitFlag.SymbolicCalls)  # restored
    assert np.all(np.isfinite(img)) and img.mean() > 0


def test_symbolic_mode_fallback(monkeypatch):
    monkeypatch.setenv("MSX_KEEP_SYMBOLIC", "1")
    mi = llvm()
    assert dr.flag(dr.JitFlag.SymbolicLoops) and dr.flag(dr.JitFlag.SymbolicCalls)
    # A live msx instance must not break a symbolic render of a scene without it.
    live = mi.load_dict(MS_BSDF)
    other = mi.load_dict(scene_dict({"type": "roughconductor", "alpha": 0.3}))
    img = np.array(mi.render(other, seed=0))
    assert np.all(np.isfinite(img)) and img.mean() > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert live._fallback_check() == 0
    # A symbolic render of a scene WITH msx: no crash, finite, black sphere, and a warning.
    scene = mi.load_dict(scene_dict(MS_BSDF))
    img = np.array(mi.render(scene, seed=0))
    assert np.all(np.isfinite(img))
    with pytest.warns(RuntimeWarning, match="evaluated_mode"):
        assert msx.check_fallback() > 0
    with pytest.raises(RuntimeError, match="symbolic"):
        msx.check_fallback(error=True)
    del live


def test_timing_batched_vs_scalar():
    mi = llvm()
    b = mi.load_dict(MS_BSDF)
    n = 200_000
    wi_np, wo_np = batch(direction_pairs(3, 2000, grazing_fraction=0.0))
    reps = n // len(wi_np)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(np.tile(wi_np[:, i], reps)) for i in range(3)])
    wo = mi.Vector3f(*[mi.Float(np.tile(wo_np[:, i], reps)) for i in range(3)])
    dr.eval(si.wi, wo)
    ctx = mi.BSDFContext()
    dr.eval(b.eval(ctx, si, wo))
    t0 = time.perf_counter()
    v = b.eval(ctx, si, wo)
    dr.eval(v)
    t_b = (time.perf_counter() - t0) / n
    mi.set_variant("scalar_rgb")
    msx.register()
    bs = mi.load_dict(MS_BSDF)
    ctx = mi.BSDFContext()
    m = 2000
    sis = []
    for i in range(m):
        s = mi.SurfaceInteraction3f()
        s.wi = mi.Vector3f(*map(float, wi_np[i]))
        sis.append((s, mi.Vector3f(*map(float, wo_np[i]))))
    t0 = time.perf_counter()
    for s, w in sis:
        bs.eval(ctx, s, w)
    t_s = (time.perf_counter() - t0) / m
    print("\n[timing correlated Cu α=0.5, %d threads] batched LLVM eval %.0f ns/lane; scalar plugin %.0f ns/call "
          "(%.1fx)" % (dr.thread_count(), t_b * 1e9, t_s * 1e9, t_s / t_b))


FUZZ_LANES = 1 << 15  # per configuration and method; 8 configurations x 4 methods ≈ 10⁶ lanes


@pytest.mark.parametrize("surface, model, estimator", [
    ("conductor", "correlated", "pt"), ("conductor", "heitz", "pt"), ("conductor", "invariance", "pt"),
    ("conductor", "uncorrelated", "bdpt"), ("dielectric", "correlated", "bdpt"), ("dielectric", "invariance", "pt"),
    ("diffuse", "heitz", "pt"), ("diffuse", "auto", "pt"),
])
def test_fuzz_llvm_batches(surface, model, estimator):
    """Batched route with adversarial lanes: NaN/Inf/negative/huge texture values (bitmaps), NaN and
    below-horizon directions, odd sample values. Outputs finite and non-negative, and the C ABI cleaned
    nothing (its raw counters, see msx.diagnostics)."""
    mi = llvm()
    rng = np.random.default_rng(hash((surface, model, estimator)) % (1 << 32))
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e30, 1e-45, 3.4e38], np.float32)

    def bitmap(channels):
        vals = rng.uniform(0.0, 2.0, (8, 8, channels)).astype(np.float32)
        mask = rng.random(vals.shape) < 0.4
        vals[mask] = rng.choice(special, mask.sum())
        return {"type": "bitmap", "data": mi.TensorXf(vals), "raw": True, "filter_type": "nearest"}

    params = dict(type="msx_posfree", surface=surface, model=model, estimator=estimator, distribution="ggx",
                  alpha=bitmap(1))
    params.update({"conductor": {"eta": bitmap(3), "k": bitmap(3)},
                   "dielectric": {"specular_transmittance": bitmap(3)},
                   "diffuse": {"reflectance": bitmap(3)}}[surface])
    b = mi.load_dict(params)
    n = FUZZ_LANES

    def dirs():
        d = rng.normal(size=(n, 3)).astype(np.float32)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        bad = rng.random(n) < 0.05
        d[bad, rng.integers(0, 3, bad.sum())] = rng.choice(special, bad.sum())
        d[rng.random(n) < 0.05] = [0.6, 0.8, 1e-7]
        return mi.Vector3f(*[mi.Float(d[:, i]) for i in range(3)])

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = dirs()
    si.uv = mi.Point2f(mi.Float(rng.random(n).astype(np.float32)), mi.Float(rng.random(n).astype(np.float32)))
    wo = dirs()
    s = rng.random((3, n)).astype(np.float32)
    s[0, rng.random(n) < 0.02] = np.nan
    before = msx.diagnostics()
    outs = []
    for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
        ctx = mi.BSDFContext(mode)
        outs += [b.eval(ctx, si, wo), b.pdf(ctx, si, wo)]
        bs, w = b.sample(ctx, si, mi.Float(s[0]), mi.Point2f(mi.Float(s[1]), mi.Float(s[2])))
        outs += [bs.pdf, w]
    after = msx.diagnostics()
    for o in outs:
        x = np_of(o)
        assert np.all(np.isfinite(x)) and np.all(x >= 0)
    print(f"\n[llvm fuzz {surface} {model} {estimator}] {6 * n} lanes; diagnostics {after}")
    assert {k: after[k] - before[k] for k in after} == {"nonfinite": 0, "negative": 0, "panics": 0}
