"""The ``msx_posfree`` class of the Dr.Jit engine, for every vectorized variant (``llvm_*``, ``cuda_*``).

Twin of the class part of ``src/bsdf.rs``: it maps the configuration to one model implementation at
construction (``jit/bsdf.py``: the table of what runs, the refusals, the per-surface adapters), checks each
call's inputs (a usable material), applies Mitsuba's ``specular_reflectance`` afterwards, and derives each
lane's random stream from the lane's inputs and ``seed``. Parameters, flags, ``traverse`` and the surface
factory are those of the other routes (``base.py``); the parameters are validated by the same code and the
core, so a bad parameter gives the same one-line message as in ``scalar_rgb``.

The methods are traced: Mitsuba calls them once per kernel with symbolic arrays, and the models' walks
become loops inside the integrator's kernel. Nothing here changes drjit's flags.
"""

import math

import drjit as dr
import mitsuba as mi

from ..jit import analytic
from ..jit.bsdf import (FLT_MIN, INDEX_MATCHED, MATERIAL_VALUE_MAX, MODELS_BY_SURFACE, WO_KEY_GRID, Call,
                        differentiable_walk, differentiate_directions_problem, direction_gradient_problem,
                        engine_support, eta_gradient_problem, flush_subnormal, gradient_problem, moving_directions)
from ..jit.microfacet import ConductorFresnel, Microfacet
from ..jit.rng import hash_words
from .base import make_base_class, make_factory, native_channels, one_line
from .parameters import MsxParameterError, warn
from .vectorized_config import vectorized_config


def make_bsdf_factory(variant):
    """The factory of ``msx_posfree`` instances for the current vectorized variant."""
    nch = native_channels(mi, variant)
    BSDFFlags = mi.BSDFFlags

    def build(kind):
        dielectric = kind == "dielectric"
        if dielectric:
            R_TYPE, T_TYPE = int(BSDFFlags.GlossyReflection), int(BSDFFlags.GlossyTransmission)
        elif kind == "diffuse":
            R_TYPE = T_TYPE = int(BSDFFlags.DiffuseReflection)
        else:
            R_TYPE = T_TYPE = int(BSDFFlags.GlossyReflection)

        class MsxPosfree(make_base_class(mi, kind, nch)):
            """Multiple-scattering microfacet BSDF (the Dr.Jit engine)."""

            def __init__(self, props):
                super().__init__(props)
                problem = engine_support(self._cfg) or differentiate_directions_problem(self._cfg)
                if problem is not None:
                    raise MsxParameterError(problem)
                if dielectric:
                    # The relative IOR as a parameter, as roughdielectric's ``eta`` (traverse below).
                    self._ior = mi.Float(self._cfg.ior)
                self._model = MODELS_BY_SURFACE[kind](self._cfg)
                self._gradient_problem = gradient_problem(self._cfg)
                self._eta_problem = eta_gradient_problem(self._cfg) if dielectric else None
                self._direction_problem = direction_gradient_problem(self._cfg)
                self._differentiable_walk = differentiable_walk(self._cfg)
                self._refresh()

            def _config(self, props):
                cfg = vectorized_config(mi, props)
                warn(mi, cfg.sample_visible_note())
                return cfg

            def traverse(self, cb):
                super().traverse(cb)
                if dielectric:
                    cb.put("eta", self._ior, mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous)

            def _refresh(self):
                self._set_flags()
                if dielectric:
                    self._refresh_ior()
                # A differentiable walk samples its proposal while any parameter carries gradients (set
                # here, by the parameter update, so that prb's primal and adjoint passes sample alike).
                # ``differentiate_directions``: always, since the directions' gradients (a normal map's, a
                # shape's) come from outside this BSDF's parameters.
                self._traced = self._differentiable_walk is not None and (any(
                    dr.grad_enabled(params[k]) for params in map(mi.traverse, self._textures) for k in params.keys())
                    or (dielectric and dr.grad_enabled(self._ior)) or self._cfg.differentiate_directions)
                # The perfect mirror (Mitsuba's material='none' with its default η = 0, k = 1) has F = 1; a
                # constant material's average Fresnel term (compensation) is computed once, here.
                self._mirror, self._fresnel_average = False, None
                if kind == "conductor" and not (self._eta.is_spatially_varying() or self._k.is_spatially_varying()):
                    si = dr.zeros(mi.SurfaceInteraction3f)
                    eta, k = self._eta.eval(si), self._k.eval(si)
                    self._mirror = bool(dr.all(dr.ravel(eta) == 0.0)) and bool(dr.all(dr.ravel(k) == 1.0))
                    # Not when η or k is differentiated: an average computed here would tie the kernel to a
                    # derivative taken outside the render (Mitsuba's render isolates its own); the call then
                    # computes it, differentiably.
                    traced = dr.grad_enabled(eta) or dr.grad_enabled(k)
                    # Nor in spectral variants: there η and k depend on the wavelengths each lane samples
                    # (a zero interaction evaluates them at λ = 0), so the average is a per-lane value.
                    if self._cfg.model == "compensated" and not self._mirror and not traced and not mi.is_spectral:
                        clip = (lambda v: dr.clip(v, 0.0, MATERIAL_VALUE_MAX))
                        self._fresnel_average = analytic.fresnel_average(ConductorFresnel(clip(eta), clip(k)))
                        dr.eval(self._fresnel_average)

            def _refresh_ior(self):
                """A new ``eta``: ``auto``'s rules depend on it (one per side), so the model is rebuilt. A value
                the calls refuse (not finite, index-matched) keeps the old model: every call is unusable then."""
                ior = float(dr.ravel(dr.detach(self._ior))[0]) if dr.width(self._ior) > 0 else float("nan")
                if ior == self._cfg.ior or not (math.isfinite(ior) and abs(ior - 1.0) > INDEX_MATCHED):
                    return
                self._cfg.ior = min(max(ior, 1.0 / MATERIAL_VALUE_MAX), MATERIAL_VALUE_MAX)
                self._model = MODELS_BY_SURFACE[kind](self._cfg)

            # ----------------------------------------------------- the call

            def _spectrum(self, tex, si, active):
                """A spectral texture at the hit, clamped into [0, MATERIAL_VALUE_MAX], and whether it is finite."""
                v = tex.eval(si, active)
                return dr.clip(v, 0.0, MATERIAL_VALUE_MAX), dr.all(dr.isfinite(v))

            def _call(self, ctx, si, active):
                """The call at the hit, its values cleaned as ``Material::usable`` does."""
                au = self._alpha_u.eval_1(si, active)
                av = au if self._cfg.isotropic else self._alpha_v.eval_1(si, active)
                usable = dr.isfinite(au) & dr.isfinite(av)
                call = Call(Microfacet(self._cfg.distribution, au, av), usable)
                if not self._cfg.sample_visible:
                    call.mf.sample_all_normals = True  # read by the closed forms' sampling (jit/single.py)
                call.alphas, call.traced = ((au,) if self._cfg.isotropic else (au, av)), self._traced
                if kind == "conductor":
                    call.tint_r, ok = self._spectrum(self._specular_reflectance, si, active)
                    usable &= ok
                    if self._mirror:
                        call.fresnel = ConductorFresnel(None, None, mirror=True)
                    else:
                        (eta, ok_e), (k, ok_k) = self._spectrum(self._eta, si, active), self._spectrum(self._k, si, active)
                        usable &= ok_e & ok_k
                        call.fresnel = ConductorFresnel(eta, k, average=self._fresnel_average)
                elif dielectric:
                    call.tint_r, ok_r = self._spectrum(self._specular_reflectance, si, active)
                    call.tint_t, ok_t = self._spectrum(self._specular_transmittance, si, active)
                    ior = self._ior
                    usable &= ok_r & ok_t & dr.isfinite(ior) & (dr.abs(ior - 1.0) > INDEX_MATCHED)
                    call.eta = dr.clip(ior, 1.0 / MATERIAL_VALUE_MAX, MATERIAL_VALUE_MAX)
                    call.radiance = ctx.mode == mi.TransportMode.Radiance
                else:
                    call.albedo, ok = self._spectrum(self._reflectance, si, active)
                    usable &= ok
                call.usable = usable
                if self._gradient_problem is not None:
                    values = (au, av, call.fresnel and call.fresnel.eta, call.fresnel and call.fresnel.k, call.tint_r,
                              call.tint_t, call.albedo, call.eta)
                    if any(v is not None and dr.grad_enabled(v) for v in values):
                        raise MsxParameterError(self._gradient_problem)
                if self._eta_problem is not None and dr.grad_enabled(call.eta):
                    raise MsxParameterError(self._eta_problem)
                return call

            def _eval_key(self, si, wo):
                p, uv, wi = si.p, si.uv, si.wi
                if self._traced:
                    # prb re-evaluates a sampled ω_o after a round trip through world space, a few ulps off:
                    # the key must not see that, or eval's estimate is not the one the sample weighed.
                    wo = dr.round(wo * WO_KEY_GRID) / WO_KEY_GRID
                return hash_words(self._cfg.seed, (p[0], p[1], p[2], uv[0], uv[1],
                                                   wi[0], wi[1], wi[2], wo[0], wo[1], wo[2]))

            def _lane_mask(self, ctx, si, wo, active):
                """The lanes whose lobe the context enables, or None when it enables none."""
                r_on, t_on = self._lobes(ctx)
                if not (r_on or t_on):
                    return None
                if not dielectric or (r_on and t_on):
                    return mi.Bool(active)
                reflect = si.wi[2] * wo[2] > 0.0
                return active & (reflect if r_on else ~reflect)

            def _evaluate(self, ctx, si, wo, active, want_value, want_pdf):
                mask = self._lane_mask(ctx, si, wo, active)
                if mask is None:
                    return dr.zeros(mi.Spectrum), dr.zeros(mi.Float)
                if moving_directions(self._direction_problem, si.wi, wo):
                    raise MsxParameterError(self._direction_problem)
                call = self._call(ctx, si, mask)
                mask &= call.usable & dr.all(dr.isfinite(si.wi)) & dr.all(dr.isfinite(wo))
                value, pdf = self._model.eval_pdf(call, si.wi, wo, self._eval_key(si, wo), want_value, want_pdf)
                if want_value:
                    value = dr.select(mask & dr.all(dr.isfinite(value)), flush_subnormal(value), 0.0)
                if want_pdf:
                    pdf = dr.select(mask & dr.isfinite(pdf), pdf, 0.0)
                return value, pdf

            def eval(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, True, False)[0]

            def pdf(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, False, True)[1]

            def eval_pdf(self, ctx, si, wo, active=True):
                return self._evaluate(ctx, si, wo, active, True, True)

            def sample(self, ctx, si, sample1, sample2, active=True):
                r_on, t_on = self._lobes(ctx)
                if not (r_on or t_on):
                    return dr.zeros(mi.BSDFSample3f), dr.zeros(mi.Spectrum)
                if moving_directions(self._direction_problem, si.wi):
                    raise MsxParameterError(self._direction_problem)
                call = self._call(ctx, si, active)
                wi = si.wi
                key = hash_words(self._cfg.seed, (sample1, sample2[0], sample2[1], wi[0], wi[2]))
                if call.traced:
                    wo, pdf, weight, valid = self._model.sample_traced(call, wi, sample1, sample2[0], sample2[1],
                                                                       lambda wo: self._eval_key(si, wo))
                else:
                    wo, pdf, weight, valid = self._model.sample(call, wi, sample1, sample2[0], sample2[1], key)
                ok = active & call.usable & valid & dr.all(dr.isfinite(wi)) & dr.isfinite(pdf) & (pdf > 0.0)
                ok &= dr.all(dr.isfinite(weight))
                weight = dr.select(dr.abs(weight * pdf) >= FLT_MIN, weight, 0.0)  # as eval's flush_subnormal
                bs = dr.zeros(mi.BSDFSample3f)
                transmit = wo[2] * wi[2] < 0.0
                if dielectric:
                    ok &= dr.select(transmit, t_on, r_on)
                    eta_t = dr.select(wi[2] > 0.0, call.eta, 1.0 / call.eta)
                    bs.eta = dr.select(ok & transmit, eta_t, 1.0)
                    bs.sampled_type = dr.select(ok & transmit, mi.UInt32(T_TYPE), mi.UInt32(R_TYPE))
                    bs.sampled_component = dr.select(ok & transmit, mi.UInt32(1), mi.UInt32(0))
                else:
                    bs.eta = mi.Float(1.0)
                    bs.sampled_type = mi.UInt32(R_TYPE)
                    bs.sampled_component = mi.UInt32(0)
                bs.wo = dr.select(ok, wo, mi.Vector3f(0.0))
                bs.pdf = dr.select(ok, pdf, 0.0)
                return bs, dr.select(ok, weight, 0.0)

            def to_string(self):
                return one_line(self._cfg, variant, "Dr.Jit engine")

        MsxPosfree.__name__ = MsxPosfree.__qualname__ = "MsxPosfree"
        return MsxPosfree

    return make_factory(build)
