"""The papers' scenes rendered by both engines: the image mean of ``llvm_ad_rgb`` (the Dr.Jit engine,
drjit's default symbolic mode) equals the one of ``scalar_rgb`` (the native back end on the Rust core)
within their noise, per model.

The two renders are independent (each engine's own random streams), so the per-pixel difference of two
unbiased images has mean 0. Its standard error comes from the pixels' channel means (the channels of one
pixel share their paths: on grey glass they are identical, and counting them as three samples made σ √3
too small) and, in case neighbouring pixels share noise, from 4×4 block means: σ is the larger of the two.
The threshold is a Šidák-corrected family-wise false-alarm rate of 1e-3 over the cases of this file. Each render runs in its
own process (the native plugin and the LLVM variant do not share one).
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
RES, SPP = 48, 16
CASES = [
    ("fig09_copper_sphere.xml", "correlated"),
    ("fig09_copper_sphere.xml", "uncorrelated"),
    ("fig09_copper_sphere.xml", "heitz"),
    ("fig01_dielectric_slab.xml", "correlated"),
    ("fig01_dielectric_slab.xml", "single"),
    ("fig09_copper_sphere.xml", "invariance"),
    ("fig01_dielectric_slab.xml", "invariance"),
]
FAMILY_RATE = 1e-3
Z_MAX = statistics.NormalDist().inv_cdf(1 - (1 - (1 - FAMILY_RATE) ** (1 / len(CASES))) / 2)

_RENDER = textwrap.dedent("""
    import json, sys
    import numpy as np
    import mitsuba as mi
    variant, scene, model, res, spp, seed, out = sys.argv[1:]
    mi.set_variant(variant)
    import msx
    msx.register()
    s = mi.load_file(scene, model=model, width=res, height=res)
    img = np.array(mi.render(s, spp=int(spp), seed=int(seed)), dtype=np.float64)
    np.save(out, img)
    print(json.dumps({"backend": msx.backend()}))
""")


def render(tmp_path, variant, scene, model, seed):
    from msx._render import scenes_dir

    path = str(scenes_dir() / scene)
    out = tmp_path / ("%s_%s_%s.npy" % (variant, scene, model))
    r = subprocess.run([sys.executable, "-c", _RENDER, variant, path, model, str(RES), str(SPP), str(seed), str(out)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    backend = json.loads(r.stdout.strip().splitlines()[-1])["backend"]
    return np.load(out), backend


@pytest.mark.parametrize("scene,model", CASES)
def test_image_means_equal_across_engines(tmp_path, scene, model):
    jit, b1 = render(tmp_path, "llvm_ad_rgb", scene, model, 1 + SEED_OFFSET)
    native, b2 = render(tmp_path, "scalar_rgb", scene, model, 2 + SEED_OFFSET)
    assert (b1, b2) == ("jit", "native")
    assert np.all(np.isfinite(jit)) and jit.mean() > 0
    d = (jit - native).mean(axis=-1)  # one value per pixel
    blocks = d.reshape(RES // 4, 4, RES // 4, 4).mean(axis=(1, 3)).ravel()
    se = max(d.std(ddof=1) / math.sqrt(d.size), blocks.std(ddof=1) / math.sqrt(blocks.size))
    z = d.mean() / se
    print("%s %s: llvm jit %.5f, scalar native %.5f, z %.2f" % (scene, model, jit.mean(), native.mean(), z))
    assert abs(z) <= Z_MAX, (scene, model, jit.mean(), native.mean(), z)
