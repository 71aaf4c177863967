"""The native back end (C++ plugin on the Rust core) in Mitsuba's scalar variants.

- It equals the Python back end call for call on every model and surface (same core, same keys from the
  hit, same material values): eval, pdf and every field of the sample record — a build whose struct
  layouts differ from the installed Mitsuba could not pass this.
- `single` renders the same image as roughconductor / roughdielectric with the same seeds.
- A render with a fixed seed is the same image with 1 and with 2 render threads.
"""

import math
import random

import numpy as np
import pytest

from conftest import set_variant

from msx.plugin.parameters import SURFACES, models

# Every model on every surface of the core's table of names (src/config.rs).
SURFACE_MODELS = [(s, m) for s in SURFACES for m in models(s, distribution="ggx")]


def native(mi):
    import msx

    msx.register(backend="native")
    assert msx.backend() == "native"
    return mi


def both(mi, params):
    """The same BSDF from the native and the Python back end."""
    import msx

    msx.register(backend="native")
    n = mi.load_dict(params)
    msx.register(backend="python")
    p = mi.load_dict(params)
    msx.register()
    assert "native" in str(n) and "native" not in str(p)
    return n, p


def params_of(surface, model, spectral_texture=False):
    d = dict(type="msx_posfree", surface=surface, model=model, distribution="ggx", alpha=0.4, seed=3)
    if surface == "conductor":
        d["material"] = "Cu" if model != "fastmsx" else "Au"
    elif surface == "dielectric":
        d["int_ior"] = 1.5
    else:
        d["reflectance"] = {"type": "rgb", "value": [0.8, 0.5, 0.2]}
    return d


def directions(rng, n, both_sides):
    out = []
    for _ in range(n):
        z = rng.uniform(-1, 1) if both_sides else rng.uniform(0.05, 1)
        phi = rng.uniform(0, 2 * math.pi)
        r = math.sqrt(max(0.0, 1 - z * z))
        out.append((r * math.cos(phi), r * math.sin(phi), z))
    return out


def rel_close(a, b, rtol=2e-6, atol=1e-7):
    return abs(a - b) <= rtol * max(abs(a), abs(b)) + atol


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
@pytest.mark.parametrize("surface, model", SURFACE_MODELS)
def test_native_equals_python_call_for_call(variant, surface, model):
    mi = set_variant(variant)
    nat, py = both(mi, params_of(surface, model))
    rng = random.Random(hash((surface, model)) % 1000)
    si = mi.SurfaceInteraction3f()
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 680.0)
    mismatches = []
    for i in range(60):
        for mode in (mi.TransportMode.Radiance, mi.TransportMode.Importance):
            ctx = mi.BSDFContext(mode)
            wi = directions(rng, 1, surface == "dielectric")[0]
            wo = directions(rng, 1, surface == "dielectric")[0]
            si.wi = mi.Vector3f(*wi)
            si.p = mi.Point3f(rng.random(), rng.random(), rng.random())
            si.uv = mi.Point2f(rng.random(), rng.random())
            w = mi.Vector3f(*wo)
            for name, f in (("eval", lambda b: list(b.eval(ctx, si, w))), ("pdf", lambda b: [float(b.pdf(ctx, si, w))]),
                            ("eval_pdf", lambda b: list(b.eval_pdf(ctx, si, w)[0]) + [float(b.eval_pdf(ctx, si, w)[1])])):
                a, b = f(nat), f(py)
                if not all(rel_close(x, y) for x, y in zip(a, b)):
                    mismatches.append((name, i, a, b))
            s = (rng.random(), rng.random(), rng.random())
            (bn, wn), (bp, wp) = nat.sample(ctx, si, s[0], mi.Point2f(s[1], s[2])), py.sample(ctx, si, s[0], mi.Point2f(s[1], s[2]))
            fa = list(bn.wo) + [float(bn.pdf), float(bn.eta), int(bn.sampled_type), int(bn.sampled_component)] + list(wn)
            fb = list(bp.wo) + [float(bp.pdf), float(bp.eta), int(bp.sampled_type), int(bp.sampled_component)] + list(wp)
            if float(bp.pdf) > 0 or float(bn.pdf) > 0:
                if not all(rel_close(x, y) for x, y in zip(fa, fb)):
                    mismatches.append(("sample", i, fa, fb))
    assert not mismatches, mismatches[:4]


def test_flags_and_traverse_match(rgb):
    import msx

    mi = rgb
    for params in (dict(type="msx_posfree", alpha_u=0.2, alpha_v=0.5), dict(type="msx_posfree", surface="dielectric"),
                   dict(type="msx_posfree", surface="diffuse", alpha={"type": "checkerboard"})):
        nat, py = both(mi, params)
        assert nat.flags() == py.flags(), params
        assert [nat.flags(i) for i in range(nat.component_count())] == [py.flags(i) for i in range(py.component_count())]
        assert set(mi.traverse(nat).keys()) == set(mi.traverse(py).keys()), params
    msx.register()


def scene(mi, bsdf, spp=4, size=24):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": {"type": "directional", "direction": [0.3, -0.5, -1.0], "irradiance": 3.0},
        "env": {"type": "constant", "radiance": 0.5},
    })


@pytest.mark.parametrize("builtin, params", [
    ("roughconductor", dict(distribution="ggx", alpha=0.3, material="Cu")),
    ("roughdielectric", dict(distribution="beckmann", alpha=0.4, int_ior=1.5)),
])
def test_native_single_renders_the_builtin_image(builtin, params):
    import drjit as dr

    mi = native(set_variant("scalar_rgb"))
    dr.set_thread_count(2)
    surface = {"surface": "dielectric"} if builtin == "roughdielectric" else {}
    ours = np.array(mi.render(scene(mi, dict(type="msx_posfree", model="single", **surface, **params)), seed=4))
    ref = np.array(mi.render(scene(mi, dict(type=builtin, **params)), seed=4))
    diff = np.abs(ours - ref)
    print(f"\n[native single vs {builtin}] max |diff| {diff.max():.2e}, mean {ref.mean():.4f}")
    # Same samples: float32 rounding only (Mitsuba computes in float32, the core in float64).
    assert diff.max() <= 2e-3 * max(1.0, float(ref.max()))
    assert abs(ours.mean() - ref.mean()) <= 1e-4 * ref.mean()


def test_same_seed_same_image_with_1_and_2_threads():
    import drjit as dr

    mi = native(set_variant("scalar_rgb"))
    imgs = []
    for threads in (1, 2, 2):
        dr.set_thread_count(threads)
        s = scene(mi, dict(type="msx_posfree", model="correlated", distribution="ggx", alpha=0.7, material="Au"), spp=8)
        imgs.append(np.array(mi.render(s, seed=11)))
    dr.set_thread_count(1)
    assert np.array_equal(imgs[0], imgs[1]) and np.array_equal(imgs[1], imgs[2])


@pytest.mark.parametrize("backend", ["native", "python"])
def test_parallel_instantiation_is_safe(backend):
    """Mitsuba instantiates the plugins of a scene on several threads; five msx_posfree conductors with a
    material preset (each loads a built-in roughconductor for its IOR data) crashed the process within 60
    loads in 4 runs out of 4 before instantiation was serialised. Loaded here 60 times in a subprocess, which
    must exit cleanly."""
    import subprocess
    import sys

    code = (
        "import mitsuba as mi, msx\n"
        "mi.set_variant('scalar_rgb')\n"
        f"msx.register(backend='{backend}')\n"
        "from msx._render import scenes_dir\n"
        "for _ in range(60):\n"
        "    s = mi.load_file(str(scenes_dir() / 'roughness_ramp.xml'), width='8', height='40')\n"
        "    assert sum(str(x.bsdf()).startswith('MsxPosfree') for x in s.shapes()) == 5\n"
        "print('ok')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "ok" in r.stdout, (r.returncode, r.stderr[-2000:])
