"""msx — multiple-scattering microfacet BSDFs for Mitsuba 3.

Usage::

    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    import msx
    msx.register()            # registers the BSDF "msx_posfree" for this variant

The math lives in a Rust library linked into the cffi extension
``msx._native``; this package only parses parameters, evaluates textures at
the hit and forwards each BSDF call to the C ABI (``include/msx.h``).
"""

import os
import functools
import threading

from ._scenes import scene_path

__version__ = "0.1.0"

__all__ = ["register", "backend", "registered_variants", "native_version", "diagnostics", "evaluated_mode", "check_fallback",
           "__version__", "scene_path"]

# Variants for which msx_posfree has been registered in this process.
_REGISTERED = {}


def native_version():
    """Version string of the linked Rust core."""
    from ._native import ffi, lib

    return ffi.string(lib.msx_version()).decode()


def diagnostics():
    """Process-wide counters of the Rust core's C ABI: output values it had to
    clean before returning them to Mitsuba (``nonfinite``: NaN or ±Inf,
    ``negative``) and panics it caught (``panics``). All stay 0 unless the core
    has a defect (docs/conventions.md); the tests assert on them."""
    from ._native import lib

    d = lib.msx_diagnostics()
    return {"nonfinite": int(d.nonfinite), "negative": int(d.negative), "panics": int(d.panics)}


def registered_variants():
    """Variants in which :func:`register` has registered ``msx_posfree``."""
    return sorted(_REGISTERED)


BACKENDS = ("auto", "native", "python", "jit", "batched")


def register(backend=None):
    """Register the ``msx_posfree`` BSDF for the current Mitsuba variant.

    ``backend``, per variant kind (also ``MSX_BACKEND``; ``None``/``"auto"`` picks the fastest):

    - scalar variants: ``"native"`` (a C++ plugin calling the Rust core directly — no Python per call,
      all render threads; compiled on first use and cached, see ``plugin/native.py``; the default where
      it builds and passes its check, else Python, saying why once) or ``"python"`` (the Python class,
      one call per sample, one render thread);
    - vectorized variants (``llvm_*``, ``cuda_*``): ``"jit"`` (the default: the Dr.Jit engine, ``msx/jit/``,
      traced into Mitsuba's kernels; drjit's flags stay as they are) or ``"batched"`` (one batched native
      call per wavefront for the models the engine does not run yet; it turns drjit's symbolic loops and
      calls off for the whole process, which slows every other scene down).

    Idempotent per (variant, backend). Returns the factory Mitsuba calls.
    """
    import mitsuba as mi

    variant = mi.variant()
    usable = [v for v in mi.variants() if "polarized" not in v]
    if variant is None:
        raise RuntimeError("msx.register(): no Mitsuba variant is set; call mi.set_variant(...) first with one of "
                           f"{', '.join(usable)}")
    typed = "msx.register()" if backend is None else f"msx.register(backend={backend!r})"
    if backend is None and os.environ.get("MSX_BACKEND"):
        backend = os.environ["MSX_BACKEND"]
        typed = f"msx.register() with MSX_BACKEND={backend!r}"
    backend = backend or "auto"
    if not isinstance(backend, str) or backend not in BACKENDS:
        import difflib

        close = difflib.get_close_matches(str(backend).lower(), BACKENDS, n=1) if isinstance(backend, str) else []
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise ValueError(f"{typed}: unknown back end {backend!r}{hint}; back ends: {', '.join(BACKENDS)}")
    if "polarized" in variant:
        raise NotImplementedError(f"{typed}: Mitsuba variant '{variant}' is polarized, which msx_posfree does not "
                                  f"support; set one of {', '.join(usable)}")
    known = _REGISTERED.get(variant)
    if known is not None and backend in ("auto", known[0]):
        return known[1]
    scalar = variant.startswith("scalar_")
    if scalar and backend in ("jit", "batched"):
        raise RuntimeError(f"{typed}: the '{backend}' back end serves Mitsuba's vectorized variants (llvm_*, "
                           f"cuda_*); in {variant} use 'native' or 'python'")
    if not scalar and backend in ("native", "python"):
        raise RuntimeError(f"{typed}: the '{backend}' back end serves Mitsuba's scalar variants; in {variant} use "
                           "'jit' (the default) or 'batched'")
    factory, chosen = None, "python"
    if scalar and backend in ("auto", "native"):
        from .plugin.native import NativeUnavailable, make_factory

        try:
            factory, chosen = make_factory(mi), "native"
        except NativeUnavailable as e:
            if backend == "native":
                raise RuntimeError(f"{typed}: the native back end is unavailable here ({e.summary()}); use "
                                   "backend='python', or leave backend unset to fall back to it") from None
            _warn_once(f"msx: the native back end is unavailable ({e.summary()}); using the Python back end "
                       "(one Python call per BSDF call, one render thread)")
    if factory is None:
        if not scalar and backend == "batched":
            from .plugin.vectorized import _switch_to_evaluated_mode, make_bsdf_class

            # Native code cannot run in drjit's symbolic kernels: turn them off now (saying so once), so that
            # a plain mi.render() of a scene with msx_posfree gives the right image. (Mitsuba's scene loader
            # restores drjit's flags after loading, so the switch cannot wait for the instance.)
            _switch_to_evaluated_mode()
            factory, chosen = make_bsdf_class(mi, variant), "batched"
        elif not scalar:
            from .plugin.parameters import channels_of
            from .plugin.jit_bsdf import make_bsdf_factory

            channels_of(mi, variant)  # polarized variants: a clear error now, not at scene load
            factory, chosen = make_bsdf_factory(variant), "jit"
        else:
            from .plugin.scalar import make_bsdf_class

            factory = make_bsdf_class(mi, variant)
    mi.register_bsdf("msx_posfree", functools.partial(_create, factory))  # no frame of its own in a traceback
    _REGISTERED[variant] = (chosen, factory)
    return factory


_CREATE_LOCK = threading.Lock()


def _create(factory, props):
    """Mitsuba's scene loader instantiates plugins on several threads at once; the factories load helper
    objects with mi.load_dict (conductor presets, the native plugin), which crashed when two threads did so
    concurrently. One instance at a time (instantiation is rare; rendering is not affected)."""
    from .plugin.parameters import MsxParameterError

    with _CREATE_LOCK:
        try:
            return factory(props)
        except MsxParameterError as e:
            # Mitsuba quotes the Python traceback in its message: a scene's mistake is the one line, not the
            # frames of msx's parser that found it.
            error = MsxParameterError(str(e))
    raise error


def backend():
    """The back end of ``msx_posfree`` in the current variant (``"native"``, ``"python"``, ``"jit"`` or
    ``"batched"``), or None if :func:`register` has not run for it."""
    import mitsuba as mi

    known = _REGISTERED.get(mi.variant())
    return known[0] if known else None


_WARNED = set()


def _warn_once(message):
    if message not in _WARNED:
        _WARNED.add(message)
        import warnings

        warnings.warn(message, RuntimeWarning, stacklevel=3)


def evaluated_mode():
    """Vectorized variants, batched route only (``msx.register(backend="batched")``): context manager
    turning off dr.JitFlag.SymbolicLoops and SymbolicCalls, which that route needs
    (``with msx.evaluated_mode(): mi.render(scene)``; ``.enable()`` keeps it on). The Dr.Jit engine, the
    default, needs no such mode."""
    from .plugin.vectorized import evaluated_mode as _f

    return _f()


def check_fallback(error=False):
    """LLVM variants: warn (or raise) if a symbolic render reached msx_posfree's zero fallback."""
    from .plugin.vectorized import check_fallback as _f

    return _f(error)
