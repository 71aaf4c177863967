"""Mitsuba's own tests of its rough BSDFs, run on ``msx_posfree`` ``model="single"`` beside the built-in as the
control (issue 32, item 1).

Written for this project after the cases of Mitsuba 3.9.1's ``src/bsdfs/tests/test_rough_conductor.py`` and
``test_rough_dielectric.py`` (the configurations, directions, chi² resolutions and seeds are theirs): chi² tests
of ``sample`` against ``pdf`` (``mi.chi2``, in ``llvm_ad_rgb`` as upstream's ``variants_vec_backends_once_rgb``),
including ``sample_visible=false`` and single lobes chosen through ``ctx.component``; ``eval``/``pdf`` against
``eval_pdf`` (upstream runs it in ``scalar_rgb``: here in a subprocess, the native back end); and the
attached-sampling test (the derivative of ``sample``'s weight as the shading normal tilts).
"""

import json
import subprocess
import sys
import textwrap

import pytest

from llvm_support import llvm_unusable_reason  # noqa: E402  (sets DRJIT_LIBLLVM_PATH before drjit starts)

pytest.importorskip("mitsuba")
_REASON = llvm_unusable_reason()
if _REASON:
    pytest.skip(_REASON, allow_module_level=True)

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

# (name, built-in, its parameters, wi, chi² settings, ctx.component) — upstream's cases at v3.9.1.
R3 = 0.5773502691896258
CHI2_CASES = [
    ("conductor smooth", "roughconductor", {"alpha": 0.05}, (R3, R3, R3), {"res": 140, "ires": 32}, None),
    ("conductor aniso beckmann all", "roughconductor",
     {"alpha_u": 0.2, "alpha_v": 0.05, "distribution": "beckmann", "sample_visible": False}, (R3, R3, R3),
     {"ires": 16}, None),
    ("conductor aniso beckmann visible", "roughconductor",
     {"alpha_u": 0.2, "alpha_v": 0.05, "distribution": "beckmann", "sample_visible": True}, (R3, R3, R3),
     {"ires": 16, "seed": 2}, None),
    ("conductor aniso ggx all", "roughconductor",
     {"alpha_u": 0.2, "alpha_v": 0.05, "distribution": "ggx", "sample_visible": False}, (R3, R3, R3),
     {"ires": 8}, None),
    ("conductor aniso ggx visible", "roughconductor",
     {"alpha_u": 0.2, "alpha_v": 0.05, "distribution": "ggx", "sample_visible": True}, (R3, R3, R3),
     {"ires": 8}, None),
    ("dielectric rough grazing", "roughdielectric", {"alpha": 0.5}, (0.8, 0.3, 0.05), {"seed": 4}, None),
    ("dielectric beckmann all", "roughdielectric",
     {"alpha": 0.5, "sample_visible": False, "distribution": "beckmann"}, (0.5, 0.0, 0.5), {"res": 201}, None),
    ("dielectric beckmann visible", "roughdielectric",
     {"alpha": 0.5, "sample_visible": True, "distribution": "beckmann"}, (0.5, 0.0, 0.5), {}, None),
    ("dielectric ggx all", "roughdielectric",
     {"alpha": 0.5, "sample_visible": False, "distribution": "ggx"}, (0.5, 0.0, 0.5), {"res": 201}, None),
    ("dielectric ggx visible", "roughdielectric",
     {"alpha": 0.5, "sample_visible": True, "distribution": "ggx"}, (0.5, 0.5, 0.001), {"seed": 2}, None),
    ("dielectric from inside", "roughdielectric", {"alpha": 0.5}, (0.2, -0.6, -0.5), {"res": 201}, None),
    ("dielectric from inside tir", "roughdielectric", {"alpha": 0.5}, (0.8, 0.3, -0.05), {"seed": 8}, None),
    ("dielectric from denser", "roughdielectric", {"alpha": 0.5, "ext_ior": 1.5, "int_ior": 1.0},
     (0.2, -0.6, 0.5), {}, None),
    ("dielectric lobe reflection", "roughdielectric", {"alpha_u": 0.5, "alpha_v": 0.2}, (-0.5, -0.5, 0.1),
     {"res": 201, "seed": 2}, 0),
    ("dielectric aniso lobe transmission", "roughdielectric", {"alpha_u": 0.5, "alpha_v": 0.2},
     (-0.5, -0.5, 0.1), {"res": 201}, 1),
]


def as_msx(builtin, params):
    out = {"type": "msx_posfree", "model": "single", **params}
    if builtin == "roughdielectric":
        out["surface"] = "dielectric"
    return out


@pytest.fixture(scope="module")
def llvm():
    """msx's Dr.Jit engine in llvm_ad_rgb, drjit's default symbolic mode, for the module."""
    import jit_support

    with jit_support.engine_mode():
        yield mi


@pytest.mark.parametrize("who", ["builtin", "msx"])
@pytest.mark.parametrize("name,builtin,params,wi,settings,component", CHI2_CASES, ids=[c[0] for c in CHI2_CASES])
def test_chi2(llvm, who, name, builtin, params, wi, settings, component):
    ctx = mi.BSDFContext()
    if component is not None:
        ctx.component = component
    d = {"type": builtin, **params} if who == "builtin" else as_msx(builtin, params)
    xml = "".join('<%s name="%s" value="%s"/>' % (
        "boolean" if isinstance(v, bool) else "string" if isinstance(v, str) else "float", k,
        str(v).lower() if isinstance(v, bool) else v) for k, v in d.items() if k != "type")
    sample_func, pdf_func = mi.chi2.BSDFAdapter(d["type"], xml, wi=dr.normalize(mi.ScalarVector3f(*wi)), ctx=ctx)
    chi2 = mi.chi2.ChiSquareTest(domain=mi.chi2.SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func,
                                 sample_dim=3, **settings)
    assert chi2.run(), chi2.messages


@pytest.mark.parametrize("who", ["builtin", "msx"])
def test_attached_sampling(llvm, who):
    """Upstream's test13: d(weight)/d(tilt) of roughdielectric α 0.5 at normal incidence is 0.02079637…"""
    d = {"type": "roughdielectric", "alpha": 0.5}
    bsdf = mi.load_dict(d if who == "builtin" else as_msx("roughdielectric", {"alpha": 0.5}))
    angle = mi.Float(0)
    dr.enable_grad(angle)
    si = mi.SurfaceInteraction3f()
    si.p = [0, 0, 0]
    si.n = [dr.sin(angle), 0, dr.cos(angle)]
    si.sh_frame = mi.Frame3f(si.n)
    si.wi = si.sh_frame.to_local([0, 0, 1])
    bs, weight = bsdf.sample(mi.BSDFContext(), si, 0, [0.3, 0.3])
    assert dr.grad_enabled(weight)
    dr.forward(angle)
    assert dr.allclose(mi.unpolarized_spectrum(dr.grad(weight)), 0.02079637348651886)


_EVAL_PDF = textwrap.dedent("""
    import json, sys
    import drjit as dr, mitsuba as mi
    mi.set_variant("scalar_rgb")
    import msx
    msx.register()
    out = []
    for d in json.loads(sys.argv[1]):
        bsdf = mi.load_dict(d)
        si = mi.SurfaceInteraction3f()
        si.p, si.n, si.wi = [0, 0, 0], [0, 0, 1], [0, 0, 1]
        si.sh_frame = mi.Frame3f(si.n)
        ctx = mi.BSDFContext()
        for i in range(20):
            theta = i / 19.0 * (dr.pi / 2)
            wo = [dr.sin(theta), 0, dr.cos(theta)]
            v_pdf, v_eval = bsdf.pdf(ctx, si, wo=wo), bsdf.eval(ctx, si, wo=wo)[0]
            v_eval_pdf = bsdf.eval_pdf(ctx, si, wo=wo)
            out.append(bool(dr.allclose(v_eval, v_eval_pdf[0])) and bool(dr.allclose(v_pdf, v_eval_pdf[1])))
    print(json.dumps({"backend": msx.backend(), "ok": out}))
""")


def test_eval_pdf_scalar():
    """Upstream's eval_pdf tests (scalar_rgb): eval and pdf equal eval_pdf's two values, default parameters."""
    cases = [{"type": "roughconductor"}, {"type": "roughdielectric"}, as_msx("roughconductor", {}),
             as_msx("roughdielectric", {})]
    r = subprocess.run([sys.executable, "-c", _EVAL_PDF, json.dumps(cases)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    last = r.stdout.strip().splitlines()[-1]
    result = json.loads(last[last.index("{"):])
    assert result["backend"] == "native"
    assert len(result["ok"]) == 80 and all(result["ok"]), result
