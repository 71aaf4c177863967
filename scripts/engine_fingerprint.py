"""A fingerprint of the Dr.Jit engine's results, to check that a refactoring leaves them bit-identical.

In ``llvm_ad_rgb``, for every model × surface × estimator the engine runs (its own table,
``msx.jit.bsdf.ENGINE_MODELS`` and ``bdpt_models``) and both distributions, it prints one line per result
with a hash of its bytes:

* ``render``: a 32×32 image of a sphere under a sky and a sun, 4 spp, fixed seed (``path``, depth 6), for
  the configurations a scene can use;
* ``call``: ``eval``, ``pdf`` and ``sample`` (ω_o, pdf, weight) of a symbolic call at fixed lanes (ω_i on
  both sides for the dielectric);
* ``d/d…``: for every differentiable configuration, the forward derivative of ``eval`` (and of ``sample``'s
  weight, which then draws from the proposal) in α, and in the material (a conductor's η, a glass's IOR
  where the walk differentiates in it, a diffuse surface's albedo).

Usage: ``python scripts/engine_fingerprint.py [ggx] [beckmann] > /tmp/fingerprint.txt`` (both distributions by
default: ~9 min on 2 cores, ~1 min of it GGX); compare two runs with ``diff``.
Lines are independent: a difference names the configuration and the result that changed.
"""

import hashlib
import os
import sys

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

mi.set_variant("llvm_ad_rgb")

import msx  # noqa: E402

msx.register(backend="jit")

from msx.jit import bsdf as engine  # noqa: E402

LANES = 2048
SIZE, SPP, SEED = 32, 4, 7


def digest(*arrays):
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a, dtype=np.float32)).tobytes())
    return h.hexdigest()[:16]


def material(surface):
    return {"conductor": {"material": "Cu"},
            "dielectric": {"surface": "dielectric", "int_ior": 1.5},
            "diffuse": {"surface": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.6, 0.4]}}}[surface]


def bsdf_dict(surface, model, estimator, distribution):
    return {"type": "msx_posfree", **material(surface), "model": model, "estimator": estimator,
            "distribution": distribution, "alpha": 0.5, "seed": 3}


def scene(bsdf):
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 32, "to_world": look,
                   "film": {"type": "hdrfilm", "width": SIZE, "height": SIZE, "rfilter": {"type": "box"}}},
        "sky": {"type": "constant", "radiance": 0.5},
        "sun": {"type": "directional", "direction": [0.4, -0.3, -1.0], "irradiance": 3.0},
        "ball": {"type": "sphere", "radius": 1.0, "bsdf": bsdf}})


def lanes(surface):
    """Fixed incidences and exits (ω_i below too on the dielectric), each lane at its own position."""
    rng = np.random.default_rng(11)

    def dirs(lower):
        v = rng.normal(size=(3, LANES))
        v /= np.linalg.norm(v, axis=0)
        v[2] = np.abs(v[2]) + 1e-3
        if lower:
            v[2, ::2] = -v[2, ::2]
        return mi.Vector3f(*[mi.Float(c.astype(np.float32)) for c in v])

    lower = surface == "dielectric"
    si = dr.zeros(mi.SurfaceInteraction3f, LANES)
    si.wi = dr.normalize(dirs(lower))
    si.p = mi.Point3f(*[mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(3)])
    si.uv = mi.Point2f(*[mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(2)])
    wo = dr.normalize(dirs(lower))
    u = [mi.Float(rng.random(LANES).astype(np.float32)) for _ in range(3)]
    return si, wo, u


def pointer(b, direct):
    """The BSDF called through a symbolic call, as a render calls it, or directly (``direct``: a walk with
    local arrays, which drjit cannot compile inside a symbolic call)."""
    return b if direct else dr.gather(mi.BSDFPtr, mi.BSDFPtr(b), dr.zeros(mi.UInt32, LANES))


def calls(b, surface, direct):
    """(eval, pdf, ω_o, sample pdf, weight) of a call."""
    si, wo, u = lanes(surface)
    ptr = pointer(b, direct)
    ctx = mi.BSDFContext()
    f = ptr.eval(ctx, si, wo)
    pdf = ptr.pdf(ctx, si, wo)
    bs, w = ptr.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
    return f, pdf, bs.wo, bs.pdf, w


def derivative(b, surface, key, direct):
    """Forward derivatives of eval and of sample's weight in ``key`` (direction 1)."""
    p = mi.traverse(b)
    x0 = type(p[key])(p[key])
    dr.enable_grad(p[key])
    p.update()
    si, wo, u = lanes(surface)
    ptr = pointer(b, direct)
    ctx = mi.BSDFContext()
    f = ptr.eval(ctx, si, wo)
    dr.set_grad(p[key], 1.0)
    dr.forward_to(f)
    df = dr.grad(f)
    out = [dr.detach(f), df]
    p[key] = type(x0)(x0)
    dr.enable_grad(p[key])
    p.update()
    bs, w = ptr.sample(ctx, si, u[0], mi.Point2f(u[1], u[2]))
    dr.set_grad(p[key], 1.0)
    note = ""
    try:
        dr.forward_to(w, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
        out += [dr.detach(bs.wo), dr.detach(w), dr.grad(w)]
    except RuntimeError as e:  # recorded as it is: a failure is part of the behaviour
        note = " (sample: %s)" % str(e).split(":")[0]
    p[key] = type(x0)(x0)
    p.update()
    return digest(*[np.array(a) for a in out]) + note


def configurations():
    for surface, models in engine.ENGINE_MODELS.items():
        for model in models:
            yield surface, model, "pt"
        for model in engine.bdpt_models(surface):
            yield surface, model, "bdpt"


def main(distributions):
    for distribution in distributions:
        for surface, model, estimator in configurations():
            label = "%s %s %s %s" % (surface, model, estimator, distribution)
            d = bsdf_dict(surface, model, estimator, distribution)
            cfg_local = False
            try:
                b = mi.load_dict(d)
            except Exception as e:  # a configuration that the engine refuses in a scene, or that has no meaning
                if "dr.alloc_local" not in str(e):
                    print("%s load: refused (%s)" % (label, str(e).split("invalid parameter")[-1].strip()))
                    continue
                print("%s load: refused in a scene (local arrays); called directly" % label)
                engine.ALLOW_LOCAL_ARRAYS, cfg_local = True, True
                b = mi.load_dict(d)
            try:
                print("%s call: %s" % (label, digest(*[np.array(a) for a in calls(b, surface, cfg_local)])), flush=True)
                if not cfg_local:
                    img = mi.render(scene(d), spp=SPP, seed=SEED)
                    print("%s render: %s mean %.6g" % (label, digest(np.array(img)), float(np.mean(img))), flush=True)
                keys = []
                if engine.gradient_problem(b._cfg) is None:
                    keys.append("alpha.value")
                    if surface == "dielectric" and engine.eta_gradient_problem(b._cfg) is None:
                        keys.append("eta")
                    keys += {"conductor": ["eta.value"], "diffuse": ["reflectance.value"]}.get(surface, [])
                for key in keys:
                    print("%s d/d%s: %s" % (label, key, derivative(b, surface, key, cfg_local)), flush=True)
            finally:
                engine.ALLOW_LOCAL_ARRAYS = False
    return 0


if __name__ == "__main__":
    main(sys.argv[1:] or ("ggx", "beckmann"))
    sys.stdout.flush()
    # drjit 1.5 can crash while it tears down the kernels of the local-array walk; every line is out by now.
    os._exit(0)
