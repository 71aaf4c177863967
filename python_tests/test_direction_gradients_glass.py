"""Gradients through directions of the glass walks (issue 32, item 4; docs/gradients.md, "Directions through the
walks", "The glass walks along moving directions" and "Heitz's walk through glass along moving directions"): the
position-free walks on a rough dielectric (``uncorrelated``, ``correlated``, ``auto``), Heitz's walk
(``heitz``) and the invariance walk (``invariance``), Beckmann and GGX, with
``differentiate_directions=true``.

- Per call, on the walk itself (``posfree_dielectric.eval_pt``, ``heitz.dielectric_eval`` or
  ``invariance_dielectric.eval`` traced, as ``DielectricModel.differentiable_estimate`` runs it for one
  coordinate of the directions): the forward-mode derivative along a tangent of ω_i, and of ω_o, lane by lane at fixed lane keys, against central differences of the same lanes (common random numbers: step h
  and 2h, the truncation estimated from D(2h) − D(h) = 3·O(h²)); a paired z-test per derivative, Šidák over all
  the checks of this file. Every lane's derivative must be finite: the walk's own derivatives are read before
  ``gradients.attach`` would set a non-finite one to 0, so no lane is dropped silently.
- Through the BSDF as a render calls it (``mi.BSDFPtr``): forward and reverse mode agree, and match central
  differences of the mean.
"""

from statistics import NormalDist

import numpy as np
import pytest

from test_direction_gradients import ANGLE, N, _agrees_with_central_differences, _directions  # noqa: F401

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import jit_support  # noqa: E402


@pytest.fixture(scope="module")
def table():
    """The engine's table, with the engine registered in drjit's default symbolic mode for the module (as in
    test_direction_gradients.py)."""
    import jit_support
    from msx.jit import bsdf as jit_bsdf

    with jit_support.engine_mode():
        yield jit_bsdf

# The central differences' step. On GGX the next events' values jump where their half vector turns horizontal, and
# a lane whose jump falls between θ ± h carries jump/2h: such lanes are ∝ h, so the differences' variance ∝ 1/h; a
# larger step there (its truncation estimated as everywhere) resolves the derivative with fewer lanes.
# Heitz's walk (and the invariance walk, which hands its paths to it) with ω_o reflected takes 4·10⁻³ on Beckmann
# too (H_HEITZ_REFLECTED): more of its lanes flip a decision between θ ± h (outside → reflected, 2¹⁹ lanes,
# h = 10⁻³: the differences' standard error 0.0074 against the derivative's own 0.0024).
H = {"beckmann": 1e-3, "ggx": 4e-3}
H_HEITZ_REFLECTED = 4e-3
IOR = 1.5
# (name, ω_i, ω_o) in the local frame (η = 1.5: total internal reflection inside beyond 41.8°). Chosen where
# the derivatives stand well above their noise (a reflection at moderate incidence off glass is ~4 % of the
# light, and its derivative in ω_i is lost in the noise of the draws' weights).
GEOMETRIES = {
    "outside-reflected": ((0.94, 0.0, 0.34), (-0.94, 0.0, 0.34)),
    "outside-transmitted": ((0.5, 0.1, 0.86), (-0.3, 0.2, -0.9)),
    "inside-reflected": ((0.5, 0.0, -0.87), (-0.7, 0.0, -0.71)),
    "inside-reflected-near-tir": ((0.64, 0.1, -0.76), (-0.6, -0.05, -0.8)),
    "inside-transmitted": ((0.3, 0.1, -0.95), (-0.4, 0.2, 0.9)),
    "grazing": ((0.97, 0.0, 0.24), (-0.5, 0.0, -0.85)),
}
# model, distribution, α, geometry, lanes (log2): enough that the paired standard error is ≤ 1 % of the derivative.
# (GGX outside-transmitted is left out: its ∂/∂ω_i, 0.126, needs 2²⁰ lanes to be resolved so; measured in
# docs/gradients.md.)
CASES = [("correlated", "beckmann", 0.5, "outside-reflected", 19),
         ("correlated", "beckmann", 0.5, "outside-transmitted", 16),
         ("correlated", "beckmann", 0.5, "inside-reflected", 18),
         ("correlated", "beckmann", 0.5, "inside-reflected-near-tir", 19),
         ("correlated", "beckmann", 0.5, "inside-transmitted", 16),
         ("correlated", "beckmann", 0.5, "grazing", 17),
         ("correlated", "ggx", 0.5, "outside-reflected", 19),
         ("correlated", "ggx", 0.5, "inside-transmitted", 16),
         ("uncorrelated", "beckmann", 0.5, "outside-transmitted", 16),
         ("uncorrelated", "ggx", 0.5, "inside-transmitted", 17),
         ("auto", "beckmann", 0.3, "inside-transmitted", 16),
         # Heitz's walk (its heights reparameterized; P_hit/A(w) folded into one factor).
         ("heitz", "beckmann", 0.5, "outside-reflected", 19),
         ("heitz", "beckmann", 0.5, "outside-transmitted", 16),
         ("heitz", "beckmann", 0.5, "inside-reflected", 21),
         ("heitz", "beckmann", 0.5, "inside-transmitted", 16),
         ("heitz", "ggx", 0.5, "outside-reflected", 18),
         ("heitz", "ggx", 0.5, "inside-transmitted", 16),
         # The invariance walk (its first run's depths reparameterized, Heitz's walk after the refraction).
         ("invariance", "beckmann", 0.5, "outside-reflected", 19),
         ("invariance", "beckmann", 0.5, "outside-transmitted", 16),
         ("invariance", "beckmann", 0.5, "inside-reflected", 20),
         ("invariance", "beckmann", 0.5, "inside-transmitted", 16),
         # On GGX with the first run's edge terms (inside → reflected: the derivative in ω_i is heavy-tailed).
         ("invariance", "ggx", 0.5, "outside-reflected", 18),
         ("invariance", "ggx", 0.5, "outside-transmitted", 18),
         ("invariance", "ggx", 0.5, "inside-reflected", 23),
         ("invariance", "ggx", 0.5, "inside-transmitted", 16)]
# The walks checked through the BSDF as a render calls it (and through prb).
BSDF_MODELS = ["correlated", "heitz"]
# The invariance walk on GGX at α 0.8, ω_i inside → reflected, ∂/∂ω_o up to order 4
# (test_invariance_ggx_edges_of_every_scattering_lane).
EDGE_CHECKS = 1
# Two derivatives (ω_i, ω_o) per case, plus the BSDF-level checks.
Z_MAX = NormalDist().inv_cdf(1.0 - (1.0 - (1.0 - 1e-3) ** (1.0 / (2 * len(CASES) + len(BSDF_MODELS) + EDGE_CHECKS)))
                             / 2.0)


def _tangent(w):
    """A unit tangent of the unit direction w (the move of a frame tilting about the axis (0.3, 1, 0))."""
    return dr.normalize(dr.cross(mi.Vector3f(0.3, 1.0, 0.0), w))


def _case_walk(model, distribution, alpha, n, max_bounces=None):
    from msx.jit import gradients

    b = mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "int_ior": IOR, "model": model,
                      "alpha": alpha, "distribution": distribution, "differentiate_directions": True})
    call = b._call(mi.BSDFContext(), dr.zeros(mi.SurfaceInteraction3f, n), mi.Bool(True))
    model_ = b._model

    def run(wi, wo, key, tangent=None):
        bounces = model_.bounces(call, dr.detach(wi)) if max_bounces is None else max_bounces
        extra = {"direction_tangent": tangent} if tangent is not None else {}
        return model_.walk.eval_pt(call.mf, call.eta, call.radiance, wi, wo, bounces, key,
                                   mf_sample=gradients.detached(call.mf), **extra)

    return run


@pytest.mark.parametrize("model,distribution,alpha,geometry,log_lanes", CASES,
                         ids=["%s-%s-a%g-%s" % c[:4] for c in CASES])
def test_glass_walk_derivative_through_directions(table, model, distribution, alpha, geometry, log_lanes):
    _check_walk(model, distribution, alpha, geometry, log_lanes, ("wi", "wo"))


def test_invariance_ggx_edges_of_every_scattering_lane(table):
    """The invariance walk on GGX, α 0.8, ω_i inside → reflected, ∂/∂ω_o with 4 bounces: each vertex's edge
    terms (the next vertex's next event on its moving circle) are an estimate of their own, added in every lane that
    scatters — also where the scatter's own draw is invalid (a normal from its cones about w that falls below
    the horizon; docs/gradients.md). Weighed by that draw's validity they came out ~9 % short from the run's
    second vertex on, and this derivative 4 % high (0.05086 against 0.04894, z 5.5 at 2²² lanes)."""
    _check_walk("invariance", "ggx", 0.8, "inside-reflected", 22, ("wo",), max_bounces=4)


def _check_walk(model, distribution, alpha, geometry, log_lanes, derivatives, max_bounces=None):
    from msx.jit.rng import hash_words

    n = 1 << log_lanes
    run = _case_walk(model, distribution, alpha, n, max_bounces)
    # Each lane at its own pair of directions, jittered by ~0.03 rad about the geometry's: the float32 rounding of
    # the central differences (of each lane's first vertex, which has no randomness) is then independent from
    # lane to lane and enters the paired standard error instead of biasing the mean.
    rng = np.random.default_rng(5)
    wi0, wo0 = (dr.normalize(mi.Vector3f(*(np.array(v, dtype=np.float32)[:, None]
                                            + 0.03 * rng.standard_normal((3, n)).astype(np.float32))))
                for v in GEOMETRIES[geometry])
    key = hash_words(11, (dr.arange(mi.Float, n),))
    h = H_HEITZ_REFLECTED if model in ("heitz", "invariance") and "reflected" in geometry else H[distribution]
    for which in derivatives:
        t = _tangent(wi0 if which == "wi" else wo0)
        zero = mi.Vector3f(0.0)
        s = mi.Float(0.0)
        dr.enable_grad(s)
        wi = wi0 + s * t if which == "wi" else wi0
        wo = wo0 + s * t if which == "wo" else wo0
        value = run(wi, wo, key, (s, t if which == "wi" else zero, t if which == "wo" else zero))
        dr.forward(s)
        ad = np.array(dr.grad(value), dtype=np.float64)
        assert np.isfinite(np.array(value)).all()
        bad = int((~np.isfinite(ad)).sum())
        assert bad == 0, "%d of %d lanes have a non-finite derivative" % (bad, n)

        def at(step):
            with dr.suspend_grad():
                moved = dr.normalize((wi0 if which == "wi" else wo0) + step * t)
                return np.array(run(moved if which == "wi" else wi0, moved if which == "wo" else wo0, key),
                                dtype=np.float64)

        d1 = (at(h) - at(-h)) / (2 * h)
        d2 = (at(2 * h) - at(-2 * h)) / (4 * h)
        diff = ad - d1
        se = diff.std(ddof=1) / np.sqrt(n)
        se12 = (d2 - d1).std(ddof=1) / np.sqrt(n)
        truncation = (abs((d2 - d1).mean()) + Z_MAX * se12) / 3.0
        print("%s %s α %g %s, ∂/∂%s: AD %.5f, central differences %.5f ± %.5f (2h: %.5f), paired se %.5f, "
              "truncation ≤ %.5f" % (model, distribution, alpha, geometry, which, ad.mean(), d1.mean(),
                                     d1.std(ddof=1) / np.sqrt(n), d2.mean(), se, truncation))
        assert abs(d1.mean()) > 5 * d1.std(ddof=1) / np.sqrt(n), "the derivative is lost in noise"
        assert se <= 0.01 * abs(d1.mean()), "not resolved to 2 % (two standard errors)"
        assert abs(diff.mean()) <= Z_MAX * se + truncation, (model, geometry, which, ad.mean(), d1.mean())


@pytest.mark.parametrize("model", BSDF_MODELS)
def test_glass_walk_derivative_through_directions_forward_and_reverse(table, model):
    """Through the BSDF as a render calls it: forward and reverse mode give the same derivative of the mean of
    ``eval`` over a tilting frame, ω_i outside and inside, ω_o reflected and transmitted, and it agrees with
    central differences of that mean (independent lanes: the keys follow the directions)."""
    import gc

    gc.collect()  # a symbolic call traces every live instance of the class (test_direction_gradients.py)
    n = 1 << 19
    b = mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "int_ior": IOR, "model": model,
                      "alpha": 0.5, "distribution": "beckmann", "differentiate_directions": True})
    idx = dr.arange(mi.UInt32, n)
    # ω_i above for the first half of the lanes, below for the second; ω_o on both sides.
    wi_w = dr.gather(mi.Vector3f, _directions(1, 1.0), idx % N)
    wi_w[2] = dr.select(idx < n // 2, wi_w[2], -wi_w[2])
    wo_w = dr.gather(mi.Vector3f, _directions(2, 1.0), idx % N)
    wo_w[2] = dr.select(idx % 2 == 0, wo_w[2], -wo_w[2])
    mean_eval = jit_support.tilting_eval(b, wi_w, wo_w)
    fwd, rev = jit_support.forward_and_reverse(mean_eval, ANGLE)
    assert np.isfinite(fwd).all()
    assert abs(rev - fwd[0].mean()) <= 1e-3 * abs(fwd[0].mean()), (rev, fwd[0].mean())
    assert _agrees_with_central_differences(fwd[0], lambda a: np.array(mean_eval(mi.Float(a)), dtype=np.float64)[0],
                                            0.03, "glass %s through the BSDF (reverse %.5f)" % (model, rev))


@pytest.mark.parametrize("model", BSDF_MODELS)
def test_glass_walk_through_prb_and_normalmap(table, model):
    """``prb`` through Mitsuba's ``normalmap`` on a glass walk with ``differentiate_directions``: the render's
    gradient in the map runs (reverse mode through the walk's forward passes, jit/gradients.py) and is finite and
    not zero, as the conductor's (examples/fit_normal_map.py). Its value is the per-call checks' above."""
    from test_direction_gradients import _normalmap_gradient

    grad = _normalmap_gradient({"type": "msx_posfree", "surface": "dielectric", "int_ior": IOR, "model": model,
                                "alpha": 0.3, "distribution": "beckmann", "differentiate_directions": True})
    assert np.isfinite(grad).all() and np.abs(grad).max() > 0.0
