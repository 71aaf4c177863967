"""Gradients of the Dr.Jit engine in ``llvm_ad_rgb`` (docs/gradients.md).

- The closed-form models (``single``, ``fastmsx``, ``compensated``; conductor and dielectric): drjit's
  forward- and reverse-mode derivatives of ``eval``, ``pdf`` and the ``sample`` weight, with respect to
  every parameter ``mi.traverse`` exposes, equal central finite differences of the same calls at fixed
  directions and sample numbers. These are deterministic: the tolerance is float32 rounding of the two
  evaluations divided by the step, plus the step's truncation error (both below), so a wrong sign or a
  factor 2 fails by orders of magnitude.
- Rendered with Mitsuba's ``prb``: the derivative of the image mean by forward and by reverse mode equals
  the central difference of renders at the same seeds, within the noise of the paired per-seed differences
  (a z-test; the Šidák threshold of a family-wise false-alarm rate of 1e-3 over this file's render checks).
- The walks ``uncorrelated``, ``correlated``, ``heitz`` and ``invariance``: their derivative per call, through a symbolic
  call as in a render, forward and reverse, against central differences of the mean estimate (a z-test),
  and rendered as above (including BSDF-sampled paths: the walk samples its proposal while differentiated).
- A walk not declared differentiable, and a glass walk not declared differentiable in its IOR, refuse to be
  differentiated (one line naming the differentiable models) instead of returning a gradient that is wrong:
  plain AD through a walk gave the opposite sign of the finite difference, and a glass walk's score in η
  drawn in the space of directions misses a moving edge (docs/gradients.md).
"""

import math
from statistics import NormalDist

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH first)

np = pytest.importorskip("numpy")
mi = pytest.importorskip("mitsuba")
import drjit as dr  # noqa: E402

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import jit_support  # noqa: E402

LANES = 512
# float32 evaluations of f carry a relative rounding error of a few hundred ulps at most through these
# formulas (tables, Fresnel, visible normals); the differences below divide it by h (the bound sums the four
# evaluations' errors with Richardson's weights, 4/3 · 1/(2h) and 1/3 · 1/(4h), rounded up to 1/h).
ULPS = 256
EPS32 = 2.0 ** -24
# Truncation of the extrapolated central difference (below): O(h⁴) with h = 5e-3 of the parameter's scale,
# far below 1e-3 of the derivative for smooth f; allowed 1e-3 (a factor 2 or a sign is 1 or 2).
TRUNCATION = 1e-3
SEEDS = 12  # render checks: paired per-seed differences


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():
        yield


# (label, plugin dictionary): every closed-form model of the engine, GGX and Beckmann, isotropic and not.
CASES = [
    ("conductor single ggx", {"material": "Cu", "model": "single", "distribution": "ggx", "alpha": 0.437}),
    ("conductor single beckmann aniso", {"material": "Au", "model": "single", "distribution": "beckmann",
                                         "alpha_u": 0.263, "alpha_v": 0.581}),
    ("conductor fastmsx", {"material": "Cu", "model": "fastmsx", "distribution": "ggx", "alpha": 0.613}),
    ("conductor compensated", {"material": "Cu", "model": "compensated", "distribution": "ggx", "alpha": 0.737}),
    ("conductor compensated aniso", {"material": "Al", "model": "compensated", "alpha_u": 0.347,
                                     "alpha_v": 0.853}),
    ("dielectric single", {"surface": "dielectric", "model": "single", "int_ior": 1.5, "alpha": 0.419,
                           "specular_transmittance": 0.9}),
    ("dielectric compensated", {"surface": "dielectric", "model": "compensated", "int_ior": 1.33,
                                "alpha": 0.671, "specular_reflectance": 0.8}),
]


def load(params):
    return mi.load_dict({"type": "msx_posfree", **params})


def directions(n, seed, lower):
    """n (ω_i, ω_o) pairs: ω_i above, ω_o above or (``lower``: half of them) below, none near grazing."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0.05, 1.35, n), rng.uniform(0.05, 1.35, n)
    pi, po = rng.uniform(0, 2 * math.pi, (2, n))
    wi = np.stack([np.sin(ti) * np.cos(pi), np.sin(ti) * np.sin(pi), np.cos(ti)])
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)])
    if lower:
        wo[2, n // 2:] *= -1.0
    return wi.astype(np.float32), wo.astype(np.float32)


def lobe_probability(wi, wo, eta):
    """The probability with which a dielectric's sampler chose the lobe of (ω_i, ω_o) (numpy, per lane): F for a
    reflection, 1 − F for a refraction, at the generalised half vector, with Mitsuba's ``fresnel``."""
    reflect = wi[2] * wo[2] > 0.0
    eta_r = np.where(wi[2] > 0.0, eta, 1.0 / eta)
    m = wi + wo * np.where(reflect, 1.0, eta_r)
    m = m / np.linalg.norm(m, axis=0)
    m = m * np.sign(m[2])
    cos_i = (wi * m).sum(axis=0)
    eta_it = np.where(cos_i >= 0.0, eta, 1.0 / eta)
    cos_i = np.abs(cos_i)
    cos_t2 = 1.0 - (1.0 - cos_i * cos_i) / (eta_it * eta_it)
    cos_t = np.sqrt(np.maximum(cos_t2, 0.0))
    r_s = (cos_i - eta_it * cos_t) / (cos_i + eta_it * cos_t)
    r_p = (eta_it * cos_i - cos_t) / (eta_it * cos_i + cos_t)
    f = np.where(cos_t2 <= 0.0, 1.0, 0.5 * (r_s * r_s + r_p * r_p))
    return np.where(reflect, f, 1.0 - f)


def interaction(wi):
    n = wi.shape[1]
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(c) for c in wi])
    si.p = mi.Point3f(mi.Float(np.arange(n, dtype=np.float32)), mi.Float(0.0), mi.Float(0.0))
    return si


def outputs(b, si, wo, u):
    """eval, pdf, sample weight and the sampled ω_o, flattened (channels × lanes); drjit values."""
    ctx = mi.BSDFContext()
    f = b.eval(ctx, si, wo)
    p = b.pdf(ctx, si, wo)
    bs, w = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
    return f, p, w, bs.wo


def as_np(values):
    out = []
    for v in values:
        dr.eval(v)
        out.append(np.array(v, dtype=np.float64).reshape(-1, dr.width(v)) if dr.depth_v(v) > 1 else
                   np.array(v, dtype=np.float64)[None, :])
    return out


def parameters(b):
    """The differentiable parameters of a BSDF: {key: (value, direction of the derivative)}."""
    p = mi.traverse(b)
    keys = [k for k in p.keys() if p.flags(k) & int(mi.ParamFlags.NonDifferentiable) == 0]
    out = {}
    for k in keys:
        v = p[k]
        if dr.depth_v(v) > 1:  # a colour: one direction through its channels
            direction = type(v)(1.0, 0.5, -0.7)
        else:
            direction = type(v)(1.0)
        out[k] = (type(v)(v), direction)
    return p, out


@pytest.mark.parametrize("label, params", CASES, ids=[c[0] for c in CASES])
def test_closed_form_models_differentiate_like_finite_differences(label, params):
    b = load(params)
    dielectric = params.get("surface") == "dielectric"
    wi, wo_np = directions(LANES, 3, lower=dielectric)
    si = interaction(wi)
    wo = mi.Vector3f(*[mi.Float(c) for c in wo_np])
    u = np.random.default_rng(5).uniform(0.0, 1.0, (3, LANES)).astype(np.float32)
    p, params_ = parameters(b)
    assert params_, f"{label}: mi.traverse lists no differentiable parameter"
    names = ("eval", "pdf", "sample weight")
    for key, (x0, v) in params_.items():
        scale = max(float(dr.max(dr.abs(dr.ravel(x0)))[0] if dr.depth_v(x0) > 1 else dr.abs(x0)[0]), 0.1)
        h = 5e-3 * scale

        def at(t):
            p[key] = type(x0)(x0 + t * v)
            p.update()
            return as_np(outputs(b, si, wo, u))

        base, plus, minus, plus2, minus2 = at(0.0), at(h), at(-h), at(2 * h), at(-2 * h)
        # Forward mode.
        p[key] = type(x0)(x0)
        dr.enable_grad(p[key])
        p.update()
        x = p[key]
        out = outputs(b, si, wo, u)
        dr.set_grad(x, v)
        dr.forward_to(*out[:3])
        fwd = as_np([dr.grad(o) for o in out[:3]])
        # Reverse mode: random weights on every output, against the forward derivatives.
        p[key] = type(x0)(x0)
        dr.enable_grad(p[key])
        p.update()
        x = p[key]
        out = outputs(b, si, wo, u)
        rng = np.random.default_rng(7)
        weights = [rng.normal(size=a.shape) for a in fwd]
        loss = 0.0
        for o, wgt in zip(out[:3], weights):
            arr = o if dr.depth_v(o) > 1 else [o]
            for c in range(len(weights[0]) if dr.depth_v(o) > 1 else 1):
                loss = loss + dr.sum(arr[c] * mi.Float(wgt[c].astype(np.float32)))
        dr.backward(loss)
        g = dr.grad(x)
        rev = float(dr.sum(g * v)[0]) if dr.depth_v(g) > 1 else float((g * v)[0])
        expected_rev = sum(float((a * wgt).sum()) for a, wgt in zip(fwd, weights))
        p[key] = type(x0)(x0)
        p.update()
        # The sample weight is compared where the sampled direction moved smoothly: over [x − 2h, x + 2h]
        # twice as far as over [x − h, x + h] (a lane whose lobe choice flips has no derivative there, and
        # its jump breaks that ratio), and stayed valid, or invalid, throughout (crossing the horizon).
        moved1 = np.abs(plus[3] - minus[3]).max(axis=0)
        moved2 = np.abs(plus2[3] - minus2[3]).max(axis=0)
        valid = np.stack([np.any(o[2] != 0.0, axis=0) for o in (plus, minus, plus2, minus2)])
        smooth = (np.abs(moved2 - 2.0 * moved1) <= 0.25 * moved2 + 1e-5) & (valid.any(axis=0) == valid.all(axis=0))
        assert smooth.mean() > 0.9, f"{label} {key}: the sampled directions jump on {1 - smooth.mean():.2%} of lanes"
        score = 0.0
        if dielectric:
            # A dielectric's sampler picks its lobe with a detached probability P (F or 1 − F) and, as
            # roughdielectric does, its weight P/P keeps P's derivative: dw = d(value) + w·d ln P, where finite
            # differences at fixed random numbers see only the first term. d ln P from the sampled directions.
            eta0 = float(x0[0]) if key == "eta" else params["int_ior"] / params.get("ext_ior", 1.000277)

            def log_p(o, t):
                return np.log(np.maximum(lobe_probability(wi, o[3], eta0 + (t * float(v[0]) if key == "eta" else 0.0)),
                                         1e-30))

            s1 = (log_p(plus, h) - log_p(minus, -h)) / (2.0 * h)
            s2 = (log_p(plus2, 2 * h) - log_p(minus2, -2 * h)) / (4.0 * h)
            score = (4.0 * s1 - s2) / 3.0
        for name, f0, f_plus, f_minus, f_plus2, f_minus2, d in zip(names, base, plus, minus, plus2, minus2, fwd):
            # Richardson's extrapolation of central differences at h and 2h: the h² error term cancels.
            d1, d2 = (f_plus - f_minus) / (2.0 * h), (f_plus2 - f_minus2) / (4.0 * h)
            fd = (4.0 * d1 - d2) / 3.0
            if name == "sample weight":
                fd = fd + f0 * score
            rounding = ULPS * EPS32 * (np.abs(f_plus) + np.abs(f_minus) + np.abs(f_plus2) + np.abs(f_minus2)) / h
            # Where f curves fast (a lobe near the horizon), the h⁴ term is not small: bounded by the h² term
            # that the extrapolation removed, |d1 − d2|. Where f has a kink at x (a min or max in a formula)
            # the derivative is one-sided: anything between the slopes on either side, |(f₊ − f₀) − (f₀ − f₋)|/h
            # apart (h·|f''| where f is smooth), is right.
            kink = np.abs((f_plus - f0) - (f0 - f_minus)) / h
            tol = rounding + np.abs(d1 - d2) + kink + TRUNCATION * (np.abs(fd) + np.abs(fd).max())
            ok = np.abs(d - fd) <= tol
            if name == "sample weight":
                ok |= ~smooth[None, :]
            bad = ~ok
            compared = np.broadcast_to(smooth[None, :] if name == "sample weight" else True, d.shape)
            print(f"{label} {key} {name}: |d| max {np.abs(d).max():.4g}, worst |AD − FD|/tol "
                  f"{(np.abs(d - fd) / np.maximum(tol, 1e-30))[compared].max():.3g}")
            assert np.all(np.isfinite(d)), f"{label} {key} {name}: non-finite derivative"
            assert not bad.any(), (f"{label} {key} {name}: AD {d[bad][:4]} vs finite difference {fd[bad][:4]} "
                                   f"on {bad.mean():.2%} of lanes")
        assert abs(rev - expected_rev) <= 1e-3 * (abs(expected_rev) + 1e-6 * LANES), (
            f"{label} {key}: reverse mode {rev} vs forward mode {expected_rev}")


# ------------------------------------------------------------------ renders

def scene(bsdf):
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "prb", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 32, "to_world": look,
                   "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}}},
        "sky": {"type": "constant", "radiance": 0.5},
        "sun": {"type": "directional", "direction": [0.4, -0.3, -1.0], "irradiance": 3.0},
        "ball": {"type": "sphere", "radius": 1.0, "bsdf": bsdf}})


RENDERED = [
    ("single", {"type": "msx_posfree", "material": "Cu", "model": "single", "alpha": 0.5}, "ball.bsdf.alpha.value"),
    ("compensated", {"type": "msx_posfree", "material": "Cu", "model": "compensated", "alpha": 0.8},
     "ball.bsdf.alpha.value"),
    ("compensated eta", {"type": "msx_posfree", "material": "Cu", "model": "compensated", "alpha": 0.8},
     "ball.bsdf.eta.value"),
    ("dielectric compensated", {"type": "msx_posfree", "surface": "dielectric", "model": "compensated",
                                "int_ior": 1.5, "alpha": 0.3}, "ball.bsdf.alpha.value"),
    ("dielectric eta", {"type": "msx_posfree", "surface": "dielectric", "model": "compensated", "int_ior": 1.5,
                        "alpha": 0.6}, "ball.bsdf.eta"),
    ("correlated", {"type": "msx_posfree", "material": "Cu", "model": "correlated", "alpha": 0.5},
     "ball.bsdf.alpha.value"),
    ("uncorrelated", {"type": "msx_posfree", "material": "Au", "model": "uncorrelated", "alpha": 1.2},
     "ball.bsdf.alpha.value"),
    ("invariance", {"type": "msx_posfree", "material": "Cu", "model": "invariance", "alpha": 0.7},
     "ball.bsdf.alpha.value"),
    ("heitz", {"type": "msx_posfree", "material": "Cu", "model": "heitz", "alpha": 0.8}, "ball.bsdf.alpha.value"),
    ("diffuse correlated", {"type": "msx_posfree", "surface": "diffuse", "model": "correlated", "alpha": 0.8,
                            "reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}}, "ball.bsdf.alpha.value"),
    ("diffuse reflectance", {"type": "msx_posfree", "surface": "diffuse", "model": "uncorrelated", "alpha": 0.6,
                                   "reflectance": {"type": "rgb", "value": [0.9, 0.6, 0.2]}},
     "ball.bsdf.reflectance.value"),
    ("diffuse heitz reflectance", {"type": "msx_posfree", "surface": "diffuse", "model": "heitz", "alpha": 0.6,
                                   "reflectance": {"type": "rgb", "value": [0.9, 0.6, 0.2]}},
     "ball.bsdf.reflectance.value"),
]
RENDER_CHECKS = 2 * 2 * len(RENDERED)  # forward and reverse × two losses × the rendered cases
Z_MAX = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / RENDER_CHECKS)) / 2.0)


@pytest.mark.parametrize("label, bsdf, key", RENDERED, ids=[r[0] for r in RENDERED])
def test_rendered_gradients_equal_finite_differences_within_noise(label, bsdf, key):
    """prb's derivative of two linear losses — the image mean and a per-pixel weighted sum (a ramp across
    the image, weighted per channel) — forward and reverse, against central differences at the same seeds
    (the same paths up to the parameter's effect): paired per seed, z-test of the mean difference."""
    sc = scene(bsdf)
    p = mi.traverse(sc)
    x0 = type(p[key])(p[key])
    v = type(x0)(1.0, 0.5, -0.7) if dr.depth_v(x0) > 1 else type(x0)(1.0)
    # The step: 1 % of the value, 4 % for the IOR (refraction and the reflect-or-refract choice move every
    # path through the glass: the paired difference's noise falls with the step).
    h = (4e-2 if key.endswith(".eta") else 1e-2) * (0.8 if dr.depth_v(x0) > 1 else float(x0[0]))
    spp = 32
    # Per-pixel weights: a ramp across the image times a colour (a gradient put on the wrong pixels or
    # channels changes this loss's derivative, not the mean's).
    ramp = np.linspace(0.0, 2.0, 24)[None, :, None] * np.array([1.0, 0.3, 1.7])[None, None, :]
    weights = mi.TensorXf(np.broadcast_to(ramp, (24, 24, 3)).astype(np.float32))

    def losses(img):
        return dr.mean(img, axis=None), dr.mean(img * weights, axis=None)

    def mean(img):
        return np.array([float(x.array[0]) for x in losses(img)])

    def primal(t, seed):
        p[key] = type(x0)(x0 + t * v)
        p.update()
        with dr.suspend_grad():
            return mean(mi.render(sc, spp=spp, seed=seed))

    fd, fwd, rev = [], [], []
    for seed in range(SEEDS):
        fd.append((primal(h, seed) - primal(-h, seed)) / (2 * h))
        p[key] = type(x0)(x0)
        dr.enable_grad(p[key])
        p.update()
        img = mi.render(sc, params=p, spp=spp, seed=seed)
        dr.set_grad(p[key], v)
        dr.forward_to(img)
        fwd.append(mean(dr.grad(img)))
        r = []
        for which in range(2):  # one render per loss: a backward pass consumes the render's graph
            p[key] = type(x0)(x0)
            dr.enable_grad(p[key])
            p.update()
            img = mi.render(sc, params=p, spp=spp, seed=seed)
            dr.backward(losses(img)[which])
            g = dr.grad(p[key])
            r.append(float(dr.sum(g * v)[0]) if dr.depth_v(g) > 1 else float((g * v)[0]))
        rev.append(r)
    p[key] = type(x0)(x0)
    p.update()
    fd = np.array(fd)
    for mode, ad in (("forward", np.array(fwd)), ("reverse", np.array(rev))):
        for which, loss in enumerate(("image mean", "weighted pixels")):
            d = ad[:, which] - fd[:, which]
            se = d.std(ddof=1) / math.sqrt(SEEDS)
            z = d.mean() / se if se > 0 else (0.0 if d.mean() == 0 else math.inf)
            print(f"{label} {mode} {loss}: AD {ad[:, which].mean():.5f} ± {ad[:, which].std(ddof=1) / SEEDS ** 0.5:.5f}, "
                  f"FD {fd[:, which].mean():.5f}, paired z {z:+.2f}")
            assert np.all(np.isfinite(ad)), f"{label} {mode}: non-finite gradient"
            assert abs(z) <= Z_MAX, f"{label} {mode} {loss}: AD {ad[:, which].mean():.5f} vs FD {fd[:, which].mean():.5f}, z = {z:.2f}"
    se_fd = fd.std(axis=0, ddof=1) / math.sqrt(SEEDS)
    assert np.all(np.abs(fd.mean(axis=0)) > 3 * se_fd), f"{label}: a derivative is lost in noise ({fd.mean(axis=0)} ± {se_fd})"


SINGLE_TWINS = [
    ("roughconductor alpha", "roughconductor", {"material": "Cu", "alpha": 0.5}, {"material": "Cu"},
     "ball.bsdf.alpha.value"),
    ("roughdielectric eta", "roughdielectric", {"int_ior": 1.5, "alpha": 0.3}, {"surface": "dielectric"},
     "ball.bsdf.eta"),
    ("roughdielectric alpha", "roughdielectric", {"int_ior": 1.33, "alpha": 0.6}, {"surface": "dielectric"},
     "ball.bsdf.alpha.value"),
]


@pytest.mark.parametrize("label, builtin, common, ours, key", SINGLE_TWINS, ids=[t[0] for t in SINGLE_TWINS])
def test_single_renders_the_gradient_of_the_builtin(label, builtin, common, ours, key):
    """``single`` is Mitsuba's ``roughconductor`` / ``roughdielectric``: the same prb gradient at the same
    seeds, to float32 (the two accumulate in other orders: 1e-3 relative)."""
    grads = []
    for bsdf in ({"type": builtin, **common}, {"type": "msx_posfree", "model": "single", **ours, **common}):
        sc = scene(bsdf)
        p = mi.traverse(sc)
        dr.enable_grad(p[key])
        p.update()
        img = mi.render(sc, params=p, spp=16, seed=3)
        dr.backward(dr.mean(img, axis=None))
        grads.append(float(dr.grad(p[key])[0]))
    print("%s: built-in %.6f, single %.6f" % (label, *grads))
    assert grads[0] != 0.0 and abs(grads[1] - grads[0]) <= 1e-3 * abs(grads[0])


def test_eta_updates_like_roughdielectric():
    """``eta`` is the relative IOR as in ``roughdielectric``: setting it gives the values of a BSDF built with
    that IOR (``auto``'s per-side rules included: at α = 0.45 they differ between η = 1.5 and 1.8 for ω_i
    near the normal), and a value the core refuses (index-matched, not finite) gives zeros rather than NaN."""
    n = 1 << 16
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(0.1, 0.0, float(math.sqrt(0.99)))
    si.p = mi.Point3f(mi.Float(np.arange(n, dtype=np.float32)), 0.0, 0.0)
    wo = mi.Vector3f(-0.3, 0.2, float(-math.sqrt(0.87)))  # transmitted
    ctx = mi.BSDFContext()

    def values(b):
        return np.array(b.eval(ctx, si, wo), dtype=np.float64)

    bsdf = {"type": "msx_posfree", "surface": "dielectric", "model": "auto", "alpha": 0.45, "ext_ior": 1.0}
    b = load({**bsdf, "int_ior": 1.5})
    p = mi.traverse(b)
    assert abs(float(p["eta"][0]) - 1.5) < 1e-6
    before = values(b)
    p["eta"] = 1.8
    p.update()
    after, fresh = values(b), values(load({**bsdf, "int_ior": 1.8}))
    assert np.array_equal(after, fresh)
    assert not np.array_equal(after, before)
    for bad in (1.0, float("nan"), float("inf")):
        p["eta"] = bad
        p.update()
        v = values(b)
        assert np.all(v == 0.0), f"eta = {bad}: {v[v != 0.0][:4]}"


def refusal(sc, p):
    """The messages (the exception and its causes) of a differentiated render of ``sc`` that must refuse."""
    with pytest.raises(Exception) as e:
        img = mi.render(sc, params=p, spp=4, seed=0)
        dr.backward(dr.mean(img, axis=None))
    chain, err = [], e.value
    while err is not None:
        chain.append(str(err))
        err = err.__cause__ or err.__context__
    return "\n".join(chain)


def test_a_walk_without_gradients_refuses_in_one_line(monkeypatch):
    """Every walk the engine renders differentiates today; one without its gradient (a new walk whose
    ``differentiable`` is False — here ``heitz`` on Lambertian facets, made so for the test) refuses in one
    line at the first differentiated render instead of returning drjit's AD of the walk as written, which is
    biased; without gradients the same scene renders."""
    from msx.jit import bsdf as engine
    from msx.jit import heitz

    model, surface, key = "heitz", "diffuse", "reflectance.value"
    monkeypatch.setattr(heitz.DIFFUSE_WALKS[model], "differentiable", False)
    monkeypatch.setitem(engine.DIFFERENTIABLE_MODELS, surface,
                        tuple(m for m in engine.DIFFERENTIABLE_MODELS[surface] if m != model))
    sc = scene({"type": "msx_posfree", "surface": surface, "model": model, "alpha": 0.5})
    p = mi.traverse(sc)
    key = "ball.bsdf." + key
    dr.enable_grad(p[key])
    p.update()
    text = refusal(sc, p)
    assert f"model='{model}' on surface '{surface}' is not differentiable" in text, text[-2000:]
    assert "single, fastmsx, compensated, uncorrelated, correlated, heitz, invariance, auto (conductor)" in text
    # Without gradients the same scene renders.
    dr.disable_grad(p[key])
    p.update()
    img = mi.render(sc, spp=4, seed=0)
    assert np.all(np.isfinite(np.array(img)))


def test_subnormal_values_give_no_nan_gradient():
    """A walk's estimate can be subnormal, and prb divides by the sample's weight × pdf: where subnormals are
    not flushed (drjit's thread count 1 runs kernels on the calling thread) 1/x overflowed and the albedo
    gradient of ``heitz`` on Lambertian facets had a NaN pixel in every render of this scene (32 spp, seeds
    0–2) before the engine returned such values as 0 (jit/bsdf.py ``flush_subnormal``)."""
    bsdf = {"type": "msx_posfree", "surface": "diffuse", "model": "heitz", "alpha": 0.6,
            "reflectance": {"type": "rgb", "value": [0.9, 0.6, 0.2]}}
    sc = scene(bsdf)
    p = mi.traverse(sc)
    key = "ball.bsdf.reflectance.value"
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for seed in range(3):
            dr.enable_grad(p[key])
            p.update()
            img = mi.render(sc, params=p, spp=32, seed=seed)
            dr.set_grad(p[key], 1.0)
            dr.forward_to(img)
            g = np.array(dr.grad(img))
            assert np.all(np.isfinite(g)), f"seed {seed}: {np.count_nonzero(~np.isfinite(g))} non-finite entries"
    finally:
        dr.set_thread_count(threads)
        dr.disable_grad(p[key])
        p.update()


# The glass walks: every one differentiates in η (docs/gradients.md, "The IOR of the glass walks": drawn in the
# space of normals, with the next-event edge terms).
ETA_GLASS_WALKS = ["correlated", "uncorrelated", "heitz", "invariance", "auto"]


def test_a_glass_walk_without_unbiased_eta_refuses_eta_gradients(monkeypatch):
    """A glass walk whose derivative in η would be biased (a new walk whose ``eta_differentiable`` is False —
    here ``heitz``, made so for the test; a walk drawing its directions in the space of directions misses the
    moving edge of the refraction density) refuses a render differentiated in ``eta`` in one line naming those
    that differentiate in η; differentiated in ``alpha`` it runs; per call (at trace time, before anything
    compiles) it refuses, and every glass walk of the engine and the closed forms do not."""
    from msx.jit import heitz

    si = jit_support.lanes_si((0.3, 0.0, 0.954), 16, 0)
    wo = mi.Vector3f(-0.3, 0.1, -0.95)
    for model in ETA_GLASS_WALKS + ["single", "compensated"]:
        b = mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "model": model, "alpha": 0.5})
        q = mi.traverse(b)
        dr.enable_grad(q["eta"])
        q.update()
        assert np.all(np.isfinite(np.array(b.eval(mi.BSDFContext(), si, wo)))), model
    monkeypatch.setattr(heitz.DIELECTRIC_WALKS["heitz"], "eta_differentiable", False)
    sc = scene({"type": "msx_posfree", "surface": "dielectric", "model": "heitz", "alpha": 0.5})
    p = mi.traverse(sc)
    dr.enable_grad(p["ball.bsdf.eta"])
    p.update()
    text = refusal(sc, p)
    assert "model='heitz' on surface 'dielectric' is not differentiable in 'eta'" in text, text[-2000:]
    assert "single, compensated, uncorrelated, correlated, invariance, auto differentiate in 'eta'" in text, text[-2000:]
    dr.disable_grad(p["ball.bsdf.eta"])
    dr.enable_grad(p["ball.bsdf.alpha.value"])
    p.update()
    img = mi.render(sc, params=p, spp=4, seed=0)
    dr.backward(dr.mean(img, axis=None))
    g = dr.grad(p["ball.bsdf.alpha.value"])
    assert np.all(np.isfinite(np.array(g))) and float(dr.abs(g)[0]) > 0.0
    b = mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "model": "heitz", "alpha": 0.5})
    q = mi.traverse(b)
    dr.enable_grad(q["eta"])
    q.update()
    with pytest.raises(Exception, match="not differentiable in 'eta'"):
        b.eval(mi.BSDFContext(), si, wo)
    # A symbolic call traces every registered BSDF: none may be left refusing for the tests after this one.
    dr.disable_grad(q["eta"])
    q.update()
    dr.disable_grad(p["ball.bsdf.alpha.value"])
    p.update()


# ------------------------------------------------------------------ the position-free walks, per call

WALK_LANES = 1 << 20


WALKS = [("correlated", "conductor"), ("uncorrelated", "conductor"), ("heitz", "conductor"),
         ("invariance", "conductor"), ("correlated", "diffuse"), ("uncorrelated", "diffuse"), ("heitz", "diffuse"),
         ("correlated", "dielectric"), ("uncorrelated", "dielectric"), ("heitz", "dielectric"), ("auto", "conductor"),
         ("auto", "dielectric"), ("invariance", "dielectric"), ("invariance below reflected", "dielectric"),
         ("correlated below", "dielectric"), ("correlated below reflected", "dielectric"), ("heitz below", "dielectric"),
         ("invariance below", "dielectric"), ("correlated aniso", "conductor"), ("heitz below aniso", "dielectric"),
         ("correlated bdpt", "conductor"), ("invariance bdpt", "conductor")]
DIFFUSE_ALBEDO = {"type": "rgb", "value": [0.8, 0.6, 0.4]}


def walk_keys(model, surface):
    """(key, h, direction) of the parameters a walk's check differentiates: every one ``mi.traverse`` lists.
    α; a conductor's η and k (its Fresnel term, inside the walk), a diffuse surface's albedo, a glass's IOR.
    The tints (``specular_reflectance``, ``specular_transmittance``) multiply the walk's estimate outside it
    (jit/bsdf.py) whatever the walk: checked on ``correlated`` only, each where it acts (the reflection's on a
    conductor and on glass with ω_o reflected, the transmission's with ω_o transmitted)."""
    colour = (1.0, 0.5, -0.7)
    name, *options = model.split()
    keys = [("alpha_u.value", 0.02, None), ("alpha_v.value", 0.02, None)] if "aniso" in options else \
        [("alpha.value", 0.02, None)]
    if surface == "conductor":
        keys += [("eta.value", 0.02, colour), ("k.value", 0.02, colour)]
    elif surface == "diffuse":
        keys.append(("reflectance.value", 0.02, colour))
    elif name in ETA_GLASS_WALKS:
        keys.append(("eta", 0.02, None))
    if name == "correlated" and not {"bdpt", "aniso"} & set(options) and surface != "diffuse":
        tint = "specular_transmittance" if surface == "dielectric" and "reflected" not in options else "specular_reflectance"
        keys.append((tint + ".value", 0.02, colour))
    return keys


# Per channel, every key of every walk.
WALK_CHECKS = 3 * sum(len(walk_keys(model, surface)) for model, surface in WALKS)
Z_WALK = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / WALK_CHECKS)) / 2.0)


@pytest.mark.parametrize("model, surface", WALKS, ids=["%s %s" % w for w in WALKS])
def test_walks_differentiate_without_bias(model, surface):
    """The walk's derivative (detached directions, density ratios, detached roulette: docs/gradients.md)
    through a symbolic call, forward and reverse, against central differences of the mean estimate over
    2²⁰ lanes at one (ω_i, ω_o): z-test on the two means (the differences are noisy: the walk at α ± h
    draws other paths)."""
    material = {"conductor": {"material": "Cu"}, "diffuse": {"surface": "diffuse", "reflectance": DIFFUSE_ALBEDO},
                "dielectric": {"surface": "dielectric", "int_ior": 1.5}}[surface]
    # "model [bdpt] [below] [reflected] [aniso]": the estimator; ω_i below the surface (inside the glass); the
    # dielectric's ω_o on ω_i's side (by default it is transmitted: the reflected side is the conductor's case);
    # α_u ≠ α_v.
    keys = walk_keys(model, surface)
    model, *options = model.split()
    roughness = {"alpha_u": 0.4, "alpha_v": 0.7} if "aniso" in options else {"alpha": 0.5}
    b = mi.load_dict({"type": "msx_posfree", **material, "model": model, "distribution": "ggx", **roughness,
                      "estimator": "bdpt" if "bdpt" in options else "pt"})
    p = mi.traverse(b)
    n = WALK_LANES
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    side = -1.0 if "below" in options else 1.0
    si.wi = mi.Vector3f(float(math.sin(0.5)), 0.0, side * float(math.cos(0.5)))
    si.p = mi.Point3f(mi.Float(np.arange(n, dtype=np.float32)), 0.0, 0.0)
    across = surface == "dielectric" and "reflected" not in options
    wo = dr.normalize(mi.Vector3f(-0.5, 0.4, side * (-0.77 if across else 0.77)))
    ptr = dr.gather(mi.BSDFPtr, mi.BSDFPtr(b), dr.zeros(mi.UInt32, n))  # as a render calls it
    ctx = mi.BSDFContext()
    for key, h, v in keys:
        x0 = type(p[key])(p[key])
        direction = type(x0)(*v) if v and dr.depth_v(x0) > 1 else type(x0)(1.0)

        def mean_eval(t):
            p[key] = type(x0)(x0 + t * direction)
            p.update()
            f = np.array(ptr.eval(ctx, si, wo), dtype=np.float64)
            return f

        fp, fm = mean_eval(h), mean_eval(-h)
        fd = (fp - fm) / (2 * h)
        p[key] = type(x0)(x0)
        dr.enable_grad(p[key])
        p.update()
        f = ptr.eval(ctx, si, wo)
        dr.set_grad(p[key], direction)
        dr.forward_to(f)
        fwd = np.array(dr.grad(f), dtype=np.float64)
        p[key] = type(x0)(x0)
        dr.enable_grad(p[key])
        p.update()
        f = ptr.eval(ctx, si, wo)
        dr.backward(dr.sum(f[0] + f[1] + f[2]) / n)
        g = dr.grad(p[key])
        rev = float(dr.sum(g * direction)[0]) if dr.depth_v(g) > 1 else float((g * direction)[0])
        p[key] = type(x0)(x0)
        p.update()
        for c in range(3):
            se = math.hypot(fd[c].std(ddof=1), fwd[c].std(ddof=1)) / math.sqrt(n)
            z = (fwd[c].mean() - fd[c].mean()) / se
            print(f"{model} {surface} {key} channel {c}: AD {fwd[c].mean():.5f}, FD {fd[c].mean():.5f} ± "
                  f"{fd[c].std(ddof=1) / math.sqrt(n):.5f}, z {z:+.2f}")
            assert abs(z) <= Z_WALK, f"{model} {key} channel {c}: AD {fwd[c].mean()} vs FD {fd[c].mean()}"
            assert abs(fd[c].mean()) > 5 * fd[c].std(ddof=1) / math.sqrt(n), "the derivative is lost in noise"
        expected = float(sum(fwd[c].mean() for c in range(3)))
        assert abs(rev - expected) <= 1e-3 * abs(expected), f"{model} {key}: reverse {rev} vs forward {expected}"


# ------------------------------------------------------------------ sampling while differentiated

TRACED_SAMPLING = [("correlated", "conductor"), ("correlated bdpt", "conductor"), ("correlated", "diffuse"),
                   ("heitz", "diffuse"), ("correlated", "dielectric"), ("heitz", "dielectric"),
                   ("invariance", "dielectric")]
Z_SAMPLING = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / len(TRACED_SAMPLING))) / 2.0)


@pytest.mark.parametrize("model, surface", TRACED_SAMPLING, ids=["%s %s" % c for c in TRACED_SAMPLING])
def test_traced_sample_weighs_eval_by_its_own_density(model, surface):
    """What prb relies on while a walk is differentiated: ``sample``'s weight × pdf is ``eval`` at the sampled
    direction (the same estimate: same lane key), ``pdf`` reports the sampled pdf, and that pdf is the density
    the directions are drawn from — E[|cos θ_o|/pdf] over the sampled directions is the integral of |cos θ_o|
    over the directions the proposal reaches (π per hemisphere; a z-test over 2²⁰ lanes)."""
    material = {"conductor": {"material": "Cu"}, "diffuse": {"surface": "diffuse", "reflectance": DIFFUSE_ALBEDO},
                "dielectric": {"surface": "dielectric", "int_ior": 1.5}}[surface]
    model, _, estimator = model.partition(" ")
    b = mi.load_dict({"type": "msx_posfree", **material, "model": model, "alpha": 0.6, "estimator": estimator or "pt"})
    p = mi.traverse(b)
    dr.enable_grad(p["alpha.value"])
    p.update()
    n = 1 << 20
    rng = np.random.default_rng(11)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = dr.normalize(mi.Vector3f(0.6, -0.2, 0.7))
    si.p = mi.Point3f(mi.Float(np.arange(n, dtype=np.float32)), 0.0, 0.0)
    u = rng.uniform(0.0, 1.0, (3, n)).astype(np.float32)
    ctx = mi.BSDFContext()
    with dr.suspend_grad():
        bs, w = b.sample(ctx, si, mi.Float(u[0]), mi.Point2f(mi.Float(u[1]), mi.Float(u[2])))
        f = b.eval(ctx, si, bs.wo)
        pdf = b.pdf(ctx, si, bs.wo)
    w, f, pdf_s, pdf = (np.array(x, dtype=np.float64) for x in (w, f, bs.pdf, pdf))
    wo_z = np.array(bs.wo.z, dtype=np.float64)
    ok = pdf_s > 0.0
    assert ok.mean() > 0.9, f"only {ok.mean():.1%} of the samples are valid"
    assert np.allclose(pdf[ok], pdf_s[ok], rtol=1e-5), "pdf() differs from the sampled pdf"
    assert np.allclose((w * pdf_s)[:, ok], f[:, ok], rtol=1e-4, atol=1e-7), "weight × pdf differs from eval"
    x = np.where(ok, np.abs(wo_z) / np.where(ok, pdf_s, 1.0), 0.0)
    expected = 2.0 * math.pi if surface == "dielectric" else math.pi
    # (the cosine lobe alone has |cos θ_o|/pdf = π on every lane: float32 rounding is its only spread)
    z = (x.mean() - expected) / max(x.std(ddof=1) / math.sqrt(n), 1e-6 * expected)
    print(f"{model} {surface}: E[|cos|/pdf] = {x.mean():.5f} (expected {expected:.5f}), z = {z:+.2f}")
    assert abs(z) <= Z_SAMPLING, f"the proposal's pdf is not its density: {x.mean()} vs {expected}"
