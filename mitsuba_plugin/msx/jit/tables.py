"""The core's tables in the Dr.Jit engine: twin of ``src/tables/``.

The engine computes no table itself. It reads each table once from the core through the C ABI
(``msx_table``: the axes and the node values) and uploads it as a Dr.Jit texture. A lookup maps x to its
fractional node position on each axis exactly as ``Axis::position`` does (warp, clamp to the nodes, NaN →
first node) and lets the texture interpolate linearly between nodes, as ``Grid::at`` does: texel i of an
axis of n nodes sits at texture coordinate (i + ½)/n, so position t reads coordinate (t + ½)/n.
Textures are built with ``use_accel=False`` so that the GPU interpolates in full float precision too.
"""

import threading

import drjit as dr
import mitsuba as mi
import numpy as np

from .microfacet import BECKMANN

_CACHE = {}
_LOCK = threading.Lock()


def _warp(lib, warp, x):
    if warp == lib.MSX_WARP_IDENTITY:
        return x
    if warp == lib.MSX_WARP_SQRT:
        return dr.sqrt(x)
    if warp == lib.MSX_WARP_SQUARE:
        return dr.square(dr.clip(x, 0.0, 1.0))
    if warp == lib.MSX_WARP_LN:
        return dr.log(x)
    return dr.sqrt(dr.maximum(1.0 - 1.0 / (x * x), 0.0))  # MSX_WARP_CRITICAL_COSINE


class Table:
    """One table of the core as a texture over its axes."""

    def __init__(self, kind, distribution):
        from .._native import ffi, lib

        self._lib = lib
        dist = lib.MSX_DISTRIBUTION_BECKMANN if distribution == BECKMANN else lib.MSX_DISTRIBUTION_GGX
        shape = ffi.new("MsxTableShape *")
        err = ffi.new("char[]", 512)
        rc = lib.msx_table(kind, dist, shape, ffi.NULL, 0, err, 512)
        if rc != lib.MSX_OK:
            raise RuntimeError("msx_table: " + ffi.string(err).decode(errors="replace"))
        values = np.empty(shape.len, dtype=np.float64)
        rc = lib.msx_table(kind, dist, shape, ffi.cast("double *", values.ctypes.data), shape.len, err, 512)
        if rc != lib.MSX_OK:
            raise RuntimeError("msx_table: " + ffi.string(err).decode(errors="replace"))
        self.axes = [(a.warp, a.lo, a.hi, a.n, bool(a.centred)) for a in shape.axes[0:shape.naxes]]
        dims = [a[3] for a in self.axes]
        tensor = mi.TensorXf(values.astype(np.float32).reshape(dims + [1]))
        cls = {1: mi.Texture1f, 2: mi.Texture2f, 3: mi.Texture3f}[len(dims)]
        self._tex = cls(tensor, use_accel=False, filter_mode=dr.FilterMode.Linear, wrap_mode=dr.WrapMode.Clamp)

    def _coordinate(self, axis, x):
        warp, lo, hi, n, centred = axis
        t = (_warp(self._lib, warp, mi.Float(x)) - lo) / (hi - lo)
        t = t * n - 0.5 if centred else t * (n - 1)
        t = dr.select(dr.isnan(t), 0.0, dr.clip(t, 0.0, n - 1))
        return (t + 0.5) / n

    def at(self, *x):
        """The interpolated value at x (one Float per axis, in the axes' order)."""
        # A texture's first coordinate runs along its last (fastest) axis.
        coords = [self._coordinate(a, v) for a, v in zip(self.axes, x)][::-1]
        p = {1: mi.Point1f, 2: mi.Point2f, 3: mi.Point3f}[len(coords)](*coords)
        return self._tex.eval(p)[0]


def get(kind, distribution):
    """The table ``kind`` (an ``MSX_TABLE_*`` constant) of a distribution, for the current variant
    (built on first use)."""
    key = (mi.variant(), kind, distribution)
    with _LOCK:
        table = _CACHE.get(key)
        if table is None:
            table = _CACHE[key] = Table(kind, distribution)
    return table
