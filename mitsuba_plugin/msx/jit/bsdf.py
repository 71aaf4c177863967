"""The ``msx_posfree`` class of the Dr.Jit engine, for every vectorized variant (``llvm_*``, ``cuda_*``).

Twin of ``src/bsdf.rs``: it maps the configuration to one model implementation at construction, checks
each call's inputs (a usable material), applies Mitsuba's ``specular_reflectance`` afterwards, and derives
each lane's random stream from the lane's inputs and ``seed``. Parameters, flags, ``traverse`` and the
surface factory are those of the other routes (``_plugin_base.py``); the parameters are validated by the
same code and the core, so a bad parameter gives the same one-line message as in ``scalar_rgb``.

The methods are traced: Mitsuba calls them once per kernel with symbolic arrays, and the models' walks
become loops inside the integrator's kernel. Nothing here changes drjit's flags.
"""

import drjit as dr
import mitsuba as mi

from .._params import PLUGIN, MsxParameterError
from .._plugin_base import make_base_class, make_factory, native_channels
from .._vectorized_config import vectorized_config
from . import heitz, mis, posfree, single
from .microfacet import ConductorFresnel, Microfacet
from .rng import hash_words

# The conductor random walks of the engine, by model name: each model module provides its own.
CONDUCTOR_WALKS = {**posfree.CONDUCTOR_WALKS, **heitz.CONDUCTOR_WALKS}

# The models the engine runs, per surface (the others are refused with a message naming the batched route).
ENGINE_MODELS = {
    "conductor": ("single",) + tuple(CONDUCTOR_WALKS),
    "dielectric": (),
    "diffuse": (),
}

# Largest material value the core accepts (src/bsdf.rs, MATERIAL_VALUE_MAX).
MATERIAL_VALUE_MAX = 1e4
# Bounce cap when the scene sets none (the core's MSX_DEFAULT_MAX_BOUNCES).
DEFAULT_MAX_BOUNCES = 64


def engine_support(cfg):
    """None when the engine runs this configuration, else the message that says what to do instead."""
    models = ENGINE_MODELS.get(cfg.surface, ())
    if cfg.model in models and cfg.estimator == "pt":
        return None
    what = "model='%s'" % cfg.model if cfg.estimator == "pt" else "model='%s' with estimator='%s'" % (
        cfg.model, cfg.estimator)
    runs = ", ".join(models) if models else "none yet"
    return ("%s: %s on surface '%s' does not run in the Dr.Jit engine of the vectorized variants yet (there, "
            "surface '%s' runs: %s, with estimator 'pt'); render it in a scalar variant (scalar_rgb: the native "
            "back end), or register the batched route, msx.register(backend='batched'), which turns drjit's "
            "symbolic loops off for the process" % (PLUGIN, what, cfg.surface, cfg.surface, runs))


class ConductorModel:
    """The conductor models of the engine: ``single`` (Walter 2007 as Mitsuba) and the position-free PT
    walks (``uncorrelated``, ``correlated``) with their MIS density."""

    def __init__(self, cfg):
        self.walk = CONDUCTOR_WALKS.get(cfg.model)  # None: single scattering
        self.max_bounces = cfg.max_bounces or DEFAULT_MAX_BOUNCES

    def eval_pdf(self, mf, fresnel, wi, wo, key, want_value=True, want_pdf=True):
        walk = self.walk
        if walk is None:
            return single.eval_pdf(mf, fresnel, wi, wo)
        value = walk.eval_pt(mf, fresnel, wi, wo, self.max_bounces, key) if want_value else None
        pdf = mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo) if want_pdf else None
        return value, pdf

    def sample(self, mf, fresnel, wi, s1, u1, u2, key):
        """(ω_o, pdf, weight, valid)."""
        walk = self.walk
        if walk is None:
            return single.sample(mf, fresnel, wi, u1, u2)
        wo, weight, valid = walk.sample_walk(mf, fresnel, wi, s1, u1, u2, self.max_bounces, key)
        pdf = mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo)
        return wo, pdf, weight, valid & (pdf > 0.0)


def make_bsdf_factory(variant):
    """The factory of ``msx_posfree`` instances for the current vectorized variant."""
    nch = native_channels(mi, variant)
    BSDFFlags = mi.BSDFFlags
    R_TYPE = int(BSDFFlags.GlossyReflection)

    def build(kind):
        class MsxPosfree(make_base_class(mi, kind, nch)):
            """Multiple-scattering microfacet BSDF (the Dr.Jit engine)."""

            def __init__(self, props):
                super().__init__(props)
                problem = engine_support(self._cfg)
                if problem is not None:
                    raise MsxParameterError(problem)
                self._model = ConductorModel(self._cfg)
                self._refresh()

            def _config(self, props):
                return vectorized_config(mi, props)

            def _refresh(self):
                self._set_flags()
                # The perfect mirror (Mitsuba's material='none' with its default η = 0, k = 1) has F = 1.
                self._mirror = False
                if not (self._eta.is_spatially_varying() or self._k.is_spatially_varying()):
                    si = dr.zeros(mi.SurfaceInteraction3f)
                    eta, k = self._eta.eval(si), self._k.eval(si)
                    self._mirror = bool(dr.all(dr.ravel(eta) == 0.0)) and bool(dr.all(dr.ravel(k) == 1.0))

            # ----------------------------------------------------- the call

            def _material(self, si, active):
                """(microfacet, Fresnel, tint, usable) at the hit, cleaned as ``Material::usable``."""
                au = self._alpha_u.eval_1(si, active)
                av = au if self._cfg.isotropic else self._alpha_v.eval_1(si, active)
                usable = dr.isfinite(au) & dr.isfinite(av)
                tint = self._specular_reflectance.eval(si, active)
                usable &= dr.all(dr.isfinite(tint))
                tint = dr.clip(tint, 0.0, MATERIAL_VALUE_MAX)
                if self._mirror:
                    fresnel = ConductorFresnel(None, None, mirror=True)
                else:
                    eta, k = self._eta.eval(si, active), self._k.eval(si, active)
                    usable &= dr.all(dr.isfinite(eta)) & dr.all(dr.isfinite(k))
                    fresnel = ConductorFresnel(dr.clip(eta, 0.0, MATERIAL_VALUE_MAX),
                                               dr.clip(k, 0.0, MATERIAL_VALUE_MAX))
                mf = Microfacet(self._cfg.distribution, au, av)
                return mf, fresnel, tint, usable

            def _eval_key(self, si, wo):
                p, uv, wi = si.p, si.uv, si.wi
                return hash_words(self._cfg.seed, (p[0], p[1], p[2], uv[0], uv[1],
                                                   wi[0], wi[1], wi[2], wo[0], wo[1], wo[2]))

            def _evaluate(self, ctx, si, wo, active, want_value, want_pdf):
                on, _ = self._lobes(ctx)
                if not on:
                    return dr.zeros(mi.Spectrum), dr.zeros(mi.Float)
                mf, fresnel, tint, usable = self._material(si, active)
                active = active & usable & dr.all(dr.isfinite(si.wi)) & dr.all(dr.isfinite(wo))
                value, pdf = self._model.eval_pdf(mf, fresnel, si.wi, wo, self._eval_key(si, wo),
                                                  want_value, want_pdf)
                if want_value:
                    value = value * tint
                    value = dr.select(active & dr.all(dr.isfinite(value)), value, 0.0)
                if want_pdf:
                    pdf = dr.select(active & dr.isfinite(pdf), pdf, 0.0)
                return value, pdf

            def eval(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, True, False)[0]

            def pdf(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, False, True)[1]

            def eval_pdf(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, True, True)

            def sample(self, ctx, si, sample1, sample2, active=True):
                on, _ = self._lobes(ctx)
                if not on:
                    return dr.zeros(mi.BSDFSample3f), dr.zeros(mi.Spectrum)
                mf, fresnel, tint, usable = self._material(si, active)
                wi = si.wi
                key = hash_words(self._cfg.seed, (sample1, sample2[0], sample2[1], wi[0], wi[2]))
                wo, pdf, weight, valid = self._model.sample(mf, fresnel, wi, sample1, sample2[0], sample2[1], key)
                weight = weight * tint
                ok = active & usable & valid & dr.all(dr.isfinite(wi)) & dr.isfinite(pdf) & (pdf > 0.0)
                ok &= dr.all(dr.isfinite(weight))
                bs = dr.zeros(mi.BSDFSample3f)
                bs.wo = dr.select(ok, wo, mi.Vector3f(0.0))
                bs.pdf = dr.select(ok, pdf, 0.0)
                bs.eta = mi.Float(1.0)
                bs.sampled_type = mi.UInt32(R_TYPE)
                bs.sampled_component = mi.UInt32(0)
                return bs, dr.select(ok, weight, 0.0)

            def to_string(self):
                cfg = self._cfg
                return ("MsxPosfree[surface=\"%s\", distribution=\"%s\", model=\"%s\", estimator=\"%s\", "
                        "max_bounces=%s, seed=%d, variant=\"%s\" (Dr.Jit engine)]"
                        % (cfg.surface, cfg.distribution, cfg.model, cfg.estimator,
                           cfg.max_bounces or "default", cfg.seed, variant))

        MsxPosfree.__name__ = MsxPosfree.__qualname__ = "MsxPosfree"
        return MsxPosfree

    return make_factory(build)
