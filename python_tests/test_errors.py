"""Bad parameters fail at load with a message naming the parameter; bad call
inputs give finite zeros, never NaN."""

import math

import pytest

from conftest import set_variant


def load_error(mi, **params):
    with pytest.raises(Exception) as info:
        mi.load_dict(dict(type="msx_posfree", **params))
    return str(info.value)


BAD = [
    # (params, words that must appear in the message)
    (dict(surface="plastic"), ["surface", "conductor", "dielectric", "diffuse"]),
    (dict(distribution="phong"), ["distribution", "beckmann", "ggx"]),
    (dict(alpha=0.0), ["alpha"]),
    (dict(alpha=-0.2), ["alpha"]),
    (dict(alpha=float("nan")), ["alpha"]),
    (dict(alpha=float("inf")), ["alpha"]),
    (dict(alpha_u=0.2, alpha_v=0.0), ["alpha_v"]),
    (dict(alpha_u=-1.0, alpha_v=0.1), ["alpha_u"]),
    (dict(alpha=0.2, alpha_u=0.3), ["alpha_u"]),
    (dict(material="Unobtainium"), ["material"]),
    (dict(material="Cu", eta=1.5), ["eta", "material"]),
    (dict(material="Au", k=2.0), ["k", "material"]),
    (dict(surface="diffuse", model="compensated"), ["model", "diffuse", "invariance"]),
    (dict(surface="diffuse", model="single"), ["model", "diffuse", "uncorrelated"]),
    (dict(surface="dielectric", model="fastmsx"), ["model", "dielectric"]),
    (dict(surface="dielectric", int_ior=-1.0), ["int_ior"]),
    (dict(surface="dielectric", int_ior="unobtainium"), ["int_ior"]),
    (dict(surface="dielectric", material="Cu"), ["material", "dielectric"]),
    (dict(surface="diffuse", int_ior=1.5), ["int_ior", "diffuse"]),
    (dict(surface="diffuse", specular_reflectance=0.5), ["specular_reflectance", "diffuse"]),
    (dict(model="fastmsx"), ["distribution", "fastmsx", "ggx"]),  # default distribution is beckmann
    (dict(model="fastmsx", distribution="beckmann"), ["distribution", "ggx"]),
    (dict(model="correlated", auto_tolerance=0.05), ["auto_tolerance", "auto"]),
    (dict(model="auto", auto_tolerance=0.0), ["auto_tolerance", "(0, 1)"]),
    (dict(model="auto", auto_tolerance=1.0), ["auto_tolerance", "(0, 1)"]),
    (dict(model="auto", auto_tolerance="low"), ["auto_tolerance"]),
    (dict(mis_density="lambert"), ["mis_density", "single_cosine, cui, cui_typo"]),
    (dict(surface="dielectric", mis_density="cui"), ["mis_density", "conductor walks only", "dielectric"]),
    (dict(model="single", mis_density="single_cosine"), ["mis_density", "conductor walks only", "single"]),
    (dict(model="Single"), ["model", "single"]),
    (dict(estimator="bdpt", model="single"), ["estimator", "bdpt", "uncorrelated"]),
    (dict(surface="dielectric", model="heitz", estimator="bdpt"), ["estimator", "bdpt", "uncorrelated"]),
    (dict(estimator="mlt"), ["estimator", "pt"]),
    (dict(max_bounces=0), ["max_bounces", "1024"]),
    (dict(max_bounces=2000), ["max_bounces", "1024"]),
    (dict(max_bounces=-3), ["max_bounces"]),
    (dict(seed=-1), ["seed"]),
    (dict(int_ior=1.5), ["int_ior"]),
    (dict(ext_ior="air"), ["ext_ior"]),
    (dict(specular_transmittance=0.5), ["specular_transmittance"]),
    (dict(reflectance=0.5), ["reflectance"]),
    (dict(alpah=0.3), ["unknown parameter 'alpah'", "did you mean 'alpha'?"]),  # misspelled
    (dict(materiel="Cu"), ["unknown parameter 'materiel'", "did you mean 'material'?"]),
    (dict(sample_visible="no"), ["sample_visible", "boolean"]),
]


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
@pytest.mark.parametrize("params,words", BAD, ids=[repr(p) for p, _ in BAD])
def test_bad_parameter_raises_naming_it(variant, params, words):
    mi = set_variant(variant)
    msg = load_error(mi, **params)
    for w in words:
        assert w in msg, "message %r lacks %r" % (msg, w)


@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
def test_bad_parameter_message_is_not_buried_in_msx_frames(variant):
    """Mitsuba quotes a Python plugin's traceback in its error: one frame of msx at most, then the line."""
    mi = set_variant(variant)
    msg = load_error(mi, alpha=-1.0)
    msx_frames = [line for line in msg.splitlines() if line.strip().startswith("File") and "/msx/" in line]
    assert len(msx_frames) <= 1, msg
    assert msg.strip().splitlines()[-1].startswith("MsxParameterError: msx_posfree: parameter 'alpha'"), msg


# Every parameter Mitsuba 3.9.1's roughconductor / roughdielectric read (src/bsdfs/roughconductor.cpp,
# roughdielectric.cpp and include/mitsuba/render/microfacet.h at that version), with a value each accepts.
BUILTIN_PARAMETERS = {
    "roughconductor": dict(distribution="ggx", alpha=0.3, material="none", eta=0.2, k=3.0,
                           specular_reflectance=0.9, sample_visible=False),
    "roughdielectric": dict(distribution="beckmann", alpha_u=0.2, alpha_v=0.4, int_ior=1.4, ext_ior=1.0,
                            specular_reflectance=0.9, specular_transmittance=0.8, sample_visible=True),
}


@pytest.mark.parametrize("builtin", sorted(BUILTIN_PARAMETERS))
def test_every_builtin_parameter_is_understood(rgb, builtin):
    """A built-in's parameters, all at once, load on msx_posfree (the type changed; glass says its surface)."""
    mi = rgb
    params = BUILTIN_PARAMETERS[builtin]
    mi.load_dict(dict(type=builtin, **params))  # the control: the built-in takes them
    surface = {"surface": "dielectric"} if builtin == "roughdielectric" else {}
    b = mi.load_dict(dict(type="msx_posfree", model="single", **surface, **params))
    assert "MsxPosfree" in str(b)


def test_good_parameters_load(rgb):
    mi = rgb
    for params in [
        {},
        dict(distribution="ggx", alpha=0.5, material="Cu", model="single"),
        dict(alpha_u=0.3, alpha_v=0.1, model="uncorrelated", estimator="pt", max_bounces=16, seed=7),
        dict(eta=1.2, k=3.4, specular_reflectance=0.8),
        dict(eta={"type": "rgb", "value": [0.2, 0.9, 1.1]}, k={"type": "rgb", "value": [3.9, 2.4, 2.1]}),
        dict(material="none", max_bounces=1024),
        dict(model="heitz", mis_density="cui"),
        dict(model="auto", mis_density="cui_typo"),
        dict(alpha={"type": "checkerboard", "color0": 0.1, "color1": 0.4}),
        dict(sample_visible=False, model="single"),
        dict(sample_visible=True, model="correlated", surface="dielectric"),
    ]:
        b = mi.load_dict(dict(type="msx_posfree", **params))
        assert "MsxPosfree" in str(b)


def finite_nonneg(values):
    return all(math.isfinite(v) and v >= 0.0 for v in values)


@pytest.mark.parametrize("model", ["single", "uncorrelated", "correlated"])
@pytest.mark.parametrize("variant", ["scalar_rgb", "scalar_spectral"])
def test_bad_call_inputs_give_finite_zero(variant, model):
    mi = set_variant(variant)
    b = mi.load_dict(dict(type="msx_posfree", model=model, material="Cu", distribution="ggx", alpha=0.5))
    ctx = mi.BSDFContext()
    nan = float("nan")
    good = mi.Vector3f(0.0, 0.6, 0.8)
    below = mi.Vector3f(0.0, 0.6, -0.8)
    bad_dirs = [
        mi.Vector3f(nan, 0.0, 1.0),
        mi.Vector3f(nan, nan, nan),
        mi.Vector3f(0.0, 0.0, 0.0),
        mi.Vector3f(float("inf"), 0.0, 1.0),
    ]
    if model == "single":
        bad_dirs.append(below)  # single scattering is defined above the shading plane only
    else:
        # The position-free models take ω_i below the shading plane (normal mapping, docs/paper-notes.md);
        # ω_o below it is still outside the BSDF's support. Specular reflections never lower z along a
        # conductor walk, so from ω_i with z = −0.8 only ω_o with z ≥ 0.8 is reachable: `steep` (z = 0.96)
        # is; `good` (z = 0.8, the edge of that cone) has measure zero and evaluates to 0.
        steep = mi.Vector3f(0.0, 0.28, 0.96)
        si = mi.SurfaceInteraction3f()
        si.wi = below
        si.p = mi.Point3f(0.1, 0.2, 0.3)
        if mi.is_spectral:
            si.wavelengths = mi.Spectrum(450.0, 550.0, 600.0, 700.0)
        assert max(float(x) for x in b.eval(ctx, si, steep)) > 0.0 and float(b.pdf(ctx, si, steep)) > 0.0
        assert max(float(x) for x in b.eval(ctx, si, below)) == 0.0 and float(b.pdf(ctx, si, below)) == 0.0
        bs, w = b.sample(ctx, si, 0.5, mi.Point2f(0.3, 0.6))
        assert float(bs.pdf) > 0.0 and float(bs.wo[2]) > 0.0 and finite_nonneg([float(x) for x in w])
    for bad in bad_dirs:
        for wi, wo in [(bad, good), (good, bad), (bad, bad)]:
            si = mi.SurfaceInteraction3f()
            si.wi = wi
            if mi.is_spectral:
                si.wavelengths = mi.Spectrum(450.0, 550.0, 600.0, 700.0)
            v = [float(x) for x in b.eval(ctx, si, wo)]
            p = float(b.pdf(ctx, si, wo))
            ev, ep = b.eval_pdf(ctx, si, wo)
            assert finite_nonneg(v + [p, float(ep)] + [float(x) for x in ev])
            if wi is bad:
                assert max(v) == 0.0 and p == 0.0
            if wi is bad or wo is bad:
                assert max(v) == 0.0 and max(float(x) for x in ev) == 0.0
        si = mi.SurfaceInteraction3f()
        si.wi = bad
        for s1, s2 in [(0.5, (0.5, 0.5)), (nan, (nan, nan)), (0.0, (0.0, 0.0)), (0.999, (1.0, 1.0))]:
            bs, w = b.sample(ctx, si, s1, mi.Point2f(*s2))
            assert float(bs.pdf) == 0.0 and max(float(x) for x in w) == 0.0
    # good wi with extreme sample values: finite
    si = mi.SurfaceInteraction3f()
    si.wi = good
    for s1, s2 in [(nan, (nan, nan)), (0.0, (0.0, 0.0)), (1.0, (1.0, 1.0)), (0.5, (1e-30, 0.9999999))]:
        bs, w = b.sample(ctx, si, s1, mi.Point2f(*s2))
        assert finite_nonneg([float(bs.pdf)] + [float(x) for x in w] + [abs(float(x)) for x in bs.wo])


def test_disabled_component_gives_zero(rgb):
    mi = rgb
    b = mi.load_dict(dict(type="msx_posfree", model="single", alpha=0.3))
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0.0, 0.6, 0.8)
    wo = mi.Vector3f(0.0, -0.6, 0.8)
    ctx = mi.BSDFContext()
    assert float(b.eval(ctx, si, wo)[0]) > 0
    ctx.type_mask = int(mi.BSDFFlags.DiffuseReflection)
    assert float(b.eval(ctx, si, wo)[0]) == 0.0 and float(b.pdf(ctx, si, wo)) == 0.0
    bs, w = b.sample(ctx, si, 0.5, mi.Point2f(0.3, 0.3))
    assert float(bs.pdf) == 0.0 and float(w[0]) == 0.0
    ctx = mi.BSDFContext()
    ctx.component = 1
    assert float(b.eval(ctx, si, wo)[0]) == 0.0


def test_register_rejects_polarized_variants():
    """Polarized variants are not supported: register() says so instead of misbehaving."""
    import mitsuba as mi
    import msx

    others = [v for v in mi.variants() if v.startswith("scalar_") and "polarized" in v]
    if not others:
        pytest.skip("no polarized scalar variant installed")
    prev = mi.variant()
    try:
        mi.set_variant(others[0])
        with pytest.raises(NotImplementedError):
            msx.register()
    except ImportError:
        pytest.skip("variant %s cannot be loaded here" % others[0])
    finally:
        if prev:
            mi.set_variant(prev)
