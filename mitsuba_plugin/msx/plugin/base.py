"""The Python routes (scalar Python class, batched vectorized class, Dr.Jit engine): what they share.

The scalar variants call the core once per BSDF call (``scalar.py``); the
batched route of the vectorized variants makes one batched call per method over a wavefront
(``vectorized.py``); the Dr.Jit engine's class (``jit_bsdf.py``) builds on the same base class. Everything that does not depend on how a call reaches
the core lives here: the channel count, the native handle, the instance's
textures, the surface's lobes, flags and components, ``traverse``,
``parameters_changed`` and the factory that picks the class of the
configured surface.
"""

import drjit as dr

from .._native import ffi, lib
from .parameters import PLUGIN, Config, MsxParameterError, channels_of, warn

ERR_LEN = 512

SURFACE_KINDS = ("conductor", "dielectric", "diffuse")

# BSDFContext.component: every component (-1 as uint32).
ALL_COMPONENTS = 0xFFFFFFFF

# The spectral textures a surface may use, in the order traverse lists them; eta and k (a conductor's)
# are also discontinuous parameters, as in Mitsuba's roughconductor.
SPECTRAL_TEXTURES = ("eta", "k", "specular_reflectance", "specular_transmittance", "reflectance")
DISCONTINUOUS = ("eta", "k")


def native_channels(mi, variant):
    """Spectral channels per call in this variant, checked against the core's limit."""
    nch = channels_of(mi, variant)
    if nch > lib.MSX_MAX_CHANNELS:
        raise NotImplementedError("%s: %d channels exceed the core's limit" % (PLUGIN, nch))
    return nch


def new_handle(cfg, nch):
    """The core's BSDF for a parsed configuration (freed with its Python owner)."""
    params = ffi.new("MsxParams *", cfg.native_params(nch))
    out = ffi.new("MsxBsdf **")
    err = ffi.new("char[]", ERR_LEN)
    rc = lib.msx_bsdf_new(params, out, err, ERR_LEN)
    if rc != lib.MSX_OK:
        raise MsxParameterError("%s: %s" % (PLUGIN, ffi.string(err).decode(errors="replace")))
    return ffi.gc(out[0], lib.msx_bsdf_free)


def surface_lobes(BSDFFlags, kind):
    """(lobes, sides) of a surface kind: a dielectric reflects and transmits on both sides (non-symmetric
    under refraction), the conductor and the diffuse surface reflect on the front side."""
    if kind == "dielectric":
        return (BSDFFlags.GlossyReflection | BSDFFlags.GlossyTransmission,
                BSDFFlags.FrontSide | BSDFFlags.BackSide | BSDFFlags.NonSymmetric)
    if kind == "diffuse":
        return BSDFFlags.DiffuseReflection, BSDFFlags.FrontSide
    return BSDFFlags.GlossyReflection, BSDFFlags.FrontSide


def one_line(cfg, variant, route):
    """``to_string`` of the vectorized routes: the configuration on one line, with the variant and the route."""
    return ("MsxPosfree[surface=\"%s\", distribution=\"%s\", model=\"%s\", estimator=\"%s\", "
            "max_bounces=%s, seed=%d, variant=\"%s\" (%s)]"
            % (cfg.surface, cfg.distribution, cfg.model, cfg.estimator, cfg.max_bounces or "default", cfg.seed,
               variant, route))


def make_base_class(mi, kind, nch):
    """The part of the ``msx_posfree`` class for one surface kind that both routes share.

    A route subclasses it, adds its own per-instance state in ``__init__`` after calling this
    ``__init__``, then calls ``self._refresh()``; it overrides ``_refresh`` when it caches values
    derived from the textures (calling ``_set_flags`` there) and ``_config`` when it parses the
    properties differently.
    """
    BSDFFlags = mi.BSDFFlags
    LOBES, SIDES = surface_lobes(BSDFFlags, kind)
    LOBE_BITS = int(LOBES)
    R_BIT = int(BSDFFlags.GlossyReflection)
    T_BIT = int(BSDFFlags.GlossyTransmission)
    DIFF = mi.ParamFlags.Differentiable
    DISC = mi.ParamFlags.Discontinuous
    dielectric = kind == "dielectric"

    # The components that reflect and that transmit (BSDFContext.component; type_mask and component are
    # Python ints in every variant).
    REFLECTING = (0, ALL_COMPONENTS)
    TRANSMITTING = (1, ALL_COMPONENTS)

    if dielectric:
        def lobes(ctx):
            """(reflection enabled, transmission enabled) for this context: component 0 reflects, 1 transmits."""
            m, c = ctx.type_mask, ctx.component
            return bool(m & R_BIT) and c in REFLECTING, bool(m & T_BIT) and c in TRANSMITTING
    else:
        def lobes(ctx):
            """(reflection enabled, transmission enabled) for this context: the one component reflects."""
            m, c = ctx.type_mask, ctx.component
            return bool(m & LOBE_BITS) and c in REFLECTING, False

    class MsxPosfreeBase(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            cfg = self._config(props)
            self._cfg = cfg
            self._alpha_u = cfg.alpha_u
            # An isotropic surface has one roughness texture, used for both directions.
            self._alpha_v = cfg.alpha_u if cfg.isotropic else cfg.alpha_v
            self._eta = cfg.eta
            self._k = cfg.k
            self._specular_reflectance = cfg.specular_reflectance
            self._specular_transmittance = cfg.specular_transmittance
            self._reflectance = cfg.reflectance
            # (name, texture) of the spectral textures this surface uses (the other surfaces' are None).
            self._spectra = [(name, getattr(cfg, name)) for name in SPECTRAL_TEXTURES
                             if getattr(cfg, name) is not None]
            self._textures = [self._alpha_u, self._alpha_v] + [tex for _, tex in self._spectra]
            self._h = new_handle(cfg, nch)

        def _config(self, props):
            """The parsed and validated parameters (``parameters.py``)."""
            cfg = Config(mi, props)
            warn(mi, cfg.sample_visible_note())
            return cfg

        _lobes = staticmethod(lobes)

        # ------------------------------------------------------------ state

        def _refresh(self):
            """(Re)computes what depends on the current textures' values."""
            self._set_flags()

        def _alphas_differ(self):
            """Whether the constant roughnesses alpha_u and alpha_v differ."""
            si = mi.SurfaceInteraction3f()
            return bool(dr.any(self._alpha_u.eval_1(si) != self._alpha_v.eval_1(si)))

        def _set_flags(self):
            """Mitsuba's flags and components for the current textures: anisotropic when the roughnesses
            may differ (one varies over the surface, or their constant values differ), spatially varying
            when any texture varies over the surface."""
            flags = LOBES | SIDES
            if not self._cfg.isotropic and (self._alpha_u.is_spatially_varying()
                                            or self._alpha_v.is_spatially_varying() or self._alphas_differ()):
                flags = flags | BSDFFlags.Anisotropic
            if any(t.is_spatially_varying() for t in self._textures):
                flags = flags | BSDFFlags.SpatiallyVarying
            self.m_flags = flags
            if dielectric:
                extra = flags & ~LOBES
                self.m_components = [BSDFFlags.GlossyReflection | extra, BSDFFlags.GlossyTransmission | extra]
            else:
                self.m_components = [flags]

        # ------------------------------------------------------ parameters

        def traverse(self, cb):
            if self._cfg.isotropic:
                cb.put("alpha", self._alpha_u, DIFF | DISC)
            else:
                cb.put("alpha_u", self._alpha_u, DIFF | DISC)
                cb.put("alpha_v", self._alpha_v, DIFF | DISC)
            for name, tex in self._spectra:
                cb.put(name, tex, (DIFF | DISC) if name in DISCONTINUOUS else DIFF)

        def parameters_changed(self, keys=[]):
            self._refresh()

    MsxPosfreeBase.__name__ = MsxPosfreeBase.__qualname__ = "MsxPosfreeBase"
    return MsxPosfreeBase


class MsxPosfreeFactory:
    """Creates the msx_posfree instance of the surface named in the properties."""

    def __init__(self, classes_by_surface):
        self.classes_by_surface = classes_by_surface

    def __call__(self, props):
        classes = self.classes_by_surface
        surface = props.get("surface", "conductor") if "surface" in props else "conductor"
        return classes.get(surface, classes["conductor"])(props)


def make_factory(build):
    """The factory over ``build(kind)``, the route's class of each surface kind."""
    return MsxPosfreeFactory({kind: build(kind) for kind in SURFACE_KINDS})
