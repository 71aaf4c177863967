"""Direct access to the Rust core from NumPy, without Mitsuba: one batched C
call per method over arrays of directions (the evaluation report's atlas,
lobes and energy curves use it; so can a user's own study).

    from msx.core import CoreBsdf
    b = CoreBsdf(surface="conductor", distribution="ggx", model="heitz", alpha=0.5)
    f = b.eval(wi, wo)                 # (channels, n): f·|cos θ_o| per lane
    wo, weight, pdf = b.sample(wi, rng.random((3, n)))

Directions are (n, 3) arrays in the local frame (z = normal); material values
are scalars or per-lane arrays. Every call also reports what the C ABI had to
clean (``msx.diagnostics()``), so a study sees raw defects.
"""

from __future__ import annotations

import numpy as np

from ._native import ffi, lib
from .plugin.parameters import DISTRIBUTIONS, ESTIMATORS, MIS_DENSITIES, MODELS, SURFACES

_ERR_LEN = 512


class CoreError(ValueError):
    """The core refused a configuration or a batch (message names the parameter)."""


class CoreBsdf:
    """One configured BSDF of the core (see README.md for the parameters)."""

    def __init__(self, surface="conductor", distribution="ggx", model="correlated", estimator="pt", *,
                 channels=1, seed=0, max_bounces=0, auto_tolerance=0.0, alpha=0.5, alpha_v=None, eta=0.0, k=1.0,
                 ior=1.5, reflectance=1.0, radiance=True, mis_density=None, sample_visible=True):
        for name, value, allowed in (("surface", surface, SURFACES), ("distribution", distribution, DISTRIBUTIONS),
                                     ("model", model, MODELS), ("estimator", estimator, ESTIMATORS)):
            if value not in allowed:
                raise CoreError(f"unknown {name} '{value}'; allowed: {', '.join(allowed)}")
        if mis_density is not None and mis_density not in MIS_DENSITIES:
            raise CoreError(f"unknown mis_density '{mis_density}'; allowed: {', '.join(MIS_DENSITIES)}")
        self.surface, self.model, self.estimator, self.channels = surface, model, estimator, int(channels)
        params = ffi.new("MsxParams *", {
            "surface": SURFACES[surface], "distribution": DISTRIBUTIONS[distribution], "model": MODELS[model],
            "estimator": ESTIMATORS[estimator], "max_bounces": max_bounces, "channels": self.channels,
            "seed": seed, "auto_tolerance": auto_tolerance,
            "mis_density": 0 if mis_density is None else MIS_DENSITIES[mis_density],  # None: the core's default
            "sample_all_normals": 0 if sample_visible else 1,  # Mitsuba's sample_visible=false: 1
        })
        handle = ffi.new("MsxBsdf **")
        self._err = ffi.new("char[]", _ERR_LEN)
        rc = lib.msx_bsdf_new(params, handle, self._err, _ERR_LEN)
        if rc != lib.MSX_OK:
            raise CoreError(ffi.string(self._err).decode(errors="replace"))
        self._h = ffi.gc(handle[0], lib.msx_bsdf_free)
        self.material = dict(alpha_u=alpha, alpha_v=alpha if alpha_v is None else alpha_v, eta=eta, k=k, ior=ior,
                             reflectance=reflectance)
        self.radiance = radiance
        self._key = 0

    # ---------------------------------------------------------------- inputs

    def _batch(self, n, wi, wo=None, samples=None, key=None, **material):
        keep = []
        inp = ffi.new("MsxBatchIn *")
        inp.n = n

        def put(field, values):
            a = np.ascontiguousarray(np.asarray(values, dtype=np.float32).reshape(-1))
            if a.shape[0] not in (1, n):
                raise CoreError(f"an input of {a.shape[0]} values in a batch of {n} lanes")
            keep.append(a)
            field.ptr = ffi.cast("const float *", a.ctypes.data)
            field.len = a.shape[0]

        def channel(values, c):
            """Per-channel values: a scalar, up to 4 constants (one per channel) or a (channels, n) array."""
            v = np.asarray(values, dtype=np.float32)
            if v.ndim == 0:
                return v
            return v[min(c, v.shape[0] - 1)]

        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        for c in range(3):
            put(inp.wi[c], wi[:, c])
        if wo is not None:
            wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
            for c in range(3):
                put(inp.wo[c], wo[:, c])
        if samples is not None:
            put(inp.sample1, samples[0])
            put(inp.sample2[0], samples[1])
            put(inp.sample2[1], samples[2])
        m = dict(self.material, **material)
        put(inp.alpha_u, m["alpha_u"])
        put(inp.alpha_v, m["alpha_v"])
        put(inp.ior, m["ior"])
        for name, field in (("eta", inp.eta), ("k", inp.k), ("reflectance", inp.reflectance)):
            for c in range(4):
                put(field[c], channel(m[name], c))
        inp.mode = lib.MSX_MODE_RADIANCE if self.radiance else lib.MSX_MODE_IMPORTANCE
        if key is None:
            key, self._key = self._key, self._key + n
        inp.key = key & 0xFFFFFFFFFFFFFFFF
        return inp, keep

    def _out(self, n, value=True, pdf=False, wo=False):
        out = ffi.new("MsxBatchOut *")
        arrays = {}
        if value:
            arrays["value"] = np.empty((self.channels, n), np.float32)
            for c in range(self.channels):
                out.value[c] = ffi.cast("float *", arrays["value"][c].ctypes.data)
        if pdf:
            arrays["pdf"] = np.empty(n, np.float32)
            out.pdf = ffi.cast("float *", arrays["pdf"].ctypes.data)
        if wo:
            arrays["wo"] = np.empty((3, n), np.float32)
            for c in range(3):
                out.wo[c] = ffi.cast("float *", arrays["wo"][c].ctypes.data)
        return out, arrays

    def _check(self, rc):
        if rc != lib.MSX_OK:
            raise CoreError(ffi.string(self._err).decode(errors="replace"))

    @staticmethod
    def _n(*arrays):
        return max(np.asarray(a).reshape(-1, 3).shape[0] for a in arrays if a is not None)

    # ---------------------------------------------------------------- calls

    def eval(self, wi, wo, orders=None, key=None, **material):
        """f·|cos θ_o| per channel, shape (channels, n); `orders` = (first, last) restricts the scattering orders."""
        n = self._n(wi, wo)
        inp, keep = self._batch(n, wi, wo, key=key, **material)
        out, arrays = self._out(n)
        if orders is None:
            self._check(lib.msx_eval_batch(self._h, inp, out, self._err, _ERR_LEN))
        else:
            first, last = orders
            self._check(lib.msx_eval_orders_batch(self._h, inp, int(first), int(min(last, 2**32 - 1)), out,
                                                  self._err, _ERR_LEN))
        del keep
        return arrays["value"].astype(np.float64)

    def pdf(self, wi, wo, **material):
        n = self._n(wi, wo)
        inp, keep = self._batch(n, wi, wo, **material)
        out, arrays = self._out(n, value=False, pdf=True)
        self._check(lib.msx_pdf_batch(self._h, inp, out, self._err, _ERR_LEN))
        del keep
        return arrays["pdf"].astype(np.float64)

    def sample(self, wi, samples, **material):
        """(wo (n, 3), weight (channels, n), pdf (n)) from uniform `samples` of shape (3, n); invalid: pdf 0."""
        samples = np.asarray(samples, dtype=np.float32)
        n = samples.shape[1]
        inp, keep = self._batch(n, wi, samples=samples, **material)
        out, arrays = self._out(n, value=True, pdf=True, wo=True)
        self._check(lib.msx_sample_batch(self._h, inp, out, self._err, _ERR_LEN))
        del keep
        return arrays["wo"].T.astype(np.float64), arrays["value"].astype(np.float64), arrays["pdf"].astype(np.float64)

    def sample_orders(self, wi, samples, **material):
        """`sample` plus each sample's scattering order (n,): the number of microfacet events of the
        sampled path (1 for the analytic models, 0 for an invalid sample)."""
        samples = np.asarray(samples, dtype=np.float32)
        n = samples.shape[1]
        inp, keep = self._batch(n, wi, samples=samples, **material)
        out, arrays = self._out(n, value=True, pdf=True, wo=True)
        orders = np.empty(n, np.uint32)
        self._check(lib.msx_sample_orders_batch(self._h, inp, out, ffi.cast("uint32_t *", orders.ctypes.data),
                                                self._err, _ERR_LEN))
        del keep
        return (arrays["wo"].T.astype(np.float64), arrays["value"].astype(np.float64),
                arrays["pdf"].astype(np.float64), orders)


def pexit_study(distribution, alpha, theta_i, vertices, paths=2000, seed=1):
    """Bitterli & d'Eon's p_exit against the stable invariance-principle form on conductor walk paths:
    (median relative error, largest finite relative error, fraction non-finite)."""
    r = lib.msx_pexit_study(DISTRIBUTIONS[distribution], float(alpha), float(theta_i), int(vertices), int(paths),
                            int(seed))
    return r.median_rel_error, r.max_rel_error, r.nonfinite_fraction
