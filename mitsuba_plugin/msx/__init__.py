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

__version__ = "0.1.0"

__all__ = ["register", "registered_variants", "native_version", "diagnostics", "evaluated_mode", "check_fallback",
           "__version__"]

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


def register():
    """Register the ``msx_posfree`` BSDF for the current Mitsuba variant.

    Idempotent: a second call for the same variant does nothing. A Python
    BSDF class binds to the variant active when its class statement runs, so
    the classes are created per variant. Returns the factory Mitsuba calls
    (one class per surface kind, chosen from the ``surface`` property).
    """
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError("msx.register(): set a Mitsuba variant first, e.g. mi.set_variant('scalar_rgb')")
    cls = _REGISTERED.get(variant)
    if cls is not None:
        return cls
    if variant.startswith("llvm_"):
        from ._plugin_llvm import make_bsdf_class
    else:
        from ._plugin import make_bsdf_class

    cls = make_bsdf_class(mi, variant)
    mi.register_bsdf("msx_posfree", lambda props: cls(props))
    _REGISTERED[variant] = cls
    return cls


def evaluated_mode():
    """LLVM variants: context manager turning off dr.JitFlag.SymbolicLoops and
    SymbolicCalls, required to render scenes that use msx_posfree
    (``with msx.evaluated_mode(): mi.render(scene)``; ``.enable()`` keeps it on)."""
    from ._plugin_llvm import evaluated_mode as _f

    return _f()


def check_fallback(error=False):
    """LLVM variants: warn (or raise) if a symbolic render reached msx_posfree's zero fallback."""
    from ._plugin_llvm import check_fallback as _f

    return _f(error)
