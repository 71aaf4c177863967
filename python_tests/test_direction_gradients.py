"""Gradients with respect to directions (a tilting shading normal: Mitsuba's ``normalmap`` and ``bumpmap``,
differentiated geometry) in the Dr.Jit engine (issue 32, item 4; docs/gradients.md).

- The closed forms (``single``, ``fastmsx``, ``compensated``) differentiate through ω_i and ω_o exactly:
  forward-mode AD of the mean of ``eval`` over fixed world directions, as the shading frame tilts, equals
  central differences. The directions stay ≥ 0.3 above the horizon at every tilt used, so no lane crosses
  the horizon (a jump that neither AD nor the built-ins' gradients see). The bound is the central
  difference's own error: its truncation, estimated by |D(h) − D(2h)| (D(2h) − D(h) = 3·O(h²)), plus float32
  rounding, ε·max|f|/h, each ×4.
- A random walk refuses such directions with one line naming the model and the alternatives, in eval and
  sample, rather than return a biased derivative (measured in docs/gradients.md) or crash drjit in reverse
  mode (``LoopOp::backward(): … requires a 'max_iterations' hint``). Directions without a gradient, with
  the walk's parameters differentiated, still run.
- Through ``prb`` and ``normalmap``: ``single`` gives the built-in's gradient; a walk stops with that line.
"""

from statistics import NormalDist

import numpy as np
import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

pytest.importorskip("mitsuba")
_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import jit_support  # noqa: E402

N, ANGLE, H = 4096, 0.2, 1e-3


@pytest.fixture(scope="module")
def table():
    """The engine's table, with the engine registered in drjit's default symbolic mode for the module (a
    module run earlier may have registered the batched route, which turns symbolic loops off)."""
    import jit_support
    from msx.jit import bsdf as jit_bsdf

    with jit_support.engine_mode():
        yield jit_bsdf


def _params(surface, model):
    p = {"type": "msx_posfree", "surface": surface, "model": model, "alpha": 0.6, "distribution": "ggx"}
    if surface == "conductor":
        p["material"] = "Cu"
    return p


def _directions(seed, sign, lift=0.6):
    """Unit world directions ≥ 0.3 above (sign +1) or below (−1) the plane at every tilt used here (``lift``
    3: within ~18° of the normal)."""
    v = np.random.default_rng(seed).normal(size=(N, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2]) + lift
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] *= sign
    return mi.Vector3f(v.T.astype(np.float32))


def _mean_eval(bsdf, angle, wi_w, wo_w):
    si = dr.zeros(mi.SurfaceInteraction3f, N)
    frame = mi.Frame3f(mi.Vector3f(dr.sin(angle), 0.0 * angle, dr.cos(angle)))
    si.sh_frame = frame
    si.wi = frame.to_local(wi_w)
    value = bsdf.eval(mi.BSDFContext(), si, frame.to_local(wo_w))
    return dr.mean(value[0]), dr.max(dr.abs(value[0]))


def closed_form_cases():
    out = [("conductor", "roughconductor"), ("dielectric", "roughdielectric")]  # the built-ins, as the control
    mi.set_variant("llvm_ad_rgb")
    from msx.jit import bsdf as jit_bsdf

    for surface, models in jit_bsdf.DIFFERENTIABLE_MODELS.items():
        walks = jit_bsdf.WALKS_BY_SURFACE.get(surface, {})
        out += [(surface, m) for m in models if jit_bsdf.walk_name_of(m) not in walks]
    return out


CLOSED_FORM_CASES = [(s, m, t) for s, m in closed_form_cases() for t in ((False, True) if s == "dielectric" else (False,))]


@pytest.mark.parametrize("surface,model,transmitted", CLOSED_FORM_CASES,
                         ids=["%s-%s-%s" % (s, m, "transmitted" if t else "reflected") for s, m, t in CLOSED_FORM_CASES])
def test_closed_form_derivative_through_directions(table, surface, model, transmitted):
    if model.startswith("rough"):
        bsdf = mi.load_dict({"type": model, "alpha": 0.6, "distribution": "ggx"}
                            | ({"material": "Cu"} if surface == "conductor" else {}))
    else:
        bsdf = mi.load_dict(_params(surface, model))
    wi_w, wo_w = _directions(1, 1.0), _directions(2, 1.0)
    if transmitted:  # ω_i near the normal, ω_o near −ω_i: far from the horizon of m and from total reflection
        wi_w = _directions(1, 1.0, lift=3.0)
        wo_w = dr.normalize(-wi_w + 0.2 * (wo_w - wi_w))
    angle = mi.Float(ANGLE)
    dr.enable_grad(angle)
    value, vmax = _mean_eval(bsdf, angle, wi_w, wo_w)
    dr.forward(angle)
    ad = dr.grad(value)[0]

    def central(h):
        return (_mean_eval(bsdf, mi.Float(ANGLE + h), wi_w, wo_w)[0][0]
                - _mean_eval(bsdf, mi.Float(ANGLE - h), wi_w, wo_w)[0][0]) / (2 * h)

    fd, fd2 = central(H), central(2 * H)
    bound = 4 * abs(fd - fd2) + 4 * float(np.finfo(np.float32).eps) * vmax[0] / H
    print("%s %s: AD %.6g, central differences %.6g (2h: %.6g), bound %.3g" % (surface, model, ad, fd, fd2, bound))
    assert value[0] > 0.0
    assert abs(ad - fd) <= bound, (surface, model, ad, fd, bound)


def _tilting_interaction(n=16):
    """16 lanes of an interaction whose shading frame tilts with a differentiated angle: its ω_i carries a
    gradient, as under a differentiated normal map."""
    angle = mi.Float(ANGLE)
    dr.enable_grad(angle)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    frame = mi.Frame3f(mi.Vector3f(dr.sin(angle), 0.0 * angle, dr.cos(angle)))
    si.sh_frame = frame
    si.wi = frame.to_local(mi.Vector3f(0.3, 0.1, 0.9))
    return si


def walk_cases():
    mi.set_variant("llvm_ad_rgb")
    import jit_support

    return [(s, m) for s, m, e in jit_support.engine_cases(walks_only=True, bdpt=False)]


@pytest.mark.parametrize("surface,model", walk_cases())
def test_walk_refuses_directions_with_gradients(table, surface, model):
    bsdf = mi.load_dict(_params(surface, model))
    si = _tilting_interaction()
    wo = mi.Vector3f(-0.2, 0.1, 0.95)
    ctx = mi.BSDFContext()
    for call in (lambda: bsdf.eval(ctx, si, wo), lambda: bsdf.eval_pdf(ctx, si, wo),
                 lambda: bsdf.sample(ctx, si, 0.3, mi.Point2f(0.4, 0.6))):
        with pytest.raises(ValueError) as e:
            call()
        message = str(e.value)
        assert "model='%s'" % model in message and "directions that carry a gradient" in message, message
        assert "\n" not in message
    # Detached directions run, with the walk's own parameters differentiated where the walk is differentiable.
    si.wi = dr.detach(si.wi)
    params = mi.traverse(bsdf)
    key = next(k for k in params.keys() if "alpha" in k)
    differentiable = model in table.DIFFERENTIABLE_MODELS.get(surface, ())
    if differentiable:
        dr.enable_grad(params[key])
        params.update()
    value = bsdf.eval(ctx, si, wo)
    assert dr.grad_enabled(value) == differentiable
    dr.eval(value)


def _normalmap_scene(inner):
    """A rough plane with a normal map (its texture differentiated) under a constant sky, rendered by prb."""
    res = 8
    normals = np.zeros((res, res, 3), dtype=np.float32)
    normals[..., 0], normals[..., 2] = 0.5 + 0.15, 1.0  # tangent-space normals stored as (n + 1)/2
    normals[..., 1] = 0.5
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "prb", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([0, -2.5, 2.5], [0, 0, 0], [0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "sky": {"type": "constant", "radiance": 1.0},
        "plane": {"type": "rectangle",
                  "bsdf": {"type": "normalmap", "id": "nm",
                           "normalmap": {"type": "bitmap", "raw": True, "filter_type": "bilinear",
                                         "data": mi.TensorXf(normals)},
                           "bsdf": inner}},
    })


def _normalmap_gradient(inner):
    scene = _normalmap_scene(inner)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("normalmap.data"))
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, spp=4, seed=3)
    dr.backward(dr.mean(img))
    return np.array(dr.grad(params[key]))


def test_prb_through_normalmap(table):
    builtin = _normalmap_gradient({"type": "roughconductor", "alpha": 0.3, "material": "Cu"})
    single = _normalmap_gradient(_params("conductor", "single") | {"alpha": 0.3, "distribution": "beckmann"})
    assert np.abs(builtin).max() > 0.0
    # msx single samples and evaluates as the built-in: the same paths, the same gradient up to float rounding
    np.testing.assert_allclose(single, builtin, rtol=1e-3, atol=1e-3 * np.abs(builtin).max())
    with pytest.raises(Exception) as e:
        _normalmap_gradient(_params("conductor", "correlated"))
    text = str(e.value) + str(e.value.__cause__ or "")
    assert "directions that carry a gradient" in text and "max_iterations" not in text, text


# ------------------------------------------------------------------ the walks that differentiate through directions
#
# The position-free conductor walks on Beckmann draw each normal with everything detached and reflect the
# attached direction about it, the step weighed by its visible-normal density over the detached one
# (docs/gradients.md, "Directions through the walks"). Checked per call on the walk's estimate with a fixed
# lane key, so that the central difference uses the same random numbers (common random numbers: its noise is
# that of the lanes whose random decisions flip between θ − h and θ + h), against forward-mode AD of the same
# lanes: a paired z-test per derivative (ω_i alone, ω_o alone), Šidák-corrected over all of them.

DIRECTION_LANES = 1 << 20
DIRECTION_H = 1e-3
# model, distribution, α, θ_i (> π/2: ω_i below the macro surface, as a normal map can make it), material,
# estimator. On GGX the derivative includes the next events' horizon edge terms (posfree.horizon_edge_term).
DIRECTION_CASES = [("correlated", "beckmann", 0.6, 0.5, "none", "pt"), ("correlated", "beckmann", 1.0, 1.3, "Cu", "pt"),
                   ("uncorrelated", "beckmann", 0.3, 1.0, "none", "pt"),
                   ("correlated", "beckmann", 0.8, 1.75, "none", "pt"), ("auto", "beckmann", 0.3, 1.35, "Au", "pt"),
                   ("correlated", "beckmann", 0.6, 0.5, "Cu", "bdpt"), ("correlated", "ggx", 0.6, 0.9, "none", "pt"),
                   ("uncorrelated", "ggx", 0.6, 0.9, "none", "pt"), ("correlated", "ggx", 0.8, 1.9, "none", "pt"),
                   ("correlated", "ggx", 0.6, 0.9, "none", "bdpt"),
                   ("heitz", "beckmann", 0.6, 0.5, "Cu", "pt"), ("heitz", "beckmann", 1.0, 1.3, "none", "pt"),
                   ("invariance", "beckmann", 0.6, 0.5, "Cu", "pt"), ("invariance", "beckmann", 1.0, 1.3, "none", "pt"),
                   ("invariance", "beckmann", 0.6, 0.5, "none", "bdpt")]
# GGX's per-lane differences are noisier (its next-event value jumps at the horizon on some lanes between θ ± h):
# four times the lanes, in batches of independent keys, resolve it to the same 2 %.
DIRECTION_BATCHES = {"beckmann": 1, "ggx": 4}
# `heitz` and `invariance` on a GGX conductor: their derivative includes the edge terms of the next events
# (heitz.horizon_edge_term; invariance_conductor.nee_edge_term) and of `invariance`'s connection
# (invariance_conductor.connect_edge_term). Their central difference in ω_i is noisier (lanes whose next event
# or connection jumps between θ ± h, each ∝ 1/h): ω_i takes h = 4·10⁻³, with the difference quotient's
# truncation in the bound (``_check_per_call``). model, α, θ_i, material, estimator, batches of 2²⁰ lanes (each
# case resolved to 2 %; the edge terms' share of the derivative is 7–28 % in these cases, docs/gradients.md).
GGX_WALK_DIRECTION_CASES = [("heitz", 0.6, 0.5, "Cu", "pt", 1), ("heitz", 0.6, 0.9, "none", "pt", 4),
                            ("invariance", 0.6, 0.5, "Cu", "pt", 1), ("invariance", 0.6, 0.9, "none", "pt", 4),
                            ("invariance", 0.6, 0.5, "Cu", "bdpt", 1)]
DIRECTION_H_GGX_WALKS = 4e-3
# Two derivatives (ω_i, ω_o) × two channels per case.
Z_DIRECTION = NormalDist().inv_cdf(
    1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / (4 * (len(DIRECTION_CASES) + len(GGX_WALK_DIRECTION_CASES))))) / 2.0)


def _walk_params(model, alpha, material, estimator="pt", distribution="beckmann", **more):
    p = {"type": "msx_posfree", "model": model, "alpha": alpha, "distribution": distribution, "estimator": estimator,
         "differentiate_directions": True, **more}
    if material != "none":
        p["material"] = material
    return p


def _agrees_with_central_differences(ad, values_at, h, label):
    """Whether the mean of the per-lane derivatives ``ad`` equals the central difference of the mean of
    ``values_at(θ)`` (independent lanes at each θ) within noise: a z-test at 1e-3 on AD − D(h), plus the
    difference quotient's truncation, estimated from D(2h) − D(h) = 3·O(h²) (with that estimate's own noise)."""
    def quotient(step):
        with dr.suspend_grad():
            return (values_at(ANGLE + step) - values_at(ANGLE - step)) / (2 * step)

    d1, d2 = quotient(h), quotient(2 * h)
    n = len(ad)
    se1 = np.hypot(ad.std(ddof=1), d1.std(ddof=1)) / np.sqrt(n)
    se12 = np.hypot(d1.std(ddof=1), d2.std(ddof=1)) / np.sqrt(n)
    z_max = NormalDist().inv_cdf(1.0 - 0.5e-3)
    truncation = (abs(d2.mean() - d1.mean()) + z_max * se12) / 3.0
    print("%s: AD %.5f, central differences %.5f ± %.5f (2h: %.5f), truncation ≤ %.5f" % (
        label, ad.mean(), d1.mean(), d1.std(ddof=1) / np.sqrt(n), d2.mean(), truncation))
    assert abs(d1.mean()) > 5 * d1.std(ddof=1) / np.sqrt(n), "the derivative is lost in noise"
    return abs(ad.mean() - d1.mean()) <= z_max * se1 + truncation


@pytest.mark.parametrize("model,distribution,alpha,theta_i,material,estimator", DIRECTION_CASES,
                         ids=["%s-%s-a%g-th%g-%s-%s" % c for c in DIRECTION_CASES])
def test_walk_derivative_through_directions_equals_central_differences(table, model, distribution, alpha, theta_i,
                                                                       material, estimator):
    params = _walk_params(model, alpha, material, estimator, distribution)
    _check_per_call(params, theta_i, DIRECTION_BATCHES[distribution], Z_DIRECTION,
                    "%s %s %s α %g θ_i %g %s" % (model, estimator, distribution, alpha, theta_i, material))


@pytest.mark.parametrize("model,alpha,theta_i,material,estimator,batches", GGX_WALK_DIRECTION_CASES,
                         ids=["%s-ggx-a%g-th%g-%s-%s-x%d" % c for c in GGX_WALK_DIRECTION_CASES])
def test_ggx_walk_derivative_through_directions_equals_central_differences(table, model, alpha, theta_i, material,
                                                                           estimator, batches):
    params = _walk_params(model, alpha, material, estimator, "ggx")
    _check_per_call(params, theta_i, batches, Z_DIRECTION,
                    "%s %s ggx α %g θ_i %g %s" % (model, estimator, alpha, theta_i, material), h_wi=DIRECTION_H_GGX_WALKS)


# The walks on Lambertian facets (posfree.diffuse_eval_pt): ω_i enters the first vertex's visible-normal density,
# ω_o the next events, continuous on both distributions (no edge term). model, distribution, α, θ_i, albedo;
# θ_i 1.35 is where ``auto`` walks at α 0.3 (its rule's threshold there is below 0.3), and near grazing.
# The last entry is the number of 2²⁰-lane batches. A diffuse surface's value hardly depends on ω_i, and the
# central difference's per-lane noise (lanes whose random decisions flip between θ ± h, each ∝ 1/h) then
# swamps its derivative at h = 10⁻³ (measured, first case: standard deviation per lane 1.7 against a mean of
# 0.019); at h = 10⁻² it is 0.56, and the difference quotient's truncation, O(h²), enters the bound as
# estimated from D(2h) − D(h) = 3·O(h²) (with that estimate's own noise). ω_o keeps h = 10⁻³ (its per-lane
# difference is nearly deterministic: the next events alone see it).
DIFFUSE_DIRECTION_CASES = [("correlated", "beckmann", 0.6, 0.5, 0.8, 8), ("uncorrelated", "ggx", 0.8, 1.2, 0.5, 2),
                           ("auto", "beckmann", 0.3, 1.35, 0.9, 4), ("heitz", "ggx", 0.6, 1.0, 0.8, 4)]
DIFFUSE_H = 1e-2
FLOAT32_RELATIVE = 1e-4
DROPS_MAX = 1e-5  # the share of lanes whose derivative may overflow (``_check_per_call``)
Z_DIFFUSE = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / (4 * len(DIFFUSE_DIRECTION_CASES)))) / 2.0)


@pytest.mark.parametrize("model,distribution,alpha,theta_i,albedo,batches", DIFFUSE_DIRECTION_CASES,
                         ids=["%s-%s-a%g-th%g-r%g-x%d" % c for c in DIFFUSE_DIRECTION_CASES])
def test_diffuse_walk_derivative_through_directions_equals_central_differences(table, model, distribution, alpha,
                                                                               theta_i, albedo, batches):
    params = _walk_params(model, alpha, "none", "pt", distribution, surface="diffuse", reflectance=albedo)
    _check_per_call(params, theta_i, batches, Z_DIFFUSE,
                    "diffuse %s %s α %g θ_i %g albedo %g" % (model, distribution, alpha, theta_i, albedo), h_wi=DIFFUSE_H)


def _check_per_call(params, theta_i, batches, z_bound, label, h_wi=DIRECTION_H):
    """The per-call check of a walk's derivative through ω_i and through ω_o (the comment above
    ``DIRECTION_LANES``): channels 0 and 2, ``batches`` × 2²⁰ lanes of independent keys. With a step ``h_wi``
    (for ω_i; ω_o keeps ``DIRECTION_H``) larger than ``DIRECTION_H`` the bound adds the central difference's
    truncation, estimated from the difference quotient at 2h (paired, with its noise at 1e-3):
    |D(2h) − D(h)| = 3·O(h²)."""
    from msx.jit import gradients
    from msx.jit.rng import hash_words

    n = DIRECTION_LANES
    b = mi.load_dict(params)
    call = b._call(mi.BSDFContext(), dr.zeros(mi.SurfaceInteraction3f, n), mi.Bool(True))
    # Each lane's directions are jittered by ~10⁻³ rad about the case's (fixed seed), so that the float32
    # rounding of the directions at θ ± h differs between lanes: with one direction shared by every lane, its
    # rounding error (a few ulps, divided by 2h) was the same on all of them — a systematic error of the
    # central difference of up to 10⁻⁴ (measured: `heitz` ∂/∂ω_o, −9.6·10⁻⁵ ± 0.14·10⁻⁵ at h = 2.5·10⁻⁴,
    # −1.2·10⁻⁵ ± 0.5·10⁻⁵ at 5·10⁻⁴), which the paired z-test, built on independent lanes, cannot see. Jittered,
    # it is part of each lane's noise. AD and the difference estimate the same jitter-averaged derivative.
    jitter = np.random.default_rng(11).normal(scale=1e-3, size=(2, 3, n)).astype(np.float32)
    wi_w = dr.normalize(mi.Vector3f(float(np.sin(theta_i)), 0.0, float(np.cos(theta_i))) + mi.Vector3f(jitter[0]))
    wo_w = dr.normalize(dr.normalize(mi.Vector3f(-0.5, 0.4, 0.77)) + mi.Vector3f(jitter[1]))
    lanes = dr.zeros(mi.Vector3f, n)

    def frame(t):
        return mi.Frame3f(dr.normalize(mi.Vector3f(dr.sin(t), 0.3 * dr.sin(t), dr.cos(t))))

    def estimate(t, which, key):
        moving, still = frame(t), frame(mi.Float(ANGLE))
        wi = (moving if which == "wi" else still).to_local(wi_w) + lanes
        wo = (moving if which == "wo" else still).to_local(wo_w) + lanes
        return np.array(b._model.differentiable_estimate(call, wi, wo, key), dtype=np.float64)

    def quotient(step, which, key):
        with dr.suspend_grad():
            return (estimate(mi.Float(ANGLE + step), which, key) - estimate(mi.Float(ANGLE - step), which, key)) / (
                2 * step)

    for which in ("wi", "wo"):
        h = h_wi if which == "wi" else DIRECTION_H
        ads, fds, fds2 = [], [], []
        drops = 0  # lanes whose derivative ``gradients.attach`` found non-finite (and set to 0)
        for batch in range(batches):
            key = hash_words(7 + batch, (dr.arange(mi.Float, n),))
            t = mi.Float(ANGLE)
            dr.enable_grad(t)
            moving, still = frame(t), frame(mi.Float(ANGLE))
            wi = (moving if which == "wi" else still).to_local(wi_w) + lanes
            wo = (moving if which == "wo" else still).to_local(wo_w) + lanes
            dropped = gradients.record_dropped()
            value = b._model.differentiable_estimate(call, wi, wo, key)
            dr.forward(t)
            ads.append(np.array(dr.grad(value), dtype=np.float64))
            gradients.record_dropped(False)
            drops += sum(int(c[0]) for c in dropped)
            fds.append(quotient(h, which, key))
            if h > DIRECTION_H:
                fds2.append(quotient(2 * h, which, key))
        ad, fd = np.concatenate(ads, axis=1), np.concatenate(fds, axis=1)
        lanes_used = ad.shape[1]
        for c in (0, 2):
            diff = ad[c] - fd[c]
            se = diff.std(ddof=1) / np.sqrt(lanes_used)
            z = diff.mean() / se
            truncation = 0.0
            if fds2:
                d21 = np.concatenate(fds2, axis=1)[c] - fd[c]
                z_max = NormalDist().inv_cdf(1.0 - 0.5e-3)
                truncation = (abs(d21.mean()) + z_max * d21.std(ddof=1) / np.sqrt(lanes_used)) / 3.0
            print("%s, ∂/∂%s channel %d: AD %.5f, central differences %.5f ± %.5f (h %g), truncation ≤ %.2g, z %+.2f"
                  % (label, which, c, ad[c].mean(), fd[c].mean(), fd[c].std(ddof=1) / np.sqrt(lanes_used), h,
                     truncation, z))
            assert abs(fd[c].mean()) > 5 * fd[c].std(ddof=1) / np.sqrt(lanes_used), "the derivative is lost in noise"
            assert se <= 0.01 * abs(fd[c].mean()), "not resolved to 2 % (two standard errors)"
            # Where a direction enters the next events alone (ω_o of a diffuse surface), AD and the difference
            # agree on every lane to float32 arithmetic and the paired noise is ~10⁻⁶: the bound then needs the
            # float32 evaluation's own systematic error, taken as 10⁻⁴ of the derivative (measured differences
            # 2–3·10⁻⁵ of it; far below the 2 % this test resolves).
            arithmetic = FLOAT32_RELATIVE * abs(fd[c].mean())
            # A dropped lane counts 0 instead of its derivative: at most the largest finite one, per lane. They
            # must stay rare (one lane in 2²⁰ of `auto` on Au at θ_i 1.35, at order 4: float32 overflow of a
            # derivative whose value is O(1), docs/gradients.md), and their effect enters the bound.
            assert drops <= DROPS_MAX * lanes_used, "%d lanes with a non-finite derivative" % drops
            dropped_effect = drops * np.abs(ad[c]).max() / lanes_used
            assert abs(diff.mean()) <= z_bound * se + truncation + arithmetic + dropped_effect, (
                label, which, c, ad[c].mean(), fd[c].mean())


# model, distribution, estimator: the GGX walks with heights or an exit table carry the next events' edge terms.
FORWARD_REVERSE_CASES = [("correlated", "beckmann", "pt"), ("heitz", "ggx", "pt"), ("invariance", "ggx", "pt")]


@pytest.mark.parametrize("model,distribution,estimator", FORWARD_REVERSE_CASES,
                         ids=["%s-%s-%s" % c for c in FORWARD_REVERSE_CASES])
def test_walk_derivative_through_directions_forward_and_reverse(table, model, distribution, estimator):
    """Through the BSDF as a render calls it: forward and reverse mode give the same derivative of the mean
    of ``eval`` (reverse mode through a walk used to stop drjit: its loops have no adjoint), and it agrees with
    central differences of that mean (independent lanes: the keys follow the directions)."""
    import gc

    # A symbolic call traces every live instance of the class: free the ones earlier tests left in
    # reference cycles (a refused walk without differentiate_directions would stop this trace).
    gc.collect()
    n = DIRECTION_LANES
    b = mi.load_dict(_walk_params(model, 0.6, "Cu", estimator, distribution))
    idx = dr.arange(mi.UInt32, n) % N
    wi_w, wo_w = dr.gather(mi.Vector3f, _directions(1, 1.0), idx), dr.gather(mi.Vector3f, _directions(2, 1.0), idx)
    mean_eval = jit_support.tilting_eval(b, wi_w, wo_w)
    fwd, rev = jit_support.forward_and_reverse(mean_eval, ANGLE)
    assert abs(rev - fwd[0].mean()) <= 1e-3 * abs(fwd[0].mean()), (rev, fwd[0].mean())
    assert _agrees_with_central_differences(fwd[0], lambda a: np.array(mean_eval(mi.Float(a)), dtype=np.float64)[0],
                                            0.03, "%s %s %s through the BSDF (reverse %.5f)" % (
                                                model, distribution, estimator, rev))


@pytest.mark.parametrize("surface", ["conductor", "diffuse"])
def test_walk_sample_weight_differentiates_through_the_incident_direction(table, surface):
    """``sample`` with ω_i carrying a gradient draws ω_o with ω_i detached and weighs the walk's differentiable
    estimate by the detached density, so E[weight · g(ω_o)] = ∫ f(ω_i, ω_o) g(ω_o) dω_o at every θ. With g the
    world x-component of ω_o (a tilting frame moves the lobe along x), the mean derivative of weight · g equals
    the central difference of its mean (independent draws at θ ± h)."""
    n = DIRECTION_LANES
    b = mi.load_dict(_walk_params("correlated", 0.7, "Cu") if surface == "conductor" else
                     _walk_params("correlated", 0.7, "none", surface="diffuse", reflectance=0.8))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(3)
    u = [mi.Float(x) for x in rng.uniform(0.0, 1.0, (3, n)).astype(np.float32)]
    wi_w = mi.Vector3f(0.5, 0.2, 0.84)

    def weighted(t):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.p = mi.Point3f(dr.arange(mi.Float, n), 0.0, 0.0)
        fr = mi.Frame3f(mi.Vector3f(dr.sin(t), 0.0 * t, dr.cos(t)))
        si.sh_frame = fr
        si.wi = fr.to_local(wi_w + dr.zeros(mi.Vector3f, n))
        bs, w = b.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
        return w[0] * fr.to_world(bs.wo)[0]

    t = mi.Float(ANGLE)
    dr.enable_grad(t)
    g = weighted(t)
    dr.forward(t)
    ad = np.array(dr.grad(g), dtype=np.float64)
    assert _agrees_with_central_differences(ad, lambda a: np.array(weighted(mi.Float(a)), dtype=np.float64),
                                            0.03, "sample weight")


def test_differentiate_directions_on_invariance_diffuse_gives_its_one_line(table, monkeypatch):
    """No walk refuses differentiate_directions any more (the last, ``invariance`` on GGX glass, has its edge
    terms: docs/gradients.md). ``invariance`` on the diffuse surface is refused in the vectorized variants for its
    per-path arrays, with the flag or without: with it, the load gives that one line, not a refusal of the
    directions. (python_tests/test_jit_surfaces.py allows local arrays for its direct calls when pytest imports
    it: a scene's refusal is what a user meets.)"""
    import msx.jit.bsdf

    monkeypatch.setattr(msx.jit.bsdf, "ALLOW_LOCAL_ARRAYS", False)
    p = _walk_params("invariance", 0.5, "none") | {"surface": "diffuse"}
    with pytest.raises(Exception) as e:
        mi.load_dict(p)
    text = str(e.value)
    line = [x for x in text.splitlines() if "MsxParameterError" in x]
    assert len(line) == 1 and "dr.alloc_local" in line[0], text
    assert "differentiate_directions=true is not available" not in text, text


def test_walk_asks_for_differentiate_directions(table):
    """A walk that can differentiate through directions, without the parameter, names it in its one line."""
    p = _walk_params("correlated", 0.5, "Cu")
    del p["differentiate_directions"]
    bsdf = mi.load_dict(p)
    si = _tilting_interaction()
    with pytest.raises(ValueError) as e:
        bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(-0.2, 0.1, 0.95))
    assert "differentiate_directions" in str(e.value) and "\n" not in str(e.value)
