"""A tiny render through the plugin: finite, non-negative, and
model="single" matches roughconductor."""

import numpy as np
import pytest

from conftest import set_variant


def scene_dict(mi, bsdf):
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 6},
        "sensor": {
            "type": "perspective",
            "fov": 35,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 4},
        },
        "sphere": {"type": "sphere", "bsdf": bsdf},
        "light": {"type": "directional", "direction": [0.3, -0.5, -1.0], "irradiance": 3.0},
        "env": {"type": "constant", "radiance": 0.5},
    }


def render(mi, bsdf, seed=0):
    import drjit as dr

    dr.set_thread_count(1)  # Python BSDFs serialize on the GIL (docs/mitsuba.md)
    scene = mi.load_dict(scene_dict(mi, bsdf))
    return np.array(mi.render(scene, seed=seed), dtype=np.float64)


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
def test_single_render_matches_roughconductor(variant):
    mi = set_variant(variant)
    common = dict(distribution="ggx", alpha=0.3, material="Cu")
    ours = render(mi, dict(type="msx_posfree", model="single", **common), seed=7)
    ref = render(mi, dict(type="roughconductor", **common), seed=7)
    assert np.all(np.isfinite(ours)) and np.all(ours >= 0.0)
    rel = abs(ours.mean() - ref.mean()) / ref.mean()
    print("\n[%s render] mean msx %.6f, roughconductor %.6f, rel. diff %.2e, max |pixel diff| %.2e"
          % (variant, ours.mean(), ref.mean(), rel, np.abs(ours - ref).max()))
    assert rel < 0.02


@pytest.mark.parametrize("model", ["uncorrelated", "correlated"])
def test_multiple_scattering_render(model):
    mi = set_variant("scalar_rgb")
    common = dict(distribution="ggx", alpha=0.8)
    ms = render(mi, dict(type="msx_posfree", model=model, **common), seed=1)
    single = render(mi, dict(type="msx_posfree", model="single", **common), seed=1)
    assert np.all(np.isfinite(ms)) and np.all(ms >= 0.0)
    # A rough mirror regains energy with multiple scattering.
    print("\n[%s render] mean %.5f vs single %.5f" % (model, ms.mean(), single.mean()))
    assert ms.mean() > single.mean()
