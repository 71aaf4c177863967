"""Fuzz test through the public plugin (``msx_posfree`` loaded by Mitsuba):
random and adversarial parameters (some invalid: they must be refused with a
message naming a parameter), textures holding NaN, ±Inf, negative and huge
values, extreme α and IORs, NaN/Inf/zero/below-horizon directions and odd
sample values.

Asserted: every output is finite and non-negative, and the core's C ABI
cleaned nothing (``msx.diagnostics()`` — counted before the ABI sanitises,
so this is a check on the raw values). The C ABI alone is fuzzed with 10⁶
calls in tests/fuzz_abi.rs; the LLVM route with 10⁶ lanes in test_llvm.py.
"""

import math
import random

import numpy as np

from conftest import set_variant

N_CONFIGS = 160
CALLS_PER_CONFIG = 160  # x 4 methods
SPECIAL = [math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e30, 1e-30, 1e-45, 3.4e38]
MODELS = ["single", "uncorrelated", "correlated", "heitz", "invariance", "fastmsx", "compensated", "auto"]


def bad_bitmap(mi, rng, channels):
    """A 4x4 bitmap texture mixing plausible values with SPECIAL ones."""
    vals = np.array([[[rng.choice(SPECIAL) if rng.random() < 0.5 else rng.uniform(0.0, 2.0)
                       for _ in range(channels)] for _ in range(4)] for _ in range(4)], dtype=np.float32)
    return {"type": "bitmap", "data": mi.TensorXf(vals), "raw": True, "filter_type": "nearest"}


def random_params(mi, rng):
    surface = rng.choice(["conductor", "dielectric", "diffuse"])
    p = {"type": "msx_posfree", "surface": surface, "distribution": rng.choice(["ggx", "beckmann"]),
         "model": rng.choice(MODELS), "estimator": rng.choice(["pt", "bdpt"]), "seed": rng.randrange(1 << 32)}
    r = rng.random()
    if r < 0.3:
        p["alpha"] = bad_bitmap(mi, rng, 1)
    elif r < 0.5:
        p["alpha_u"], p["alpha_v"] = 10 ** rng.uniform(-4, 1), 10 ** rng.uniform(-4, 1)
    else:
        p["alpha"] = 10 ** rng.uniform(-6, 3)
    if rng.random() < 0.2:
        p["max_bounces"] = rng.randint(1, 64)
    if surface == "conductor":
        r = rng.random()
        if r < 0.4:
            p["material"] = rng.choice(["Cu", "Au", "Al", "none"])
        elif r < 0.8:
            p["eta"], p["k"] = bad_bitmap(mi, rng, 3), bad_bitmap(mi, rng, 3)
        if rng.random() < 0.3:
            p["specular_reflectance"] = bad_bitmap(mi, rng, 3)
    elif surface == "dielectric":
        p["int_ior"] = rng.choice([1.5, 1.0001, 0.5, 3.0, "bk7", "water", 1e3, 1e-3])
        p["ext_ior"] = rng.choice([1.0, "air", 1.33])
        if rng.random() < 0.3:
            p["specular_transmittance"] = bad_bitmap(mi, rng, 3)
    else:
        if rng.random() < 0.5:
            p["reflectance"] = bad_bitmap(mi, rng, 3)
    return p


def random_dir(rng):
    r = rng.random()
    if r < 0.08:
        return [rng.choice(SPECIAL), rng.uniform(-1, 1), rng.choice([1.0, -1.0, 0.0])]
    if r < 0.15:
        return rng.choice([[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0, 0], [0.6, 0.8, 1e-7], [0.6, 0.8, -1e-7]])
    z = rng.uniform(-1, 1) if rng.random() < 0.5 else math.copysign(10 ** rng.uniform(-7, -1), rng.uniform(-1, 1))
    phi = rng.uniform(0, 2 * math.pi)
    s = math.sqrt(max(0.0, 1 - z * z))
    return [s * math.cos(phi), s * math.sin(phi), z]


def finite_nonneg(values):
    return all(math.isfinite(v) and v >= 0.0 for v in values)


def test_fuzz_scalar_plugin():
    mi = set_variant("scalar_rgb")
    import msx

    rng = random.Random(20261124)
    before = msx.diagnostics()
    loaded = refused = calls = 0
    bad = []
    for _ in range(N_CONFIGS):
        params = random_params(mi, rng)
        try:
            bsdf = mi.load_dict(params)
        except Exception as e:  # invalid combinations must be refused by name
            last = str(e).strip().splitlines()[-1]
            assert "msx_posfree:" in last and "'" in last, last
            refused += 1
            continue
        loaded += 1
        ctx = mi.BSDFContext(mi.TransportMode.Importance if rng.random() < 0.5 else mi.TransportMode.Radiance)
        si = mi.SurfaceInteraction3f()
        for _ in range(CALLS_PER_CONFIG):
            si.wi = mi.Vector3f(*random_dir(rng))
            si.uv = mi.Point2f(rng.random(), rng.random())
            wo = mi.Vector3f(*random_dir(rng))
            v = bsdf.eval(ctx, si, wo)
            p = bsdf.pdf(ctx, si, wo)
            v2, p2 = bsdf.eval_pdf(ctx, si, wo)
            s1 = rng.choice(SPECIAL) if rng.random() < 0.05 else rng.random()
            bs, w = bsdf.sample(ctx, si, s1, mi.Point2f(rng.random(), rng.random()))
            out = list(v) + [float(p)] + list(v2) + [float(p2), float(bs.pdf)] + list(w)
            calls += 4
            if not finite_nonneg(out):
                bad.append((params, list(si.wi), list(wo), out))
    after = msx.diagnostics()
    print(f"\n[fuzz scalar_rgb] {loaded} configurations loaded, {refused} refused by name, {calls} BSDF calls; "
          f"diagnostics {after}")
    assert not bad, f"{len(bad)} non-finite or negative outputs, e.g. {bad[:3]}"
    assert loaded > N_CONFIGS // 3
    assert {k: after[k] - before[k] for k in after} == {"nonfinite": 0, "negative": 0, "panics": 0}
