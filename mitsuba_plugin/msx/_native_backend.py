"""The native back end of ``msx_posfree`` for Mitsuba's scalar variants.

A C++ BSDF (``native/msx_mitsuba.cpp``) calls the Rust core once per BSDF
call, without Python and without the GIL, so Mitsuba's render threads run in
parallel. It is compiled on first use against the headers of the *installed*
Mitsuba and Dr.Jit (their struct layouts must match the wheel exactly; the
wheels are built with AVX, hence ``-mavx``) plus nanobind's headers (a PyPI
dependency), and cached under ``native/<key>/`` of msx's cache folder
(``$MSX_CACHE_DIR``, else ``$XDG_CACHE_HOME/msx``, default ``~/.cache/msx``) — the key hashes the sources
and every version involved, so an upgrade rebuilds it. A compile that fails is remembered there with its
reason (``build-failed.txt``), so that other processes (the render workers) do not retry it.

Before it is used, the build is checked against Mitsuba's own
``roughconductor`` (``model="single"`` must agree on eval and sample): a
layout mismatch gives garbage there and the Python back end is used instead.

``msx.register()`` registers ``msx_posfree`` as a Python factory that parses
and validates the scene parameters (the same code and messages as the Python
back end) and instantiates the native class ``msx_posfree_native`` with them.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

NATIVE_PLUGIN = "msx_posfree_native"
_loaded = None  # the ctypes library once loaded and registered in this process


class NativeUnavailable(RuntimeError):
    """The native back end cannot be built or failed its check; the message says why."""


def _sources():
    """(C++ source, msx.h): shipped in the package, or the repository's when running from a checkout."""
    here = Path(__file__).resolve().parent
    for src, hdr in ((here / "native" / "msx_mitsuba.cpp", here / "native" / "msx.h"),
                     (here.parent.parent / "native" / "msx_mitsuba.cpp", here.parent.parent / "include" / "msx.h")):
        if src.exists() and hdr.exists():
            return src, hdr
    raise NativeUnavailable("the C++ source of the native plugin is not installed")


def _cache_root() -> Path:
    base = os.environ.get("MSX_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "msx")
    return Path(base) / "native"


def _toolchain():
    """Compiler and include/library folders of the installed Mitsuba, Dr.Jit and nanobind."""
    import drjit
    import mitsuba

    cxx = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
    if not cxx:
        raise NativeUnavailable("no C++ compiler (set CXX or install g++)")
    try:
        import nanobind
    except ImportError:
        raise NativeUnavailable("nanobind's headers are missing (pip install nanobind)") from None
    mi_dir, dr_dir, nb_dir = (Path(m.__file__).resolve().parent for m in (mitsuba, drjit, nanobind))
    inc = [mi_dir / "include", dr_dir / "include", Path(nanobind.include_dir()), nb_dir / "ext" / "robin_map" / "include"]
    for d in inc:
        if not d.is_dir():
            raise NativeUnavailable(f"missing headers folder {d}")
    from . import _native

    ext = Path(_native.__file__).resolve()
    versions = (mitsuba.__version__, drjit.__version__, getattr(nanobind, "__version__", "?"))
    return cxx, inc, mi_dir, dr_dir, ext, versions


def build(verbose=False) -> Path:
    """The compiled plugin (built now unless cached). Raises NativeUnavailable."""
    src, hdr = _sources()
    cxx, inc, mi_dir, dr_dir, ext, versions = _toolchain()
    h = hashlib.sha256()
    for part in (src.read_bytes(), hdr.read_bytes(), repr(versions).encode(), str(ext).encode(), cxx.encode(),
                 sys.version.encode(), Path(__file__).read_bytes()):  # this file: the compile command
        h.update(part)
    out_dir = _cache_root() / h.hexdigest()[:20]
    target = out_dir / "msx_native.so"
    if target.exists():
        return target
    _remembered_failure(out_dir)
    try:
        import fcntl  # POSIX only: imported here, so that elsewhere the fallback can say why
    except ImportError:
        raise NativeUnavailable(f"the native back end needs a POSIX system (Linux); this is {sys.platform}") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several processes may ask at once: one builds
        if target.exists():
            return target
        _remembered_failure(out_dir)  # another process failed meanwhile
        tmp = out_dir / f"msx_native.{os.getpid()}.so"
        cmd = [cxx, "-std=c++20", "-O2", "-fPIC", "-shared", "-mavx", "-DNDEBUG", "-fvisibility=hidden",
               *[f"-I{d}" for d in inc], f"-I{hdr.parent}", str(src), "-o", str(tmp), str(ext),
               f"-L{mi_dir}", "-lmitsuba", f"-L{dr_dir}", "-ldrjit-core", "-ldrjit-extra", "-lnanothread",
               f"-Wl,-rpath,{mi_dir}", f"-Wl,-rpath,{dr_dir}"]
        # A one-time cost (several seconds): say so, or the first scene load looks hung.
        print(f"msx: compiling the native plugin for mitsuba {versions[0]} (first use; cached in {out_dir})",
              file=sys.stderr, flush=True)
        if verbose:
            print(" ".join(cmd), file=sys.stderr)
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            tail = "\n".join(r.stderr.strip().splitlines()[-8:])
            reason = f"compiling the native plugin failed ({cxx}):\n{tail}"
            tmp.unlink(missing_ok=True)
            if r.returncode > 0:  # the compiler's verdict on these inputs (not a signal): remembered
                failed = out_dir / _FAILED
                part = out_dir / f"{_FAILED}.{os.getpid()}"
                part.write_text(reason)
                os.replace(part, failed)  # atomic: whole or absent
            raise NativeUnavailable(reason)
        os.replace(tmp, target)
    return target


_FAILED = "build-failed.txt"


def _remembered_failure(out_dir: Path):
    """A build of these exact inputs (the folder's key) failed before: raise its reason instead of compiling
    again (every worker process would otherwise retry). Deleting the folder, or any change of the inputs
    (sources, versions, compiler), tries again."""
    try:
        reason = (out_dir / _FAILED).read_text()
    except (OSError, UnicodeDecodeError):
        return
    first, _, rest = reason.partition("\n")
    raise NativeUnavailable(f"{first} [remembered from an earlier build of the same inputs; delete {out_dir} to "
                            f"retry]" + (f"\n{rest}" if rest else ""))


def load():
    """Builds (if needed), loads and registers the native plugin for the scalar variants, once per process."""
    global _loaded
    if _loaded is None:
        path = build()
        lib = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        lib.msx_native_register.argtypes = [ctypes.c_char_p]
        lib.msx_native_register(NATIVE_PLUGIN.encode())
        _loaded = lib
    return _loaded


def self_check(mi):
    """model="single" through the native plugin must equal Mitsuba's roughconductor (eval, pdf and a sample
    record): a build whose struct layouts differ from the running Mitsuba fails here."""
    import drjit as dr

    from ._params import Config

    common = dict(distribution="ggx", alpha=0.3, material="Cu")
    props = mi.Properties("msx_posfree")
    for k, v in dict(common, model="single").items():
        props[k] = v
    ours = mi.load_dict(dict(type=NATIVE_PLUGIN, **_native_props(Config(mi, props))))
    ref = mi.load_dict(dict(common, type="roughconductor"))
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = dr.normalize(mi.Vector3f(0.3, 0.1, 0.9))
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 680.0)
    ctx = mi.BSDFContext()
    wo = dr.normalize(mi.Vector3f(-0.2, 0.15, 0.85))
    a, b = ours.eval(ctx, si, wo), ref.eval(ctx, si, wo)
    (sa, wa), (sb, wb) = ours.sample(ctx, si, 0.4, mi.Point2f(0.3, 0.7)), ref.sample(ctx, si, 0.4, mi.Point2f(0.3, 0.7))

    def close(x, y):
        return all(abs(float(x[i]) - float(y[i])) <= 1e-4 * max(abs(float(y[i])), 1e-3) for i in range(len(y)))

    ok = (close(a, b) and abs(float(ours.pdf(ctx, si, wo)) - float(ref.pdf(ctx, si, wo))) <= 1e-4 * float(ref.pdf(ctx, si, wo))
          and close(sa.wo, sb.wo) and abs(float(sa.pdf) - float(sb.pdf)) <= 1e-4 * float(sb.pdf) and close(wa, wb)
          and int(sa.sampled_type) == int(sb.sampled_type) and int(sa.sampled_component) == int(sb.sampled_component))
    if not ok:
        raise NativeUnavailable(f"the native build disagrees with Mitsuba's roughconductor (eval {a} vs {b}, "
                                f"sample {sa.wo}/{float(sa.pdf)} vs {sb.wo}/{float(sb.pdf)}): struct layouts differ "
                                "from the installed Mitsuba")


def _native_props(cfg) -> dict:
    """The parsed parameters as the properties of msx_posfree_native (see native/msx_mitsuba.cpp)."""
    d = dict(surface=cfg.surface, distribution=cfg.distribution, model=cfg.model, estimator=cfg.estimator,
             max_bounces=int(cfg.max_bounces), seed=str(cfg.seed),
             auto_tolerance=float(cfg.auto_tolerance if cfg.model == "auto" else 0.0), isotropic=bool(cfg.isotropic),
             alpha_u=cfg.alpha_u)
    if not cfg.isotropic:
        d["alpha_v"] = cfg.alpha_v
    if cfg.specular_reflectance is not None:
        d["specular_reflectance"] = cfg.specular_reflectance
    if cfg.surface == "conductor":
        d["eta"], d["k"] = cfg.eta, cfg.k
    elif cfg.surface == "dielectric":
        d["ior"] = float(cfg.ior)
        d["specular_transmittance"] = cfg.specular_transmittance
    else:
        d["reflectance"] = cfg.reflectance
    return d


def make_factory(mi):
    """The ``msx_posfree`` factory of the native back end for the current (scalar) variant."""
    from ._params import Config

    load()
    self_check(mi)

    def factory(props):
        cfg = Config(mi, props)  # the same parsing, validation and messages as the Python back end
        return mi.load_dict(dict(type=NATIVE_PLUGIN, **_native_props(cfg)))

    return factory
