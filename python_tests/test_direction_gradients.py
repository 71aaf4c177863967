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

import numpy as np
import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

pytest.importorskip("mitsuba")
_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

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


def walk_cases():
    mi.set_variant("llvm_ad_rgb")
    import jit_support

    return [(s, m) for s, m, e in jit_support.engine_cases(walks_only=True, bdpt=False)]


@pytest.mark.parametrize("surface,model", walk_cases())
def test_walk_refuses_directions_with_gradients(table, surface, model):
    bsdf = mi.load_dict(_params(surface, model))
    angle = mi.Float(ANGLE)
    dr.enable_grad(angle)
    si = dr.zeros(mi.SurfaceInteraction3f, 16)
    frame = mi.Frame3f(mi.Vector3f(dr.sin(angle), 0.0 * angle, dr.cos(angle)))
    si.sh_frame = frame
    si.wi = frame.to_local(mi.Vector3f(0.3, 0.1, 0.9))
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
