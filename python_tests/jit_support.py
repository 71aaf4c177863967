"""What the Dr.Jit engine's test modules share (python_tests/test_jit_*.py): lanes that call a BSDF's methods
directly, and the z-test of two means with their noise (docs/testing.md, "The Dr.Jit engine against the core").
Import after ``mi.set_variant('llvm_ad_rgb')`` has been possible (the modules skip themselves otherwise)."""

import contextlib
import math

import drjit as dr
import mitsuba as mi
import numpy as np


def lanes_si(wi, n, seed):
    """n lanes at incidence ``wi``, each at its own hit position and uv (the lanes' random streams differ)."""
    rng = np.random.default_rng(seed)
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[mi.Float(np.full(n, c, np.float32)) for c in np.asarray(wi, np.float32)])
    si.p = mi.Point3f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(3)])
    si.uv = mi.Point2f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(2)])
    return si


def stats(x, replicates):
    """(mean, σ of the mean) of per-lane values along the last axis: σ the larger of the plain standard error
    and the one of ``replicates`` independent consecutive blocks (a heavy-tailed estimate that missed its
    tail gets no small σ)."""
    x = np.asarray(x, np.float64)
    n = x.shape[-1]
    plain = x.std(axis=-1, ddof=1) / math.sqrt(n)
    reps = x[..., : n - n % replicates].reshape(x.shape[:-1] + (replicates, -1)).mean(axis=-1)
    rep = reps.std(axis=-1, ddof=1) / math.sqrt(replicates)
    return x.mean(axis=-1), np.maximum(plain, rep)


def z_check(label, a, b, z_max):
    """Asserts |z| ≤ ``z_max`` for two (mean, σ) pairs (scalars or per channel), z = Δ/√(σ₁² + σ₂²); equal
    means without noise (deterministic estimates) give z = 0."""
    (ma, sa), (mb, sb) = (np.asarray(v, np.float64) for v in a), (np.asarray(v, np.float64) for v in b)
    s, d = np.hypot(sa, sb), ma - mb
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(s > 0, d / np.where(s > 0, s, 1.0), np.where(d == 0, 0.0, np.inf))
    print("%s: engine %s core %s z %s" % (label, np.round(ma, 5), np.round(mb, 5), np.round(z, 2)))
    assert np.all(np.isfinite(ma)) and np.all(np.isfinite(mb)), label
    assert np.all(np.abs(z) <= z_max), "%s: |z| %s > %.2f" % (label, np.abs(z).max(), z_max)


@contextlib.contextmanager
def engine_mode():
    """The Dr.Jit engine in llvm_ad_rgb (``msx.register(backend="jit")``) with drjit's default symbolic loops
    and calls, for a test module's duration (llvm_support.drjit_default_mode says why)."""
    import msx
    from llvm_support import drjit_default_mode

    mi.set_variant("llvm_ad_rgb")
    msx.register(backend="jit")
    with drjit_default_mode():
        yield


def engine_cases(walks_only=False, per_order=False, bdpt=True):
    """(surface, model, estimator) of every configuration the engine's table says runs in a scene (``ENGINE_MODELS``
    and ``bdpt_models``; a walk that needs local arrays is refused in a scene, so it is left out): the test
    modules driven by the table take their cases here. ``walks_only``: the random walks (``auto`` included);
    ``per_order``: the walks whose value the core's table splits by scattering order (``auto`` left out)."""
    from msx.jit import bsdf as jit_bsdf
    from msx.names import MODEL_INFO

    out = []
    for surface, models in jit_bsdf.ENGINE_MODELS.items():
        walks = jit_bsdf.WALKS_BY_SURFACE.get(surface, {})
        for m in models:
            walk = walks.get(jit_bsdf.walk_name_of(m))
            if getattr(walk, "needs_local_arrays", False):
                continue
            if (walks_only or per_order) and walk is None:
                continue
            if per_order and not (m in walks and MODEL_INFO[m].random_walk and MODEL_INFO[m].per_order):
                continue
            out.append((surface, m, "pt"))
        if bdpt and not per_order:
            out += [(surface, m, "bdpt") for m in jit_bsdf.bdpt_models(surface)]
    return out


def tilting_eval(bsdf, wi_w, wo_w):
    """``eval`` as a render calls it (a symbolic call on ``mi.BSDFPtr``) with the shading frame tilted by θ:
    returns t ↦ eval at θ = t of the fixed world directions ``wi_w``, ``wo_w`` (one per lane; each lane its own
    hit position, so its own key) — the function python_tests/test_direction_gradients*.py differentiate."""
    n = dr.width(wi_w)
    ptr = dr.gather(mi.BSDFPtr, mi.BSDFPtr(bsdf), dr.zeros(mi.UInt32, n))
    ctx = mi.BSDFContext()

    def at(t):
        si = dr.zeros(mi.SurfaceInteraction3f, n)
        si.p = mi.Point3f(dr.arange(mi.Float, n), 0.0, 0.0)
        frame = mi.Frame3f(mi.Vector3f(dr.sin(t), 0.0 * t, dr.cos(t)))
        si.sh_frame = frame
        si.wi = frame.to_local(wi_w)
        return ptr.eval(ctx, si, frame.to_local(wo_w))

    return at


def forward_and_reverse(f, angle):
    """(per-lane forward-mode derivatives of ``f`` at θ = ``angle``, channels × lanes; the reverse-mode
    derivative of the mean of channel 0) for f = ``tilting_eval(...)``."""
    t = mi.Float(angle)
    dr.enable_grad(t)
    value = f(t)
    dr.forward(t)
    fwd = np.array(dr.grad(value), dtype=np.float64)
    t = mi.Float(angle)
    dr.enable_grad(t)
    value = f(t)
    dr.backward(dr.sum(value[0]) / dr.width(value[0]))
    return fwd, float(dr.grad(t)[0])
