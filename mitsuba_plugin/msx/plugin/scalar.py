"""Scalar variants, Python route (``msx.register(backend="python")``, and the fallback when the native
plugin is unavailable): the ``msx_posfree`` BSDF class as a Python ``mi.BSDF``, one Python call per BSDF
call, one render thread. The default route of the scalar variants is the native plugin (``native.py``).

Every BSDF call crosses into the Rust core exactly once through the cffi
API-mode extension ``msx._native`` (small C helpers there take the
directions as plain floats and return the ABI's result structs by value).
Per-hit material values are packed into an ``MsxMaterial``; when no texture
varies (over the surface, or with wavelength in spectral variants) that
struct is computed once and reused. Parameters, flags, ``traverse`` and the
factory are shared with the batched route (``base.py``).
"""

from .._native import ffi, lib
from .parameters import PLUGIN
from .base import ALL_COMPONENTS, make_base_class, make_factory, native_channels, surface_lobes


def _channels(mi, variant):
    if not variant.startswith("scalar_"):
        raise NotImplementedError(
            "%s: variant '%s' is not supported yet; use a scalar variant (scalar_rgb, scalar_spectral, "
            "scalar_mono) or an LLVM variant (llvm_ad_rgb, llvm_ad_spectral)" % (PLUGIN, variant)
        )
    return native_channels(mi, variant)


def make_bsdf_class(mi, variant):
    """Defines the BSDF class for the current variant (``variant``)."""
    nch = _channels(mi, variant)

    BSDFFlags = mi.BSDFFlags
    GLOSSY_REFLECTION = BSDFFlags.GlossyReflection
    # BSDFContext.component: -1 (all components, as uint32) or our only one, 0.
    COMPONENTS = frozenset((0, ALL_COMPONENTS))
    Spectrum = mi.Spectrum
    Vector3f = mi.Vector3f
    BSDFSample3f = mi.BSDFSample3f
    SurfaceInteraction3f = mi.SurfaceInteraction3f
    ZERO = Spectrum(0.0)
    # Copying a prepared sample record is cheaper than setting eta,
    # sampled_type and sampled_component on a fresh one per call (as in
    # Mitsuba's roughconductor these are set whether or not the sample is valid).
    SAMPLE_TEMPLATE = BSDFSample3f()
    SAMPLE_TEMPLATE.eta = 1.0
    SAMPLE_TEMPLATE.sampled_type = int(GLOSSY_REFLECTION)
    SAMPLE_TEMPLATE.sampled_component = 0
    spectral = bool(mi.is_spectral)
    IMPORTANCE = mi.TransportMode.Importance
    T_TYPE = int(BSDFFlags.GlossyTransmission)
    D_TYPE = int(BSDFFlags.DiffuseReflection)

    # The C helpers take the material evaluated at the hit, or NULL for the cached one.
    c_eval, c_eval_pdf, c_pdf, c_sample = lib.msxpy_eval, lib.msxpy_eval_pdf, lib.msxpy_pdf, lib.msxpy_sample
    NULL = ffi.NULL
    new = ffi.new

    # Result structs are flat (v0..v3 / w0..w3): one attribute access each.
    if nch == 3:
        def value_of(r):
            return Spectrum(r.v0, r.v1, r.v2)

        def weight_of(r):
            return Spectrum(r.w0, r.w1, r.w2)
    elif nch == 4:
        def value_of(r):
            return Spectrum(r.v0, r.v1, r.v2, r.v3)

        def weight_of(r):
            return Spectrum(r.w0, r.w1, r.w2, r.w3)
    else:
        def value_of(r):
            return Spectrum(r.v0)

        def weight_of(r):
            return Spectrum(r.w0)

    def is_constant(tex):
        """True if the texture's value depends neither on the position nor,
        in spectral variants, on the wavelengths."""
        if tex.is_spatially_varying():
            return False
        return (not spectral) or tex.class_name() == "UniformSpectrum"

    def channel_values(value):
        if nch == 1:
            return [float(value[0]) if hasattr(value, "__getitem__") else float(value)]
        return [float(value[i]) for i in range(nch)]

    def build(kind):
        """The class for one surface kind, with its flags as closure constants."""
        LOBE_BITS = int(surface_lobes(BSDFFlags, kind)[0])

        class MsxPosfree(make_base_class(mi, kind, nch)):
            """Multiple-scattering microfacet conductor (README.md's parameter table)."""

            def __init__(self, props):
                super().__init__(props)
                # Handle + cached material. The key of msx_eval* comes from the hit (p, uv).
                self._inst = new("MsxpyInst *")
                self._inst.bsdf = self._h
                self._refresh()

            # ------------------------------------------------------------ state

            def _refresh(self):
                """(Re)computes cached constants from the current textures."""
                texs = self._textures
                self._const = all(is_constant(t) for t in texs)
                self._alpha_const = all(not t.is_spatially_varying() for t in texs[:2])

                mat = new("MsxMaterial *")
                si = SurfaceInteraction3f()
                if not spectral or self._const:
                    self._fill(mat, si)
                elif self._alpha_const:
                    mat.alpha_u = self._alpha_u.eval_1(si)
                    mat.alpha_v = self._alpha_v.eval_1(si)
                self._mat = mat
                # Textures that vary in RGB are spatially varying: evaluated per call.
                self._inst.mat = mat[0]
                self._set_flags()

            def _fill_spectra(self, mat, si):
                mat.ior = self._cfg.ior
                for field, tex in self._spectra:
                    vals = channel_values(tex.eval(si))
                    arr = getattr(mat, field)
                    for c in range(nch):
                        arr[c] = vals[c]

            def _fill(self, mat, si):
                mat.alpha_u = self._alpha_u.eval_1(si)
                mat.alpha_v = self._alpha_v.eval_1(si)
                if self._eta is None:
                    # Unused conductor fields keep a perfect mirror (η = 0, k = 1).
                    for c in range(nch):
                        mat.k[c] = 1.0
                self._fill_spectra(mat, si)

            def _material(self, si):
                """Material values at the hit (textures evaluated there)."""
                if self._const:
                    return self._mat
                mat = new("MsxMaterial *")
                if self._alpha_const:
                    mat.alpha_u = self._mat.alpha_u
                    mat.alpha_v = self._mat.alpha_v
                    if self._eta is None:
                        for c in range(nch):
                            mat.k[c] = 1.0
                    self._fill_spectra(mat, si)
                else:
                    self._fill(mat, si)
                return mat

            # ------------------------------------------------------------ calls
            # Hot paths: kept short on purpose (each Python operation costs
            # ~0.02-0.1 µs and the path integrator calls these per bounce;
            # indexing w[0] is measurably cheaper than tuple-unpacking a Vector3f).

            def eval(self, ctx, si, wo, active=True):
                if not (active and ctx.type_mask & LOBE_BITS) or ctx.component not in COMPONENTS:
                    return ZERO
                w, p, uv = si.wi, si.p, si.uv
                m = NULL if self._const else self._material(si)
                return value_of(c_eval(self._inst, m, w[0], w[1], w[2], wo[0], wo[1], wo[2], p[0], p[1], p[2],
                                       uv[0], uv[1]))

            def pdf(self, ctx, si, wo, active=True):
                if not (active and ctx.type_mask & LOBE_BITS) or ctx.component not in COMPONENTS:
                    return 0.0
                w = si.wi
                m = NULL if self._const else self._material(si)
                return c_pdf(self._inst, m, w[0], w[1], w[2], wo[0], wo[1], wo[2])

            def eval_pdf(self, ctx, si, wo, active=True):
                if not (active and ctx.type_mask & LOBE_BITS) or ctx.component not in COMPONENTS:
                    return ZERO, 0.0
                w, p, uv = si.wi, si.p, si.uv
                m = NULL if self._const else self._material(si)
                r = c_eval_pdf(self._inst, m, w[0], w[1], w[2], wo[0], wo[1], wo[2], p[0], p[1], p[2], uv[0], uv[1])
                return value_of(r), r.pdf

            def sample(self, ctx, si, sample1, sample2, active=True):
                if not (active and ctx.type_mask & LOBE_BITS) or ctx.component not in COMPONENTS:
                    return BSDFSample3f(), ZERO
                w = si.wi
                m = NULL if self._const else self._material(si)
                r = c_sample(self._inst, m, w[0], w[1], w[2], sample1, sample2[0], sample2[1])
                bs = BSDFSample3f(SAMPLE_TEMPLATE)
                if not r.valid:
                    return bs, ZERO  # pdf 0, zero weight
                bs.wo = Vector3f(r.x, r.y, r.z)
                bs.pdf = r.pdf
                return bs, weight_of(r)

            # ------------------------------------------------------ parameters

            def to_string(self):
                cfg = self._cfg
                if cfg.isotropic:
                    alpha = "  alpha = %s,\n" % _indent(self._alpha_u)
                else:
                    alpha = "  alpha_u = %s,\n  alpha_v = %s,\n" % (_indent(self._alpha_u), _indent(self._alpha_v))
                return (
                    "MsxPosfree[\n"
                    "  surface = \"%s\",\n  distribution = \"%s\",\n%s"
                    "  material = \"%s\",\n  eta = %s,\n  k = %s,\n  specular_reflectance = %s,\n"
                    "  model = \"%s\",%s%s\n  estimator = \"%s\",\n  max_bounces = %s,\n  seed = %d\n]"
                    % (
                        cfg.surface, cfg.distribution, alpha, cfg.material,
                        _indent(self._eta), _indent(self._k), _indent(self._specular_reflectance),
                        cfg.model, "\n  auto_tolerance = %g," % cfg.auto_tolerance if cfg.model == "auto" else "",
                        "\n  mis_density = \"%s\"," % cfg.mis_density if cfg.mis_density_applies() else "",
                        cfg.estimator,
                        cfg.max_bounces if cfg.max_bounces else "%d (library default)" % lib.MSX_DEFAULT_MAX_BOUNCES,
                        cfg.seed,
                    )
                )

        MsxPosfree.__name__ = MsxPosfree.__qualname__ = "MsxPosfree"
        return MsxPosfree if kind == "conductor" else _with_surface_calls(MsxPosfree, kind)

    def _with_surface_calls(base, kind):
        """Adds what differs for dielectric and diffuse surfaces: transport
        mode, per-side lobes and components, and the sample record's type/eta."""
        if kind == "diffuse":
            class Diffuse(base):
                def sample(self, ctx, si, sample1, sample2, active=True):
                    bs, w = base.sample(self, ctx, si, sample1, sample2, active)
                    bs.sampled_type = D_TYPE
                    return bs, w

            Diffuse.__name__ = Diffuse.__qualname__ = "MsxPosfree"
            return Diffuse

        class Dielectric(base):
            def _mat_for(self, ctx, si):
                """Material for this call, with the transport mode set."""
                imp = ctx.mode == IMPORTANCE
                if self._const and not imp:
                    return self._mat
                mat = new("MsxMaterial *")
                mat[0] = self._material(si)[0]
                mat.mode = lib.MSX_MODE_IMPORTANCE if imp else lib.MSX_MODE_RADIANCE
                return mat

            def eval(self, ctx, si, wo, active=True):
                return self.eval_pdf(ctx, si, wo, active)[0]

            def pdf(self, ctx, si, wo, active=True):
                return self.eval_pdf(ctx, si, wo, active)[1]

            def eval_pdf(self, ctx, si, wo, active=True):
                r_on, t_on = self._lobes(ctx)
                w, p, uv = si.wi, si.p, si.uv
                reflect = w[2] * wo[2] > 0
                if not active or not (r_on if reflect else t_on):
                    return ZERO, 0.0
                r = c_eval_pdf(self._inst, self._mat_for(ctx, si), w[0], w[1], w[2], wo[0], wo[1], wo[2],
                               p[0], p[1], p[2], uv[0], uv[1])
                return value_of(r), r.pdf

            def sample(self, ctx, si, sample1, sample2, active=True):
                r_on, t_on = self._lobes(ctx)
                if not (active and (r_on or t_on)):
                    return BSDFSample3f(), ZERO
                w = si.wi
                r = c_sample(self._inst, self._mat_for(ctx, si), w[0], w[1], w[2], sample1, sample2[0], sample2[1])
                bs = BSDFSample3f(SAMPLE_TEMPLATE)
                if not r.valid:
                    return bs, ZERO
                transmit = r.z * w[2] < 0
                if not (t_on if transmit else r_on):
                    return bs, ZERO
                bs.wo = Vector3f(r.x, r.y, r.z)
                bs.pdf = r.pdf
                if transmit:
                    ior = self._cfg.ior
                    bs.eta = ior if w[2] > 0 else 1.0 / ior
                    bs.sampled_type = T_TYPE
                    bs.sampled_component = 1
                return bs, weight_of(r)

        Dielectric.__name__ = Dielectric.__qualname__ = "MsxPosfree"
        return Dielectric

    return make_factory(build)


def _indent(obj):
    return str(obj).replace("\n", "\n  ")
