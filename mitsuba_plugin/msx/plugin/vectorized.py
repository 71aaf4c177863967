"""Vectorized variants, batched route (``msx.register(backend="batched")``): the ``msx_posfree`` BSDF class
for Mitsuba's LLVM variants (``llvm_ad_rgb``, ``llvm_ad_spectral``, ``llvm_ad_mono``). The default route
of the vectorized variants is the Dr.Jit engine (``msx/jit/``); this one serves the models the engine does
not run.

Each BSDF method invocation makes exactly one batched C call
(``msx_eval_batch`` / ``msx_pdf_batch`` / ``msx_eval_pdf_batch`` /
``msx_sample_batch``, see ``include/msx.h``) over all the lanes it receives.
Parameters, flags, ``traverse`` and the factory are shared with the scalar
route (``base.py``).

Native code cannot run inside drjit's symbolic (traced) kernels, so

* **Rendering a scene that uses msx_posfree requires evaluated mode**: turn
  off ``dr.JitFlag.SymbolicLoops`` and ``dr.JitFlag.SymbolicCalls``, e.g.
  ``with msx.evaluated_mode(): img = mi.render(scene)``. The BSDF methods
  then receive evaluated arrays of the lanes that hit the surface.
* In symbolic mode (``dr.flag(dr.JitFlag.SymbolicScope)`` or symbolic
  inputs) the methods return a traceable fallback (zero value, zero pdf,
  invalid sample) instead of calling native code: drjit traces every live
  BSDF instance of the variant in a symbolic call, so a failure there would
  break symbolic renders of scenes that do not even use msx_posfree. The
  fallback counts the active lanes that reach it (a side effect recorded in
  the kernel); when that count becomes non-zero a warning is emitted (once
  per instance) at the next evaluated call, by :func:`check_fallback` and at
  interpreter exit: a symbolic render of a scene *with* msx_posfree gives
  a black surface.
"""

import atexit
import os
import warnings
import weakref

import numpy as np

from .._native import ffi, lib
from .parameters import PLUGIN, MsxParameterError, warn
from .base import ERR_LEN, make_base_class, make_factory, native_channels, one_line
from .vectorized_config import vectorized_config

# Live instances (for check_fallback).
_INSTANCES = weakref.WeakSet()

_FALLBACK_MSG = (
    "%s: a render reached msx_posfree in drjit's symbolic mode, where native code cannot run; "
    "the BSDF returned zero there (%d lanes so far), so the image is wrong where msx_posfree is visible. "
    "Render scenes that use msx_posfree in evaluated mode: `with msx.evaluated_mode(): mi.render(scene)` "
    "(turns off dr.JitFlag.SymbolicLoops and dr.JitFlag.SymbolicCalls)."
)


class _EvaluatedMode:
    """Turns off dr.JitFlag.SymbolicLoops and SymbolicCalls.

    As a context manager the previous flags are restored on exit; calling
    :meth:`enable` instead leaves them off for the rest of the process.
    """

    def __init__(self):
        import drjit as dr

        self._dr = dr
        self._saved = None

    def enable(self):
        dr = self._dr
        self._saved = (dr.flag(dr.JitFlag.SymbolicLoops), dr.flag(dr.JitFlag.SymbolicCalls))
        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        dr.set_flag(dr.JitFlag.SymbolicCalls, False)
        return self

    def __enter__(self):
        return self.enable()

    def __exit__(self, *exc):
        dr = self._dr
        if self._saved is not None:
            dr.set_flag(dr.JitFlag.SymbolicLoops, self._saved[0])
            dr.set_flag(dr.JitFlag.SymbolicCalls, self._saved[1])
        return False


_SWITCH_MSG = (
    "%s: Dr.Jit's symbolic loops and calls are now off in this process (dr.JitFlag.SymbolicLoops and "
    "SymbolicCalls): native code cannot run inside symbolic kernels, so a plain mi.render() of this scene "
    "would show the surface black. Every scene still renders correctly; scenes without msx_posfree render "
    "more slowly in this mode. Set MSX_KEEP_SYMBOLIC=1 to keep symbolic mode (msx_posfree then renders black "
    "unless rendered inside msx.evaluated_mode())."
)
_switched = False


def _switch_to_evaluated_mode():
    """Called by msx.register() in an LLVM variant: turns drjit's symbolic modes off (with one warning per
    process) so that a plain mi.render() of a scene with msx_posfree gives the right image."""
    global _switched
    import drjit as dr

    if os.environ.get("MSX_KEEP_SYMBOLIC") == "1":
        return
    if dr.flag(dr.JitFlag.SymbolicLoops) or dr.flag(dr.JitFlag.SymbolicCalls):
        dr.set_flag(dr.JitFlag.SymbolicLoops, False)
        dr.set_flag(dr.JitFlag.SymbolicCalls, False)
        if not _switched:
            _switched = True
            warnings.warn(_SWITCH_MSG % PLUGIN, RuntimeWarning, stacklevel=3)


def evaluated_mode():
    """Evaluated mode needed to render scenes with msx_posfree in LLVM variants.

    ``with msx.evaluated_mode(): mi.render(scene)`` — or
    ``msx.evaluated_mode().enable()`` to keep it for the whole process.
    """
    return _EvaluatedMode()


def check_fallback(error=False):
    """Warns (or raises RuntimeError with ``error=True``) if a symbolic
    render reached the zero fallback of a live msx_posfree instance.
    Returns the total number of fallback lanes."""
    total = 0
    for inst in list(_INSTANCES):
        total += inst._fallback_check(error)
    return total


@atexit.register
def _check_at_exit():
    try:
        check_fallback()
    except Exception:  # interpreter shutting down: nothing sensible to do
        pass


# The batched route hands the inputs to the Rust core as numbers: no derivative crosses it. Inputs that carry
# one stop the trace with this line instead of giving a silent zero gradient.
_NO_DERIVATIVE = ("%s: model='%s' on surface '%s' on the batched route (msx.register(backend=\"batched\")) received "
                  "inputs that carry a gradient (%s); this route computes on the Rust core and carries no "
                  "derivative — differentiate with the Dr.Jit engine (msx.register(), the default in *_ad_* "
                  "variants; docs/gradients.md lists what it differentiates), or keep these inputs out of the "
                  "gradient (dr.disable_grad)")


def make_bsdf_class(mi, variant):
    """Defines the BSDF classes for the current LLVM variant; returns the factory."""
    import drjit as dr

    nch = native_channels(mi, variant)

    BSDFFlags = mi.BSDFFlags
    Float, UInt32, Bool = mi.Float, mi.UInt32, mi.Bool
    Spectrum, Vector3f = mi.Spectrum, mi.Vector3f
    BSDFSample3f = mi.BSDFSample3f
    IMPORTANCE = mi.TransportMode.Importance
    R_BIT = int(BSDFFlags.GlossyReflection)
    T_BIT = int(BSDFFlags.GlossyTransmission)
    D_BIT = int(BSDFFlags.DiffuseReflection)
    SYMBOLIC = dr.VarState.Symbolic
    new = ffi.new
    cast = ffi.cast

    def spectrum_of(chs):
        return Spectrum(*chs) if nch > 1 else Spectrum(chs[0])

    def is_symbolic(*arrays):
        if dr.flag(dr.JitFlag.SymbolicScope):
            return True
        for a in arrays:
            if isinstance(a, (bool, int, float)):
                continue
            for leaf in (a if dr.depth_v(a) > 1 else (a,)):
                if getattr(leaf, "state", None) == SYMBOLIC:
                    return True
        return False

    def channels(value):
        """List of nch Float channels of a texture's eval() result."""
        if nch == 1:
            try:
                return [value[0]] if dr.depth_v(value) > 1 else [value]
            except TypeError:
                return [value]
        return [value[c] for c in range(nch)]

    def width_of(*arrays):
        n = 1
        for a in arrays:
            w = dr.width(a)
            if w > n:
                n = w
        return n

    def build(kind):
        if kind == "dielectric":
            R_TYPE, T_TYPE = R_BIT, T_BIT
        elif kind == "diffuse":
            R_TYPE, T_TYPE = D_BIT, D_BIT
        else:
            R_TYPE, T_TYPE = R_BIT, R_BIT
        dielectric = kind == "dielectric"

        class MsxPosfree(make_base_class(mi, kind, nch)):
            """Multiple-scattering microfacet BSDF (LLVM variants, batched native calls)."""

            def __init__(self, props):
                super().__init__(props)
                self._err = new("char[]", ERR_LEN)
                self._fallback = dr.zeros(UInt32, 1)
                self._fallback_warned = False
                self._fallback_seen = False
                _INSTANCES.add(self)
                self._refresh()

            def _config(self, props):
                # parameters.Config reads constant textures as Python floats: parse through the wrappers.
                cfg = vectorized_config(mi, props)
                warn(mi, cfg.sample_visible_note())
                return cfg

            # ------------------------------------------------- symbolic fallback

            def _fallback_count(self, active):
                """Records (in the traced kernel) how many active lanes reached the fallback."""
                if not self._fallback_seen:
                    self._fallback_seen = True
                try:
                    dr.scatter_reduce(dr.ReduceOp.Add, self._fallback, UInt32(1), UInt32(0), Bool(active))
                except Exception:  # never break the trace for a diagnostic
                    pass

            def _fallback_check(self, error=False):
                if not self._fallback_seen or dr.flag(dr.JitFlag.SymbolicScope):
                    return 0
                count = int(self._fallback[0])
                if count and error:
                    raise RuntimeError(_FALLBACK_MSG % (PLUGIN, count))
                if count and not self._fallback_warned:
                    msg = _FALLBACK_MSG % (PLUGIN, count)
                    self._fallback_warned = True
                    warnings.warn(msg, RuntimeWarning, stacklevel=3)
                    try:
                        mi.Log(mi.LogLevel.Warn, msg)
                    except Exception:
                        pass
                return count

            # ------------------------------------------------------- native call

            def _call(self, fn, ctx, si, active, wo=None, sample1=None, sample2=None, want_value=True,
                      want_pdf=True, want_wo=False):
                """One batched native call. Returns (values list | None, pdf | None, wo list | None)
                as mi.Float arrays (unmasked)."""
                if self._fallback_seen:
                    self._fallback_check()
                wi = si.wi
                si_a = active
                au = self._alpha_u.eval_1(si, si_a)
                av = au if self._cfg.isotropic else self._alpha_v.eval_1(si, si_a)
                inputs = {"wi": [wi[0], wi[1], wi[2]], "alpha_u": [au], "alpha_v": [av]}
                if wo is not None:
                    inputs["wo"] = [wo[0], wo[1], wo[2]]
                    # Each lane's key comes from its hit (see msx_call_key): no dependence on lane order.
                    inputs["p"] = [si.p[0], si.p[1], si.p[2]]
                    inputs["uv"] = [si.uv[0], si.uv[1]]
                if sample1 is not None:
                    inputs["sample1"] = [Float(sample1)]
                    inputs["sample2"] = [Float(sample2[0]), Float(sample2[1])]
                for name, tex in self._spectra:
                    inputs[name] = channels(tex.eval(si, si_a))
                flat = [Float(x) if not isinstance(x, Float) else x for v in inputs.values() for x in v]
                moving = [name for name, v in inputs.items() if any(dr.grad_enabled(x) for x in v)]
                if moving:
                    raise MsxParameterError(_NO_DERIVATIVE % (PLUGIN, self._cfg.model, self._cfg.surface,
                                                              ", ".join(moving)))
                n = max(width_of(*flat), dr.width(active) if not isinstance(active, bool) else 1)
                dr.eval(*flat)

                keep = []
                inp = new("MsxBatchIn *")
                inp.n = n

                def put(field_arr, x):
                    a = x.numpy()  # read-only use: may alias JIT memory
                    if a.dtype != np.float32 or not a.flags.c_contiguous:
                        a = np.ascontiguousarray(a, dtype=np.float32)
                    ln = a.shape[0]
                    if ln != n and ln != 1:
                        raise RuntimeError("%s: input of width %d in a batch of %d lanes" % (PLUGIN, ln, n))
                    keep.append(a)
                    field_arr.ptr = cast("const float *", a.ctypes.data)
                    field_arr.len = ln

                for name, vals in inputs.items():
                    if name in ("alpha_u", "alpha_v", "sample1"):
                        put(getattr(inp, name), vals[0])
                    else:
                        arr = getattr(inp, name)
                        for c, v in enumerate(vals):
                            put(arr[c], v)
                f_ior = np.full(1, self._cfg.ior, dtype=np.float32)
                keep.append(f_ior)
                inp.ior.ptr = cast("const float *", f_ior.ctypes.data)
                inp.ior.len = 1
                inp.mode = lib.MSX_MODE_IMPORTANCE if (dielectric and ctx.mode == IMPORTANCE) else lib.MSX_MODE_RADIANCE
                inp.key = 0

                out = new("MsxBatchOut *")
                val = pdf = wo_out = None
                if want_value:
                    val = np.empty((nch, n), dtype=np.float32)
                    for c in range(nch):
                        out.value[c] = cast("float *", val[c].ctypes.data)
                if want_pdf:
                    pdf = np.empty(n, dtype=np.float32)
                    out.pdf = cast("float *", pdf.ctypes.data)
                if want_wo:
                    wo_out = np.empty((3, n), dtype=np.float32)
                    for c in range(3):
                        out.wo[c] = cast("float *", wo_out[c].ctypes.data)
                rc = fn(self._h, inp, out, self._err, ERR_LEN)
                if rc != lib.MSX_OK:
                    raise RuntimeError("%s: native batch call failed (%d): %s"
                                       % (PLUGIN, rc, ffi.string(self._err).decode(errors="replace")))
                keep.clear()  # the input arrays the native call read may go
                # Never NaN/inf, whatever the inputs of inactive lanes held.
                res = []
                for a in (val, pdf, wo_out):
                    if a is None:
                        res.append(None)
                        continue
                    np.nan_to_num(a, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
                    res.append([Float(a[c]) for c in range(a.shape[0])] if a.ndim == 2 else Float(a))
                return res

            # ------------------------------------------------------------ calls

            def _lane_mask(self, ctx, si, wo, active):
                r_on, t_on = self._lobes(ctx)
                if not dielectric:
                    return active if r_on else None
                if not (r_on or t_on):
                    return None
                if r_on and t_on:
                    return active
                reflect = si.wi[2] * wo[2] > 0
                return active & (reflect if r_on else ~reflect)

            def _evaluate(self, batch, ctx, si, wo, active, **kw):
                """One batched call of eval / pdf / eval_pdf on the lanes whose lobe the context enables:
                (mask, (value, pdf, _)), or None when no lane is enabled or the call is traced
                symbolically (counted: those lanes get zero)."""
                mask = self._lane_mask(ctx, si, wo, active)
                if mask is None:
                    return None
                if is_symbolic(si.wi, wo, active):
                    self._fallback_count(mask)
                    return None
                return mask, self._call(batch, ctx, si, active, wo=wo, **kw)

            def eval_pdf(self, ctx, si, wo, active=True):
                r = self._evaluate(lib.msx_eval_pdf_batch, ctx, si, wo, active)
                if r is None:
                    return dr.zeros(Spectrum), dr.zeros(Float)
                mask, (val, pdf, _) = r
                return (dr.select(mask, spectrum_of(val), 0.0), dr.select(mask, pdf, 0.0))

            def eval(self, ctx, si, wo, active=True):
                r = self._evaluate(lib.msx_eval_batch, ctx, si, wo, active, want_pdf=False)
                if r is None:
                    return dr.zeros(Spectrum)
                mask, (val, _, _) = r
                return dr.select(mask, spectrum_of(val), 0.0)

            def pdf(self, ctx, si, wo, active=True):
                r = self._evaluate(lib.msx_pdf_batch, ctx, si, wo, active, want_value=False)
                if r is None:
                    return dr.zeros(Float)
                mask, (_, pdf, _) = r
                return dr.select(mask, pdf, 0.0)

            def sample(self, ctx, si, sample1, sample2, active=True):
                r_on, t_on = self._lobes(ctx)
                if not (r_on or t_on):
                    return dr.zeros(BSDFSample3f), dr.zeros(Spectrum)
                if is_symbolic(si.wi, sample1, sample2, active):
                    self._fallback_count(active)
                    return dr.zeros(BSDFSample3f), dr.zeros(Spectrum)
                val, pdf, wo = self._call(lib.msx_sample_batch, ctx, si, active, sample1=sample1,
                                          sample2=sample2, want_wo=True)
                n = dr.width(pdf)
                wo_v = Vector3f(wo[0], wo[1], wo[2])
                ok = Bool(active) & (pdf > 0)
                transmit = wo_v[2] * si.wi[2] < 0
                if dielectric:
                    ok &= dr.select(transmit, t_on, r_on)
                bs = dr.zeros(BSDFSample3f, n)
                bs.wo = dr.select(ok, wo_v, Vector3f(0.0))
                bs.pdf = dr.select(ok, pdf, 0.0)
                if dielectric:
                    ior = self._cfg.ior
                    eta_t = dr.select(si.wi[2] > 0, Float(ior), Float(1.0 / ior))
                    bs.eta = dr.select(ok & transmit, eta_t, Float(1.0))
                    bs.sampled_type = dr.select(ok & transmit, UInt32(T_TYPE), UInt32(R_TYPE))
                    bs.sampled_component = dr.select(ok & transmit, UInt32(1), UInt32(0))
                else:
                    bs.eta = dr.full(Float, 1.0, n)
                    bs.sampled_type = dr.full(UInt32, R_TYPE, n)
                    bs.sampled_component = dr.zeros(UInt32, n)
                return bs, dr.select(ok, spectrum_of(val), 0.0)

            # ------------------------------------------------------ parameters

            def to_string(self):
                return one_line(self._cfg, variant, "batched LLVM")

        MsxPosfree.__name__ = MsxPosfree.__qualname__ = "MsxPosfree"
        return MsxPosfree

    return make_factory(build)
