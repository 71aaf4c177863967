"""Every model × surface × estimator the Dr.Jit engine runs renders in every variant the README names, and
its image means equal the other engine's within their noise (issue 32, item 0).

The cases come from the engine's own table (``ENGINE_MODELS``, ``bdpt_models``), so a model added there is
tested here without editing this file. All cases of a variant are spheres of one scene (a grid under a
constant environment), so each variant costs one kernel compile and one render:

| engine under test | its twin | conductor |
|---|---|---|
| ``llvm_ad_rgb`` (Dr.Jit) | ``scalar_rgb`` (native, on the Rust core) | ``material="Cu"`` |
| ``llvm_ad_spectral`` (Dr.Jit) | ``scalar_spectral`` (native) | ``material="Cu"``: IORs at the sampled wavelengths |
| ``llvm_ad_mono`` (Dr.Jit) | ``scalar_rgb`` (native), mean of its channels | grey ``eta``, ``k`` (equal in every channel) |

Every engine draws its own random streams, so the per-pixel difference of two renders has mean 0. Per
sphere, over the pixels that see only that sphere, ``z`` = mean difference / its standard error (the larger
of the pixels' and of 2×2 block means', as python_tests/test_jit_scenes.py argues), with a Šidák-corrected
family-wise false-alarm rate of 1e-3 over the spheres of each test.

What the engine's table does not run (``invariance`` on the diffuse surface, the BDPT of the dielectric and
diffuse walks and of ``auto``; their refusal names the way out) renders in the same three variants through
``msx.register(backend="batched")`` against the same twins; and the scalar variants run every model of the
core's table (``scalar_spectral`` against ``scalar_rgb``, grey materials).
"""

import json
import math
import os
import statistics
import subprocess
import sys
import textwrap

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

np = pytest.importorskip("numpy")
pytest.importorskip("mitsuba")

_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

SEED_OFFSET = int(os.environ.get("MSX_TEST_SEED_OFFSET", "0"))
COLS, CELL, SPP, ALPHA = 6, 16, 64, 0.7
GREY = {"eta": 0.2, "k": 3.0}


def engine_cases():
    """(surface, model, estimator) for everything the engine runs in a scene, from its table."""
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import jit_support

    return jit_support.engine_cases()


_RENDER = textwrap.dedent("""
    import json, sys
    import numpy as np
    import mitsuba as mi
    variant, spec_path, out = sys.argv[1:4]
    spec = json.load(open(spec_path))
    mi.set_variant(variant)
    import msx
    msx.register(**({"backend": sys.argv[4]} if len(sys.argv) > 4 else {}))
    cols, cell = spec["cols"], spec["cell"]
    rows = (len(spec["bsdfs"]) + cols - 1) // cols
    scene = {"type": "scene", "integrator": {"type": "path", "max_depth": 12},
             "sensor": {"type": "orthographic",
                        "to_world": mi.ScalarTransform4f().look_at([0, 0, 10], [0, 0, 0], [0, 1, 0])
                        @ mi.ScalarTransform4f().scale([cols / 2, cols / 2, 1]),
                        "film": {"type": "hdrfilm", "width": cols * cell, "height": rows * cell,
                                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                        "sampler": {"type": "independent"}},
             "light": {"type": "constant", "radiance": {"type": "rgb", "value": 1.0}}}
    for i, b in enumerate(spec["bsdfs"]):
        x, y = i % cols - (cols - 1) / 2, (rows - 1) / 2 - i // cols
        scene["s%d" % i] = {"type": "sphere", "center": [x, y, 0], "radius": 0.42,
                            "bsdf": b if b is not None else {"type": "diffuse", "reflectance": 0.0}}
    s = mi.load_dict(scene)
    img = np.array(mi.render(s, spp=spec["spp"], seed=spec["seed"]), dtype=np.float64)
    np.save(out, img)
    print(json.dumps({"backend": msx.backend(), "variant": variant}))
""")


def bsdf_of(surface, model, estimator, conductor):
    b = {"type": "msx_posfree", "surface": surface, "model": model, "estimator": estimator,
         "distribution": "ggx", "alpha": ALPHA}
    if surface == "conductor":
        b.update(conductor)
    return b


def render(tmp_path, variant, bsdfs, seed, tag, backend=None):
    """The image of ``bsdfs`` as spheres of one scene, rendered in a process of its own (``backend``: the one
    msx.register chooses, or the one named) and the back end that rendered it."""
    spec = {"cols": COLS, "cell": CELL, "spp": SPP, "seed": seed, "bsdfs": bsdfs}
    spec_path = tmp_path / ("%s.json" % tag)
    spec_path.write_text(json.dumps(spec))
    out = tmp_path / ("%s.npy" % tag)
    r = subprocess.run([sys.executable, "-c", _RENDER, variant, str(spec_path), str(out)] + ([backend] if backend else []),
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, "%s: %s" % (variant, r.stderr[-3000:])
    last = r.stdout.strip().splitlines()[-1]  # after Mitsuba's log lines (which may end in a colour code)
    return np.load(out), json.loads(last[last.index("{"):])["backend"]


@pytest.fixture(scope="module")
def cases():
    return engine_cases()


def sphere_masks(n):
    """Per sphere of an ``n``-sphere grid, the pixels that see only that sphere: black under the white sky with
    black spheres (a scalar_rgb render)."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        img, _ = render(Path(tmp), "scalar_rgb", [None] * n, 0, "mask")
    black = img.max(axis=-1) == 0.0
    rows = (n + COLS - 1) // COLS
    out = []
    for i in range(n):
        r, c = divmod(i, COLS)
        m = np.zeros_like(black)
        m[r * CELL:(r + 1) * CELL, c * CELL:(c + 1) * CELL] = True
        out.append(m & black)
    assert img.shape[:2] == (rows * CELL, COLS * CELL)
    return out


@pytest.fixture(scope="module")
def masks(cases):
    return sphere_masks(len(cases))


def grey(img):
    """One value per pixel: the channel mean (mono: its one channel)."""
    return img.reshape(img.shape[0], img.shape[1], -1).mean(axis=-1)


def compare_spheres(a, b, cases, masks, bound, names):
    """Per sphere, z of the mean per-pixel difference of two renders over its mask (σ the larger of the pixels'
    and of 2×2 block means' standard errors, as python_tests/test_jit_scenes.py argues); asserts something was
    rendered and every |z| ≤ ``bound``. ``names``: the two renders' labels."""
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(b)), "%s or %s rendered a non-finite pixel" % names
    failures = []
    for (surface, model, estimator), m in zip(cases, masks):
        d = (a - b)[m]
        assert d.size >= 64, (surface, model, d.size)
        # 2×2 blocks inside the sphere's cell (pixels outside the mask count as absent)
        ys, xs = np.nonzero(m)
        _, inverse, counts = np.unique((ys // 2) * 10_000 + xs // 2, return_inverse=True, return_counts=True)
        blocks = np.bincount(inverse, weights=d) / counts
        se = max(d.std(ddof=1) / math.sqrt(d.size), blocks.std(ddof=1) / math.sqrt(blocks.size))
        z = d.mean() / se
        line = "%-10s %-12s %-4s: %s %.5f, %s %.5f, z %+.2f" % (
            surface, model, estimator, names[0], a[m].mean(), names[1], b[m].mean(), z)
        print(line)
        assert a[m].mean() > 0.01, line  # something was rendered
        if abs(z) > bound:
            failures.append(line)
    assert not failures, "beyond |z| %.2f:\n%s" % (bound, "\n".join(failures))


GROUPS = [
    # (engine under test, its twin, the conductor's parameters)
    ("llvm_ad_rgb", "scalar_rgb", {"material": "Cu"}),
    ("llvm_ad_spectral", "scalar_spectral", {"material": "Cu"}),
    ("llvm_ad_mono", "scalar_rgb", GREY),
]


def z_max(n_tests, family_rate=1e-3):
    return statistics.NormalDist().inv_cdf(1 - (1 - (1 - family_rate) ** (1 / n_tests)) / 2)


@pytest.mark.parametrize("variant,twin,conductor", GROUPS, ids=[g[0] for g in GROUPS])
def test_every_engine_model_renders_in_variant_and_matches_native(tmp_path, cases, masks, variant, twin,
                                                                   conductor):
    bsdfs = [bsdf_of(s, m, e, conductor) for s, m, e in cases]
    jit, b1 = render(tmp_path, variant, bsdfs, 1 + SEED_OFFSET, "jit")
    native, b2 = render(tmp_path, twin, bsdfs, 2 + SEED_OFFSET, "native")
    assert (b1, b2) == ("jit", "native")
    compare_spheres(grey(jit), grey(native), cases, masks, z_max(len(cases) * len(GROUPS)), (variant, twin))


def core_cases():
    """(surface, model, estimator) for everything the core's table of names lists (the scalar back ends run all)."""
    from msx.plugin.parameters import MODEL_INFO

    out = []
    for name, info in MODEL_INFO.items():
        if "ggx" not in info.distributions:
            continue
        out += [(s, name, "pt") for s in info.surfaces]
        out += [(s, name, "bdpt") for s in info.bdpt_surfaces]
    return out


def test_every_core_model_renders_in_scalar_spectral_as_in_scalar_rgb(tmp_path):
    """The scalar variants run every model of the core's table (the engine's refusals included): grey
    materials (F = 1, glass, grey facets) give the same image means in scalar_spectral as in scalar_rgb."""
    cases = core_cases()
    assert len(cases) > len(engine_cases())  # the core runs more than the engine (e.g. invariance on diffuse)
    bsdfs = [bsdf_of(s, m, e, {"material": "none"}) for s, m, e in cases]
    rgb, b1 = render(tmp_path, "scalar_rgb", bsdfs, 3 + SEED_OFFSET, "rgb")
    spectral, b2 = render(tmp_path, "scalar_spectral", bsdfs, 4 + SEED_OFFSET, "spectral")
    assert (b1, b2) == ("native", "native")
    compare_spheres(grey(rgb), grey(spectral), cases, sphere_masks(len(cases)), z_max(len(cases)),
                    ("scalar_rgb", "scalar_spectral"))


@pytest.mark.parametrize("variant,twin,conductor", GROUPS, ids=[g[0] for g in GROUPS])
def test_what_the_engine_refuses_renders_in_variant_by_the_batched_route(tmp_path, variant, twin, conductor):
    """What the engine's table does not run (``invariance`` on the diffuse surface, the BDPT of the dielectric
    and diffuse walks and of ``auto``) renders in the same vectorized variants through the route the refusal's
    line names, ``msx.register(backend="batched")`` (the core per wavefront), with the native back end's image
    means: every model of the core's table renders in every variant the README names."""
    cases = sorted(set(core_cases()) - set(engine_cases()))
    assert ("diffuse", "invariance", "pt") in cases
    bsdfs = [bsdf_of(s, m, e, conductor) for s, m, e in cases]
    batched, b1 = render(tmp_path, variant, bsdfs, 5 + SEED_OFFSET, "batched", backend="batched")
    native, b2 = render(tmp_path, twin, bsdfs, 6 + SEED_OFFSET, "native")
    assert (b1, b2) == ("batched", "native")
    compare_spheres(grey(batched), grey(native), cases, sphere_masks(len(cases)), z_max(len(cases) * len(GROUPS)),
                    (variant + " batched", twin))
