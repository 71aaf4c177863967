"""The derivative of a walk's ``sample`` weight while its parameters are differentiated, in ``llvm_ad_rgb``.

Differentiated, ``sample`` draws ω_o from the walk's proposal (detached) and weighs it by the walk's estimate
there over the proposal's density (docs/gradients.md); the weight's derivative is that of the walk as
written (``prb`` does not use it: it replays ``eval``). A walk's loop must take the differentiated values
through its state: read from outside the loop inside a symbolic call, drjit 1.5 either refuses them
(``conductor invariance`` with ``estimator="bdpt"``: ``ad_traverse … isolate_grad`` when ``dr.forward``
reached the weight) or drops their derivative (the weight's derivative in a conductor's η was 0 on every
lane of ``heitz``, ``invariance`` and the position-free walks, whose ``sample`` now weighs by ``eval``'s
differentiable estimate). Checked through a symbolic call, as a render calls the BSDF:

- forward mode runs, and the derivative is finite and not all zero, for every model the engine runs with
  ``estimator="bdpt"``, in α and in η;
- in η, which moves no direction (only the Fresnel terms), the mean of the weight's derivative equals the
  central difference of the mean weight (a z-test over 2¹⁴ lanes; the proposal's directions do not depend
  on η, and the roulette's survival probability is detached, so the derivative is unbiased);
- the same in the albedo of the diffuse microsurface's walks.
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
from msx.jit import bsdf as engine  # noqa: E402

LANES = 1 << 14
# Šidák: a family-wise false-alarm rate of 1e-3 over the (6 + 3) × 3 z-tests of this file.
Z = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / 27)) / 2.0)


@pytest.fixture(scope="module", autouse=True)
def llvm():
    with jit_support.engine_mode():  # backend="jit", not whatever route an earlier module registered
        yield


def calls(model, estimator, key, surface="conductor"):
    """The differentiated ``sample`` of a copper conductor (or of a diffuse microsurface of albedo (0.8, 0.6,
    0.4)) at fixed lanes: a function of the step t along ``key`` that returns (weight, forward derivative)."""
    material = {"material": "Cu"} if surface == "conductor" else {
        "surface": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}}
    b = mi.load_dict({"type": "msx_posfree", "model": model, "estimator": estimator,
                      "distribution": "ggx", "alpha": 0.5, **material})
    p = mi.traverse(b)
    x0 = type(p[key])(p[key])
    rng = np.random.default_rng(3)
    si = dr.zeros(mi.SurfaceInteraction3f, LANES)
    si.wi = dr.normalize(mi.Vector3f(0.6, -0.2, 0.7))
    si.p = mi.Point3f(mi.Float(np.arange(LANES, dtype=np.float32)), 0.0, 0.0)
    u = [mi.Float(x) for x in rng.uniform(0.0, 1.0, (3, LANES)).astype(np.float32)]
    ptr = dr.gather(mi.BSDFPtr, mi.BSDFPtr(b), dr.zeros(mi.UInt32, LANES))

    def at(t):
        p[key] = type(x0)(x0 + t)
        dr.enable_grad(p[key])
        p.update()
        try:
            _, w = ptr.sample(mi.BSDFContext(), si, u[0], mi.Point2f(u[1], u[2]))
            dr.set_grad(p[key], 1.0)
            dr.forward_to(w)
            return np.array(dr.detach(w), dtype=np.float64), np.array(dr.grad(w), dtype=np.float64)
        finally:
            p[key] = type(x0)(x0)
            p.update()

    return at


@pytest.mark.parametrize("model", engine.bdpt_models("conductor"))
@pytest.mark.parametrize("key", ("alpha.value", "eta.value"))
def test_bdpt_sample_weight_differentiates_forward(model, key):
    w, fwd = calls(model, "bdpt", key)(0.0)
    assert np.all(np.isfinite(w)) and np.all(np.isfinite(fwd)), "a weight or its derivative is not finite"
    assert np.any(fwd != 0.0), "no derivative"


ETA_CASES = [("heitz", "pt"), ("invariance", "pt"), ("invariance", "bdpt"), ("correlated", "pt"),
             ("correlated", "bdpt"), ("uncorrelated", "pt")]


@pytest.mark.parametrize("model, estimator", ETA_CASES)
def test_sample_weight_derivative_in_eta_equals_finite_differences(model, estimator):
    _check_against_finite_differences(calls(model, estimator, "eta.value"), model, estimator)


@pytest.mark.parametrize("model", ("uncorrelated", "correlated", "heitz"))
def test_diffuse_sample_weight_derivative_in_albedo_equals_finite_differences(model):
    """The albedo moves no direction either (the cosine proposal does not depend on it). The position-free
    diffuse walks' weight used to take the walk as written, whose derivative in the albedo drjit dropped (0
    on every lane); it now weighs by ``eval``'s differentiable estimate, as the conductors do."""
    _check_against_finite_differences(calls(model, "pt", "reflectance.value", "diffuse"), model, "pt")


def _check_against_finite_differences(at, model, estimator):
    h = 1e-2
    _, fwd = at(0.0)
    fd = (at(h)[0] - at(-h)[0]) / (2.0 * h)
    for c in range(3):
        se = math.hypot(fd[c].std(ddof=1), fwd[c].std(ddof=1)) / math.sqrt(LANES)
        z = (fwd[c].mean() - fd[c].mean()) / se
        print(f"{model} {estimator} channel {c}: AD {fwd[c].mean():.5f}, FD {fd[c].mean():.5f}, z {z:+.2f}")
        assert abs(z) <= Z, f"{model} {estimator} channel {c}: AD {fwd[c].mean()} vs FD {fd[c].mean()}"
        assert abs(fd[c].mean()) > 5.0 * fd[c].std(ddof=1) / math.sqrt(LANES), "the derivative is lost in noise"
