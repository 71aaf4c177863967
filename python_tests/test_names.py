"""The one table of names (src/config.rs, read through msx_choice in include/msx.h; docs/adding-a-model.md).

- `msx.plugin.parameters` builds its dicts from the table: every name of the table is accepted, in the table's order,
  with the table's code, and the header's MSX_MODEL_* codes are unchanged (compatibility);
- every model of the table loads on every surface and distribution the table gives it, through `msx.plugin.parameters`
  and the native plugin (scalar_rgb), and is refused on the others by the core with one line;
- an unknown name gets one line that lists exactly the table's names — from `msx.plugin.parameters` and from the native
  plugin's own parser (which reads the table through the C ABI);
- README.md's model table (written by hand) says what the table says: the models, their surfaces and
  distributions;
- the C ABI answers an unknown parameter, an index out of range and a null pointer without crashing.
"""

from pathlib import Path

import pytest

from conftest import set_variant

from msx.plugin import parameters
from msx._native import ffi, lib


def test_dicts_are_the_table_in_its_order():
    for parameter, d in (("surface", parameters.SURFACES), ("distribution", parameters.DISTRIBUTIONS),
                         ("model", parameters.MODELS), ("estimator", parameters.ESTIMATORS)):
        rows = parameters.TABLE[parameter]
        assert list(d.items()) == [(c.name, c.code) for c in rows]
        assert len(set(d.values())) == len(d), parameter
    # The header's constants keep their values (code compatibility).
    assert [lib.MSX_MODEL_SINGLE, lib.MSX_MODEL_UNCORRELATED, lib.MSX_MODEL_CORRELATED, lib.MSX_MODEL_HEITZ,
            lib.MSX_MODEL_INVARIANCE, lib.MSX_MODEL_FASTMSX, lib.MSX_MODEL_COMPENSATED, lib.MSX_MODEL_AUTO] == list(range(8))
    for name, const in (("single", lib.MSX_MODEL_SINGLE), ("fastmsx", lib.MSX_MODEL_FASTMSX),
                        ("auto", lib.MSX_MODEL_AUTO)):
        assert parameters.MODELS[name] == const


def test_capability_filters():
    assert parameters.models("diffuse", estimator="bdpt") == [
        c.name for c in parameters.TABLE["model"] if "diffuse" in c.bdpt_surfaces]
    for name in parameters.models(random_walk=False):
        assert not parameters.MODEL_INFO[name].bdpt_surfaces, name
    for name in parameters.models(shortcut=True):
        assert parameters.MODEL_INFO[name].runs in parameters.MODELS
    with pytest.raises(TypeError, match="unknown capability"):
        parameters.models(fast=True)


def test_abi_refuses_bad_requests():
    c = ffi.new("MsxChoice *")
    n = lib.msx_choice_count(lib.MSX_CHOICE_MODEL)
    assert n == len(parameters.MODELS)
    assert lib.msx_choice(lib.MSX_CHOICE_MODEL, n, c) == lib.MSX_ERR_INVALID_PARAMETER
    assert ffi.string(c.name) == b"" and c.code == 0
    assert lib.msx_choice(lib.MSX_CHOICE_PARAMETERS, 0, c) == lib.MSX_ERR_INVALID_PARAMETER
    assert lib.msx_choice_count(lib.MSX_CHOICE_PARAMETERS) == 0
    assert lib.msx_choice_parameter(lib.MSX_CHOICE_PARAMETERS) == ffi.NULL
    assert lib.msx_choice(lib.MSX_CHOICE_MODEL, 0, ffi.NULL) == lib.MSX_ERR_NULL_POINTER


def _readme_model_table():
    """{model: {surface: cell}} of README.md's model table (header `| model | <surfaces…> | what it is |`)."""
    lines = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| model | "))
    header = [c.strip() for c in lines[start].strip().strip("|").split("|")]
    surfaces = header[1:-1]
    assert surfaces == list(parameters.SURFACES), f"README.md's model table has the surface columns {surfaces}"
    table = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        table[cells[0].strip("`")] = dict(zip(surfaces, cells[1:1 + len(surfaces)]))
    return table


def _cell(choice, surface):
    """What README.md's model table should say of a model on a surface, from the core's table."""
    if surface not in choice.surfaces:
        return ""
    if set(choice.distributions) == set(parameters.DISTRIBUTIONS):
        return "✓"
    return " or ".join(d.upper() if d == "ggx" else d.capitalize() for d in choice.distributions) + " only"


def test_readme_model_table_is_the_table():
    """README.md's model table (written by hand) lists exactly the core's models, in its order, each on the
    surfaces (and distributions) the core's table gives it: ✓, "GGX only", or empty."""
    readme = _readme_model_table()
    names = [c.name for c in parameters.TABLE["model"]]
    missing = [n for n in names if n not in readme]
    extra = [n for n in readme if n not in names]
    assert not missing and not extra, f"README.md's model table: missing {missing}, not in the core's table {extra}"
    assert list(readme) == names, f"README.md's model table lists {list(readme)}; the core's order is {names}"
    wrong = [f"{c.name} on {s}: README says {readme[c.name][s]!r}, the core's table {_cell(c, s)!r}"
             for c in parameters.TABLE["model"] for s in parameters.SURFACES if readme[c.name][s] != _cell(c, s)]
    assert not wrong, "README.md's model table disagrees with the core's table: " + "; ".join(wrong)


def _params_of(surface, model, distribution):
    d = dict(type="msx_posfree", surface=surface, model=model, distribution=distribution, alpha=0.4)
    if surface == "dielectric":
        d["int_ior"] = 1.5
    return d


def _cases():
    for c in parameters.TABLE["model"]:
        for surface in parameters.SURFACES:
            for distribution in parameters.DISTRIBUTIONS:
                yield c.name, surface, distribution, surface in c.surfaces and distribution in c.distributions


@pytest.fixture(scope="module")
def scalar():
    mi = set_variant("scalar_rgb")
    import msx

    msx.register(backend="native")
    assert msx.backend() == "native"
    yield mi
    msx.register()


def test_every_name_loads_where_the_table_says(scalar):
    mi = scalar
    for model, surface, distribution, supported in _cases():
        params = _params_of(surface, model, distribution)
        if supported:
            assert "native" in str(mi.load_dict(params)), (model, surface, distribution)
        else:
            with pytest.raises(Exception) as e:
                mi.load_dict(params)
            assert "msx_posfree" in str(e.value) and model in str(e.value), (model, surface, distribution)


def _one_line(error):
    lines = [line for line in str(error).strip().splitlines() if "unknown value" in line]
    assert len(lines) == 1, str(error)
    return lines[0]


@pytest.mark.parametrize("parameter", ["surface", "distribution", "model", "estimator"])
def test_unknown_names_list_exactly_the_table(scalar, parameter):
    mi = scalar
    names = ", ".join(c.name for c in parameters.TABLE[parameter])
    expected = "msx_posfree: unknown value 'nope' for parameter '%s'; allowed values: %s" % (parameter, names)
    params = dict(_params_of("conductor", "correlated", "ggx"), **{parameter: "nope"})
    with pytest.raises(Exception) as e:
        mi.load_dict(params)
    assert _one_line(e.value).endswith(expected)

    # The native plugin's own parser (native/msx_mitsuba.cpp reads the table through msx_choice), given the
    # properties the Python front end would pass it but for the one unknown name.
    from msx.plugin.native import NATIVE_PLUGIN

    props = dict(type=NATIVE_PLUGIN, surface="conductor", distribution="ggx", model="correlated", estimator="pt",
                 max_bounces=0, seed="0", auto_tolerance=0.0, isotropic=True, alpha_u=0.4, eta=0.0, k=1.0,
                 specular_reflectance=1.0)
    props[parameter] = "nope"
    with pytest.raises(Exception) as e:
        mi.load_dict(props)
    assert _one_line(e.value).endswith(expected)
