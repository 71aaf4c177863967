"""Every walk the engine runs, differentiated through directions in forward and in reverse mode (issue 32,
item 4; docs/gradients.md, "Directions through the walks").

The cases come from the engine's table (``jit_support.engine_cases``: every surface × walk × estimator it runs
in a scene), so a walk added there, or given the derivative, is tested here without editing this file. Per
case, through the BSDF as a render calls it (a symbolic call on ``mi.BSDFPtr``), with the shading frame tilting
by θ and fixed world directions, GGX (whose derivative adds the horizon edge terms) where the walk has the
derivative on GGX, else Beckmann (each differentiated walk compiles two kernels of a few seconds: one
distribution per walk keeps the file's time in CI's budget):

- where ``differentiate_directions=true`` loads, forward mode (the derivative per lane) and reverse mode (the
  adjoint of the mean) give the same derivative of the mean of ``eval`` — they differentiate the same graph,
  so they agree to float32 rounding of a sum over the lanes (1e-3 relative, as
  python_tests/test_direction_gradients.py) — every lane's derivative is finite, and the derivative is not 0;
  its value against central differences is checked per walk in test_direction_gradients.py and
  test_direction_gradients_glass.py;
- where it is refused when the scene loads (one line, naming the walks that have it), the walk without it
  stops with one line in ``eval`` when the directions carry a gradient, in forward and in reverse mode —
  never a biased derivative, never a drjit error.
"""

import gc

import numpy as np
import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

pytest.importorskip("mitsuba")
_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

mi.set_variant("llvm_ad_rgb")
import jit_support  # noqa: E402

N, ANGLE = 1 << 13, 0.2
CASES = jit_support.engine_cases(walks_only=True)


@pytest.fixture(scope="module")
def engine():
    with jit_support.engine_mode():
        yield


def _params(surface, model, estimator, distribution, flag):
    p = {"type": "msx_posfree", "surface": surface, "model": model, "estimator": estimator,
         "distribution": distribution, "alpha": 0.6}
    if surface == "conductor":
        p["material"] = "Cu"
    if flag:
        p["differentiate_directions"] = True
    return p


def _directions(seed, sign):
    """N unit world directions ≥ ~0.3 above (sign +1) or below (−1) the plane at every tilt used here."""
    v = np.random.default_rng(seed).normal(size=(N, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] = np.abs(v[:, 2]) + 0.6
    v /= np.linalg.norm(v, axis=1)[:, None]
    v[:, 2] *= sign
    return v


def _eval_at(bsdf, surface):
    """t ↦ ``eval`` of N lanes through a symbolic call as the shading frame tilts by t (jit_support.tilting_eval);
    ω_i above, ω_o above (a dielectric: every other lane below, transmitted)."""
    wo = _directions(2, 1.0)
    if surface == "dielectric":
        wo[1::2, 2] *= -1.0
    wi_w, wo_w = (mi.Vector3f(v.T.astype(np.float32)) for v in (_directions(1, 1.0), wo))
    return jit_support.tilting_eval(bsdf, wi_w, wo_w)


def _refused(surface, model, estimator, distribution, message):
    """The load's refusal of the flag is one line naming the model, and the walk without the flag stops with
    one line when its directions carry a gradient, in forward and in reverse mode."""
    assert "differentiate_directions=true is not available for model='%s'" % model in message, message
    bsdf = mi.load_dict(_params(surface, model, estimator, distribution, False))
    for mode in ("forward", "reverse"):
        with pytest.raises(ValueError) as refused:
            t = mi.Float(ANGLE)
            dr.enable_grad(t)
            f = _eval_at(bsdf, surface)(t)
            dr.forward(t) if mode == "forward" else dr.backward(dr.sum(f[0]))
        text = str(refused.value)
        assert "model='%s'" % model in text and "directions that carry a gradient" in text, (mode, text)
        assert "\n" not in text, text
    print("%s %s %s %s: refused" % (surface, model, estimator, distribution))


@pytest.mark.parametrize("surface,model,estimator", CASES, ids=["-".join(c) for c in CASES])
def test_walk_directions_in_forward_and_reverse_mode(engine, surface, model, estimator):
    for distribution in ("ggx", "beckmann"):
        gc.collect()  # a symbolic call traces every live instance: free the earlier cases' BSDFs
        try:
            bsdf = mi.load_dict(_params(surface, model, estimator, distribution, True))
        except Exception as e:  # noqa: BLE001 - refused when the scene loads (Mitsuba quotes msx's line)
            _refused(surface, model, estimator, distribution, str(e).strip().splitlines()[-1])
            continue
        fwd, rev = jit_support.forward_and_reverse(_eval_at(bsdf, surface), ANGLE)
        fwd = fwd[0]
        mean = fwd.mean()
        print("%s %s %s %s: forward %.6f, reverse %.6f" % (surface, model, estimator, distribution, mean, rev))
        assert np.all(np.isfinite(fwd)), "%d lanes non-finite" % np.count_nonzero(~np.isfinite(fwd))
        assert mean != 0.0
        assert abs(rev - mean) <= 1e-3 * abs(mean), (rev, mean)
        return
