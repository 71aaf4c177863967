"""Wang 2022 Fig. 7 in image space: scenes/fig07_normalmap.xml under plain normal mapping. Where the
normal map tilts the shading normal away from the camera, the nested BSDF receives ω_i below the
perturbed shading plane: single scattering is black there, the full-sphere position-free models are not.
Measured as the fraction of the sphere's pixels darker than 1 % of the median of the single-scattering
image (one threshold for every model); multiple scattering must stay below a tenth of single scattering's.
With Mitsuba's own workaround (-D flip=true: normal flip and shadowing term) single scattering has no
black pixel either."""

import numpy as np
import pytest

from conftest import set_variant

W = 96  # a black pixel is one whose whole footprint is black: fewer at low resolution
SPP = 16
MODELS = ["correlated", "uncorrelated", "auto"]


def scene_path():
    from msx._render import scenes_dir

    return str(scenes_dir() / "fig07_normalmap.xml")


def load(mi, **params):
    from msx._render import load_scene, with_assets

    params = with_assets(scene_path(), dict({"width": str(W), "height": str(W)}, **params))
    return load_scene(mi, scene_path(), **params)


def sphere_mask(mi, sub=3):
    """Pixels whose whole footprint (sub × sub rays) hits the sphere."""
    scene = load(mi, bsdf="roughconductor")
    sensor = scene.sensors()[0]
    mask = np.ones((W, W), dtype=bool)
    for y in range(W):
        for x in range(W):
            for j in range(sub * sub):
                uv = mi.Point2f((x + (j % sub + 0.5) / sub) / W, (y + (j // sub + 0.5) / sub) / W)
                ray, _ = sensor.sample_ray(0.0, 0.5, uv, mi.Point2f(0.5, 0.5))
                if not scene.ray_intersect(ray).is_valid():
                    mask[y, x] = False
                    break
    return mask


def luminance(mi, **params):
    img = np.array(mi.render(load(mi, **params), seed=3, spp=SPP), dtype=np.float64)[..., :3]
    assert np.all(np.isfinite(img)) and np.all(img >= 0)
    return img @ np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def mi_mask():
    mi = set_variant("scalar_rgb")
    return mi, sphere_mask(mi)


def black_fractions(mi, mask, flip):
    single = luminance(mi, bsdf="msx_posfree", model="single", flip=flip)[mask]
    threshold = 0.01 * np.median(single)
    out = {"single": float((single < threshold).mean())}
    for model in MODELS:
        out[model] = float((luminance(mi, bsdf="msx_posfree", model=model, flip=flip)[mask] < threshold).mean())
    return out, threshold


def test_plain_normal_mapping_black_pixels(mi_mask):
    mi, mask = mi_mask
    fr, threshold = black_fractions(mi, mask, "false")
    print("\n[fig07, plain normal mapping] %d sphere pixels, threshold %.3g; black fraction: %s"
          % (mask.sum(), threshold, ", ".join("%s %.4f" % kv for kv in fr.items())))
    assert fr["single"] > 0.02, "the scene should show single scattering's black regions"
    for model in MODELS:
        assert fr[model] < fr["single"] / 10, model


def test_mitsuba_flip_hides_them(mi_mask):
    mi, mask = mi_mask
    fr, _ = black_fractions(mi, mask, "true")
    print("\n[fig07, Mitsuba's flip + shadowing] black fraction: %s" % ", ".join("%s %.4f" % kv for kv in fr.items()))
    assert fr["single"] < 0.002
