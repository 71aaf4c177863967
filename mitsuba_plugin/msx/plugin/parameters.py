"""Every route: parsing and validation of ``msx_posfree`` scene parameters (README.md's parameter table),
against the core's table of names (models, estimators, distributions, surfaces, MIS densities; src/config.rs,
read by ``msx/names.py``).

Every back end parses a scene's parameters here — the scalar Python class (``scalar.py``), the native C++
plugin (``native.py``), the batched route (``vectorized.py``) and the Dr.Jit engine (``jit_bsdf.py``) — so the
messages are the same everywhere. Everything here runs once per BSDF instance at scene load; errors name the
parameter and the allowed values.
"""

import math

from .._native import lib
# The core's table of names and what each model supports (``msx/names.py``), re-exported: the routes read it here.
from ..names import DISTRIBUTIONS, ESTIMATORS, MODEL_INFO, MODELS, PLUGIN, SURFACES, TABLE, Choice  # noqa: F401


def models(surface=None, *, estimator="pt", distribution=None, **flags):
    """The names of the models (in the table's order) that run on ``surface`` (any if None) with
    ``estimator`` and ``distribution`` (any if None), and whose flags (``random_walk``, ``per_order``,
    ``exact``; ``shortcut``: it runs another model's walk, as ``auto``) have the given values."""
    unknown = set(flags) - {"random_walk", "per_order", "exact", "shortcut"}
    if unknown:
        raise TypeError("models(): unknown capability %s; known: random_walk, per_order, exact, shortcut"
                        % ", ".join(sorted(unknown)))
    out = []
    for c in TABLE["model"]:
        if surface is not None and surface not in (c.bdpt_surfaces if estimator == "bdpt" else c.surfaces):
            continue
        if surface is None and estimator == "bdpt" and not c.bdpt_surfaces:
            continue
        if distribution is not None and distribution not in c.distributions:
            continue
        have = {"random_walk": c.random_walk, "per_order": c.per_order, "exact": c.exact,
                "shortcut": c.runs != c.name}
        if any(have[k] != bool(v) for k, v in flags.items()):
            continue
        out.append(c.name)
    return out


# The conductor walks' MIS density (src/models/mis.rs); `cui_typo` is Cui's density with the H-function as the
# authors' code prints it, kept for the measurement in benches/README.md (docs/paper-notes.md).
MIS_DENSITIES = {c.name: c.code for c in TABLE["mis_density"]}
DEFAULT_MIS_DENSITY = "single_cosine"
# The models whose conductor walk reports the chosen density (elsewhere the parameter is refused).
MIS_DENSITY_MODELS = tuple(models("conductor", random_walk=True))

# The surface-specific parameters each surface accepts (the others are errors).
SURFACE_PARAMS = {
    "conductor": ("material", "eta", "k", "specular_reflectance"),
    "dielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance"),
    "diffuse": ("reflectance",),
}
COMMON_PARAMS = ("surface, distribution, alpha, alpha_u, alpha_v, model, estimator, max_bounces, seed, auto_tolerance, "
                 "mis_density, sample_visible, differentiate_directions")
# The models whose sampling ``sample_visible=false`` changes (as the built-ins': normals drawn from D·cos θ_m), on
# every route: the Dr.Jit engine (jit/single.py) and the core (src/models/single/, MsxParams::sample_all_normals).
# A walk draws visible normals by construction.
SAMPLE_VISIBLE_MODELS = ("single", "fastmsx", "compensated")

MAX_BOUNCES_LIMIT = lib.MSX_MAX_BOUNCES_LIMIT
SEED_LIMIT = 2**64


def channels_of(mi, variant):
    """Spectral channels per call in a Mitsuba variant (RGB 3, spectral 4, mono 1)."""
    if mi.is_polarized:
        raise NotImplementedError("%s: polarized variants ('%s') are not supported" % (PLUGIN, variant))
    if mi.is_spectral:
        return 4
    if mi.is_rgb:
        return 3
    return 1


class MsxParameterError(ValueError):
    """A scene parameter of ``msx_posfree`` is invalid."""


def _fmt(values):
    return ", ".join("'%s'" % v for v in values)


def _choice(props, name, default, allowed):
    """A string parameter restricted to ``allowed`` (dict or sequence)."""
    if not (name in props):
        return default
    value = props.get(name)
    if not isinstance(value, str):
        raise MsxParameterError(
            "%s: parameter '%s' must be a string, one of %s (got %r)" % (PLUGIN, name, _fmt(allowed), value)
        )
    if value in allowed:
        return value
    raise MsxParameterError(
        "%s: unknown value '%s' for parameter '%s'; allowed values: %s" % (PLUGIN, value, name, ", ".join(allowed))
    )


def _bool(props, name, default):
    if not (name in props):
        return default
    value = props.get(name)
    if not isinstance(value, bool):
        raise MsxParameterError("%s: parameter '%s' must be a boolean (got %r)" % (PLUGIN, name, value))
    return value


def warn(mi, text):
    """One line in Mitsuba's log (a warning), when ``text`` is not None."""
    if text is not None:
        mi.Log(mi.LogLevel.Warn, text)


def _int(props, name, default, lo, hi):
    if not (name in props):
        return default
    value = props.get(name)
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not (lo <= value <= hi):
        raise MsxParameterError(
            "%s: parameter '%s' must be an integer in [%d, %d] (got %r)" % (PLUGIN, name, lo, hi, value)
        )
    return value


def _fraction(props, name, default):
    """A float in the open interval (0, 1)."""
    if not (name in props):
        return default
    value = props.get(name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0.0 < float(value) < 1.0):
        raise MsxParameterError(
            "%s: parameter '%s' must be a float in (0, 1), the fraction of the scattered energy model='auto' "
            "may omit (got %r)" % (PLUGIN, name, value)
        )
    return float(value)


def _check_alpha(mi, name, tex):
    """Rejects a constant roughness that is ≤ 0 or not finite."""
    if tex.is_spatially_varying():
        return
    value = float(tex.eval_1(mi.SurfaceInteraction3f()))
    if not (math.isfinite(value) and value > 0.0):
        raise MsxParameterError(
            "%s: parameter '%s' must be a finite roughness > 0 (got %r)" % (PLUGIN, name, value)
        )


class _Collect:
    """Factory of a TraversalCallback that records every parameter object."""

    @staticmethod
    def make(mi):
        class Collect(mi.TraversalCallback):
            def __init__(self):
                super().__init__()
                self.items = {}

            def put(self, name, value, flags):
                self.items[name] = value

        return Collect()


def conductor_ior(mi, material):
    """(eta, k) textures of one of Mitsuba's conductor presets.

    Loads a built-in ``roughconductor`` with that material and collects its
    textures through ``traverse``, so the values are exactly Mitsuba's (per
    wavelength in spectral variants, its RGB values in RGB variants).
    """
    try:
        ref = mi.load_dict({"type": "roughconductor", "material": material})
    except Exception as e:  # unknown preset: Mitsuba cannot find data/ior/<name>.eta.spd
        raise MsxParameterError(
            "%s: unknown conductor for parameter 'material': '%s' (use one of Mitsuba's names such as "
            "'Cu', 'Au', 'Ag', 'Al', 'Cr', 'W', 'Ni', or 'none' for a perfect mirror; Mitsuba said: %s)"
            % (PLUGIN, material, _mitsuba_reason(e))
        ) from None
    cb = _Collect.make(mi)
    ref.traverse(cb)
    return cb.items["eta"], cb.items["k"]


def dielectric_ior(mi, props):
    """Relative IOR int_ior/ext_ior with Mitsuba's own names and checks.

    A built-in ``roughdielectric`` interprets the values (floats or names such
    as 'bk7', 'water', 'air'); its traversed ``eta`` is the relative IOR.
    """
    args = {"type": "roughdielectric"}
    for name, default in (("int_ior", "bk7"), ("ext_ior", "air")):
        value = props.get(name, default) if name in props else default
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if not (math.isfinite(value) and value > 0.0):
                raise MsxParameterError(
                    "%s: parameter '%s' must be a finite index of refraction > 0 or one of Mitsuba's names "
                    "('bk7', 'water', 'air', 'diamond', ...) (got %r)" % (PLUGIN, name, value)
                )
        elif not isinstance(value, str):
            raise MsxParameterError("%s: parameter '%s' must be a float or a string (got %r)" % (PLUGIN, name, value))
        args[name] = value
    if _same_ior(args["int_ior"], args["ext_ior"]):
        raise MsxParameterError(
            "%s: parameters 'int_ior' and 'ext_ior' must differ (both are %r): a dielectric with the same index "
            "of refraction on both sides does not scatter" % (PLUGIN, args["int_ior"])
        )
    try:
        ref = mi.load_dict(args)
    except Exception as e:
        raise MsxParameterError(
            "%s: invalid 'int_ior'/'ext_ior' (%r, %r): Mitsuba says: %s; use two different positive IORs or "
            "Mitsuba's names such as 'bk7', 'water', 'air', 'diamond'"
            % (PLUGIN, args["int_ior"], args["ext_ior"], _mitsuba_reason(e))
        ) from None
    eta = float(mi.traverse(ref)["eta"])
    if not (math.isfinite(eta) and eta > 0.0):
        raise MsxParameterError("%s: 'int_ior'/'ext_ior' give a relative IOR %r; it must be > 0" % (PLUGIN, eta))
    return eta


def _mitsuba_reason(error):
    """The last line of a Mitsuba exception without its "[file.cpp:N]" / "[Plugin]" prefixes."""
    import re

    text = str(error).strip().splitlines()[-1] if str(error).strip() else repr(error)
    text = re.sub(r"^.*failed to instantiate [^:]*:\s*", "", text)
    return re.sub(r"^(\[[\w.:]+\]\s*)+", "", text)


def _same_ior(a, b):
    """True if two IOR values (floats or Mitsuba's names) are the same number."""
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return float(a) == float(b)


def _check_names(props):
    """A parameter name msx_posfree does not know: one line with the closest known name (Mitsuba itself says
    only "unreferenced property", after the load)."""
    import difflib

    known = sorted(set(COMMON_PARAMS.split(", ")) | {n for names in SURFACE_PARAMS.values() for n in names})
    keys = props.keys() if hasattr(props, "keys") else ()
    for name in keys:
        if name not in known:
            close = difflib.get_close_matches(name, known, n=1)
            raise MsxParameterError("%s: unknown parameter '%s'%s; the parameters are %s" % (
                PLUGIN, name, " (did you mean '%s'?)" % close[0] if close else "", ", ".join(known)))


class Config:
    """Parsed parameters of one msx_posfree instance."""

    def __init__(self, mi, props):
        _check_names(props)
        self.surface = _choice(props, "surface", "conductor", SURFACES)
        own = SURFACE_PARAMS[self.surface]
        for other, names in SURFACE_PARAMS.items():
            for name in names:
                if name in props and name not in own:
                    raise MsxParameterError(
                        "%s: parameter '%s' does not apply to surface='%s' (it belongs to surface='%s'); "
                        "parameters of surface='%s': %s, %s"
                        % (PLUGIN, name, self.surface, other, self.surface, COMMON_PARAMS, ", ".join(own))
                    )
        self.distribution = _choice(props, "distribution", "beckmann", DISTRIBUTIONS)

        if ("alpha" in props):
            for name in ("alpha_u", "alpha_v"):
                if (name in props):
                    raise MsxParameterError(
                        "%s: give either 'alpha' (isotropic) or 'alpha_u'/'alpha_v' (anisotropic), not both "
                        "(got 'alpha' and '%s')" % (PLUGIN, name)
                    )
            self.alpha_u = props.get_texture("alpha", 0.1)
            self.alpha_v = self.alpha_u
            _check_alpha(mi, "alpha", self.alpha_u)
            self.isotropic = True
        else:
            self.alpha_u = props.get_texture("alpha_u", 0.1)
            self.alpha_v = props.get_texture("alpha_v", 0.1)
            _check_alpha(mi, "alpha_u", self.alpha_u)
            _check_alpha(mi, "alpha_v", self.alpha_v)
            self.isotropic = False

        # Defaults of the other surfaces' values (unused by this surface).
        self.material = "none"
        self.eta = self.k = None
        self.ior = lib.MSX_DEFAULT_IOR
        self.specular_transmittance = None
        self.reflectance = None
        if self.surface == "conductor":
            self._conductor(mi, props)
        elif self.surface == "dielectric":
            self.ior = dielectric_ior(mi, props)
            self.specular_transmittance = props.get_texture("specular_transmittance", 1.0)
        else:
            self.reflectance = props.get_texture("reflectance", 0.5)
        # A tint of the specular facets: the diffuse microsurface has none (its albedo is `reflectance`).
        self.specular_reflectance = (props.get_texture("specular_reflectance", 1.0) if self.surface != "diffuse"
                                     else None)

        self.model = _choice(props, "model", "correlated", MODELS)
        self.estimator = _choice(props, "estimator", "pt", ESTIMATORS)
        self.max_bounces = _int(props, "max_bounces", 0, 1, MAX_BOUNCES_LIMIT)
        self.seed = _int(props, "seed", 0, 0, SEED_LIMIT - 1)
        if ("auto_tolerance" in props) and self.model != "auto":
            raise MsxParameterError(
                "%s: parameter 'auto_tolerance' applies to model='auto' only (model is '%s')" % (PLUGIN, self.model)
            )
        self.auto_tolerance = _fraction(props, "auto_tolerance", lib.MSX_DEFAULT_AUTO_TOLERANCE)
        self.sample_visible = _bool(props, "sample_visible", True)
        # The walks' sampling for gradients through directions (Dr.Jit engine; docs/gradients.md): nothing is
        # differentiated in the scalar variants, where it changes nothing.
        self.differentiate_directions = _bool(props, "differentiate_directions", False)
        self.mis_density = _choice(props, "mis_density", DEFAULT_MIS_DENSITY, MIS_DENSITIES)
        if ("mis_density" in props) and not self.mis_density_applies():
            raise MsxParameterError(
                "%s: parameter 'mis_density' applies to the conductor walks only (surface='conductor' with model %s; "
                "here surface='%s', model='%s')" % (PLUGIN, ", ".join(MIS_DENSITY_MODELS), self.surface, self.model)
            )

    def sample_visible_note(self):
        """None when ``sample_visible`` is honoured (true, the default, by every model; false by the closed forms
        ``single``, ``fastmsx`` and ``compensated`` on every route), else the one line that says it is not, and
        why: a walk draws visible normals by construction."""
        if self.sample_visible or self.model in SAMPLE_VISIBLE_MODELS:
            return None
        return ("%s: sample_visible=false is ignored by model='%s': a random walk draws visible normals by "
                "construction (honoured by %s); the option changes the noise of a built-in's samples, not the "
                "expected image" % (PLUGIN, self.model, ", ".join(SAMPLE_VISIBLE_MODELS)))

    def mis_density_applies(self):
        """Whether ``mis_density`` changes anything: a conductor walk reports it for MIS."""
        return self.surface == "conductor" and self.model in MIS_DENSITY_MODELS

    def _conductor(self, mi, props):
        material = props.get("material", "none") if ("material" in props) else "none"
        if not isinstance(material, str):
            raise MsxParameterError("%s: parameter 'material' must be a string (got %r)" % (PLUGIN, material))
        self.material = material
        if material == "none":
            self.eta = props.get_unbounded_texture("eta", 0.0)
            self.k = props.get_unbounded_texture("k", 1.0)
        else:
            for name in ("eta", "k"):
                if (name in props):
                    raise MsxParameterError(
                        "%s: parameter '%s' cannot be combined with material='%s': specify either "
                        "(eta, k) or 'material', not both" % (PLUGIN, name, material)
                    )
            self.eta, self.k = conductor_ior(mi, material)

    def native_params(self, channels):
        return {
            "surface": SURFACES[self.surface],
            "distribution": DISTRIBUTIONS[self.distribution],
            "model": MODELS[self.model],
            "estimator": ESTIMATORS[self.estimator],
            "max_bounces": self.max_bounces,
            "channels": channels,
            "seed": self.seed,
            "auto_tolerance": self.auto_tolerance if self.model == "auto" else 0.0,
            "mis_density": MIS_DENSITIES[self.mis_density] if self.mis_density_applies() else 0,
            # MSX_SAMPLE_ALL_NORMALS (1) for sample_visible=false; the core's walks ignore it (the note above).
            "sample_all_normals": 0 if self.sample_visible else 1,
        }

