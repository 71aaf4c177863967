"""Scalar variants, native route (the default; ``msx.register(backend="native")``): the native back end of
``msx_posfree``.

A C++ BSDF (``native/msx_mitsuba.cpp``) calls the Rust core once per BSDF
call, without Python and without the GIL, so Mitsuba's render threads run in
parallel. It is compiled on first use against the headers of the *installed*
Mitsuba and Dr.Jit (their struct layouts must match the wheel exactly; the
wheels are built with AVX, hence ``-mavx``) plus nanobind's headers (a PyPI
dependency), and cached under ``native/<key>/`` of msx's cache folder
(``$MSX_CACHE_DIR``, else ``$XDG_CACHE_HOME/msx``, default ``~/.cache/msx``) — the key hashes the sources
and every version involved, so an upgrade rebuilds it. The library is written atomically with its size and
checksum beside it (msx/_cache.py): a truncated or damaged build is reported in one line and compiled again.
A compile that fails is remembered there with its reason (``build-failed.txt``), so that other processes (the
render workers) do not retry it. Linux only (tested on x86-64); elsewhere :func:`build` raises
NativeUnavailable naming the platform, before importing anything POSIX-only, and msx.register() falls back
to the Python back end saying so.

Before it is used, the build is checked (:func:`self_check`): a conductor against Mitsuba's own
``roughconductor``, a dielectric's sample records (reflection and refraction: η, component, weight) and a
diffuse eval against the Python back end. A layout mismatch gives garbage there, and the Python back end is
used instead.

``msx.register()`` registers ``msx_posfree`` as a Python factory that parses
and validates the scene parameters (the same code and messages as the Python
back end) and instantiates the native class ``msx_posfree_native`` with them.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

NATIVE_PLUGIN = "msx_posfree_native"
_loaded = None  # the ctypes library once loaded and registered in this process


class NativeUnavailable(RuntimeError):
    """The native back end cannot be built or failed its check; the message says why (a compile failure adds
    the compiler's last lines), :meth:`summary` in one line."""

    def summary(self) -> str:
        lines = [ln.strip() for ln in str(self).splitlines() if ln.strip()]
        if not lines:
            return "unknown reason"
        first = lines[0].rstrip(":")
        detail = next((ln for ln in lines[1:] if "error" in ln.lower()), lines[1] if len(lines) > 1 else "")
        if len(detail) > 160:
            detail = detail[:157] + "..."
        return f"{first}: {detail}" if detail else first


def _sources():
    """(C++ source, msx.h): shipped in the package, or the repository's when running from a checkout."""
    here = Path(__file__).resolve().parent.parent  # the msx package (this module is msx/plugin/native.py)
    for src, hdr in ((here / "native" / "msx_mitsuba.cpp", here / "native" / "msx.h"),
                     (here.parent.parent / "native" / "msx_mitsuba.cpp", here.parent.parent / "include" / "msx.h")):
        if src.exists() and hdr.exists():
            return src, hdr
    raise NativeUnavailable("the C++ source of the native plugin is not installed")


def _platform_flags():
    """Compiler flags for this platform, or NativeUnavailable saying why there are none.

    Linux only (tested on x86-64): the plugin links against the wheel's ``libmitsuba.so`` with an rpath and
    marks its entry points with GCC's visibility attribute; macOS (``.dylib``, two-level namespaces) and
    Windows (MSVC, ``.dll``) would each need their own build, which nobody has run. Mitsuba's x86-64 wheels are
    compiled with AVX, and the struct layouts must match theirs (``-mavx``); other Linux machines are tried
    without it — the self-check decides."""
    if not sys.platform.startswith("linux"):
        raise NativeUnavailable(f"the native back end is built on Linux only (tested on x86-64); this is "
                                f"{sys.platform}")
    machine = platform.machine().lower()
    return ["-mavx"] if machine in ("x86_64", "amd64") else []


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
    from .. import _native

    ext = Path(_native.__file__).resolve()
    versions = (mitsuba.__version__, drjit.__version__, getattr(nanobind, "__version__", "?"))
    return cxx, inc, mi_dir, dr_dir, ext, versions


def build(verbose=False) -> Path:
    """The compiled plugin (built now unless cached). Raises NativeUnavailable."""
    from .. import _cache

    arch = _platform_flags()
    src, hdr = _sources()
    cxx, inc, mi_dir, dr_dir, ext, versions = _toolchain()
    h = hashlib.sha256()
    for part in (src.read_bytes(), hdr.read_bytes(), repr(versions).encode(), str(ext).encode(), cxx.encode(),
                 sys.version.encode(), Path(__file__).read_bytes(),  # this file: the compile command
                 repr((sys.platform, platform.machine(), arch)).encode()):
        h.update(part)
    out_dir = _cache.folder("native") / h.hexdigest()[:20]
    target = out_dir / "msx_native.so"
    if _cache.valid_file(target):  # the common case, without the lock
        return target
    _remembered_failure(out_dir)
    try:
        import fcntl  # POSIX only: imported here, so that elsewhere the fallback can say why
    except ImportError:
        raise NativeUnavailable(f"the native back end needs a POSIX system (Linux); this is {sys.platform}") from None
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        lock = open(out_dir / ".lock", "w")
    except OSError as e:
        raise NativeUnavailable(f"cannot write the native build into {out_dir} ({e.strerror or e}); set MSX_CACHE_DIR "
                                "to a writable folder") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # several processes may ask at once: one builds
        # Under the lock, so that a damaged build is reported (and rebuilt) by one process only.
        if _cache.check_file(target):
            return target
        _remembered_failure(out_dir)  # another process failed meanwhile
        tmp = out_dir / f".msx_native.{os.getpid()}.tmp.so"
        cmd = [cxx, "-std=c++20", "-O2", "-fPIC", "-shared", *arch, "-DNDEBUG", "-fvisibility=hidden",
               *[f"-I{d}" for d in inc], f"-I{hdr.parent}", str(src), "-o", str(tmp), str(ext),
               f"-L{mi_dir}", "-lmitsuba", f"-L{dr_dir}", "-ldrjit-core", "-ldrjit-extra", "-lnanothread",
               f"-Wl,-rpath,{mi_dir}", f"-Wl,-rpath,{dr_dir}"]
        # A one-time cost (several seconds): say so, or the first scene load looks hung.
        print(f"msx: compiling the native plugin for mitsuba {versions[0]} (once per install; cached in {out_dir})",
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
        _cache.commit_file(tmp, target)  # atomic, with its size and checksum beside it
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
        try:
            lib = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        except OSError as e:
            raise NativeUnavailable(f"the native build {path} does not load ({e}); delete it to rebuild") from None
        lib.msx_native_register.argtypes = [ctypes.c_char_p]
        lib.msx_native_register(NATIVE_PLUGIN.encode())
        _loaded = lib
    return _loaded


def self_check(mi):
    """The native plugin, just built or loaded, must give what the other routes give before it is used; a build
    whose struct layouts differ from the running Mitsuba (or a slip in the plugin's fields) fails here:

    - conductor, ``model="single"``: eval, pdf and the sample record equal Mitsuba's ``roughconductor``;
    - dielectric, ``model="single"``: the sample record of a reflection and of a refraction from either side
      (direction, pdf, η, sampled type and component, weight) equals the Python back end's (the same core);
    - diffuse microsurface, ``model="correlated"``: eval and pdf equal the Python back end's.

    Raises NativeUnavailable naming the first difference."""
    import drjit as dr

    from .parameters import Config
    from .scalar import make_bsdf_class

    python_class = make_bsdf_class(mi, mi.variant())

    def make(params, builtin=None):
        props = mi.Properties("msx_posfree")
        for k, v in params.items():
            props[k] = v
        native = mi.load_dict(dict(type=NATIVE_PLUGIN, **_native_props(Config(mi, props))))
        if builtin:
            other = mi.load_dict(dict({k: v for k, v in params.items() if k != "model"}, type=builtin))
        else:
            other = python_class(props)
        return native, other

    si = dr.zeros(mi.SurfaceInteraction3f)
    si.p, si.uv = mi.Point3f(0.25, -0.5, 1.0), mi.Point2f(0.3, 0.6)
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(450.0, 520.0, 600.0, 680.0)
    ctx = mi.BSDFContext()
    up, down = dr.normalize(mi.Vector3f(0.3, 0.1, 0.9)), dr.normalize(mi.Vector3f(0.2, -0.3, -0.8))
    wo = dr.normalize(mi.Vector3f(-0.2, 0.15, 0.85))

    def values(x):
        return [float(x[i]) for i in range(len(x))] if hasattr(x, "__len__") else [float(x)]

    def record(bs, w):
        return dict(wo=values(bs.wo), pdf=values(bs.pdf), eta=values(bs.eta), type=[int(bs.sampled_type)],
                    component=[int(bs.sampled_component)], weight=values(w))

    def differ(a, b):
        return any(len(x) != len(y) or any(abs(u - v) > 1e-4 * max(abs(v), 1e-3) for u, v in zip(x, y))
                   for x, y in zip(a, b))

    checks = []  # (what, native values, reference values)
    conductor = make(dict(distribution="ggx", alpha=0.3, material="Cu", model="single"), "roughconductor")
    si.wi = up
    for name, f in (("eval", lambda b: values(b.eval(ctx, si, wo))), ("pdf", lambda b: values(b.pdf(ctx, si, wo)))):
        checks.append((f"conductor single {name} (against roughconductor)", f(conductor[0]), f(conductor[1])))
    s1, s2 = 0.4, mi.Point2f(0.3, 0.7)
    for k, v in record(*conductor[0].sample(ctx, si, s1, s2)).items():
        checks.append((f"conductor single sample {k} (against roughconductor)", v,
                       record(*conductor[1].sample(ctx, si, s1, s2))[k]))

    dielectric = make(dict(surface="dielectric", distribution="ggx", alpha=0.3, int_ior=1.5, model="single"))
    transmitted = set()
    for side, wi, s1 in (("reflect", up, 0.01), ("refract", up, 0.99), ("refract from inside", down, 0.99)):
        si.wi = wi
        a, b = record(*dielectric[0].sample(ctx, si, s1, s2)), record(*dielectric[1].sample(ctx, si, s1, s2))
        if b["component"] == [1]:
            transmitted.add(side)
        for k in a:
            checks.append((f"dielectric single sample ({side}) {k}", a[k], b[k]))
    if transmitted != {"refract", "refract from inside"}:  # the check itself must see both components
        raise NativeUnavailable(f"the self-check's dielectric samples did not refract as planned ({transmitted})")

    diffuse = make(dict(surface="diffuse", distribution="ggx", alpha=0.5, model="correlated",
                        reflectance=mi.load_dict(dict(type="rgb", value=[0.8, 0.5, 0.2]))))
    si.wi = up
    for name, f in (("eval", lambda b: values(b.eval(ctx, si, wo))), ("pdf", lambda b: values(b.pdf(ctx, si, wo)))):
        checks.append((f"diffuse correlated {name}", f(diffuse[0]), f(diffuse[1])))

    for what, a, b in checks:
        if differ([a], [b]) or (not any(b) and what.endswith(("eval", "pdf"))):
            raise NativeUnavailable(f"the native build fails its self-check: {what} is {a}, expected {b} (the "
                                    "struct layouts differ from the installed Mitsuba, or the plugin is wrong)")


def _native_props(cfg) -> dict:
    """The parsed parameters as the properties of msx_posfree_native (see native/msx_mitsuba.cpp)."""
    d = dict(surface=cfg.surface, distribution=cfg.distribution, model=cfg.model, estimator=cfg.estimator,
             max_bounces=int(cfg.max_bounces), seed=str(cfg.seed),
             auto_tolerance=float(cfg.auto_tolerance if cfg.model == "auto" else 0.0), isotropic=bool(cfg.isotropic),
             alpha_u=cfg.alpha_u, mis_density=cfg.mis_density if cfg.mis_density_applies() else "default",
             sample_visible=bool(cfg.sample_visible))
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
    from .parameters import Config, warn

    load()
    try:
        self_check(mi)
    except NativeUnavailable:
        raise
    except Exception as e:  # noqa: BLE001 - a build that cannot even run the check is not used
        lines = str(e).strip().splitlines() or [type(e).__name__]
        raise NativeUnavailable(f"the native build fails its self-check: {lines[-1].strip()}") from None

    def factory(props):
        cfg = Config(mi, props)  # the same parsing, validation and messages as the Python back end
        warn(mi, cfg.sample_visible_note())
        return mi.load_dict(dict(type=NATIVE_PLUGIN, **_native_props(cfg)))

    return factory
