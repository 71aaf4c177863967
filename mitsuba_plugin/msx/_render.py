"""Rendering for the command line: one scene, its samples split into chunks
rendered by worker processes and averaged.

Scalar variants run one render thread per process when the BSDF is the
Python class (Python BSDFs serialise on the GIL), so the CLI parallelises
over processes: each chunk is a render with its own seed, and the chunks are
averaged weighted by their sample counts.

Failure handling (the reason this module exists): a scene that fails to load,
a worker that dies and Ctrl-C all end the run at once with one clear line
(:class:`RenderError`) instead of a pool that respawns failing workers.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import re
import signal
import sys
import time
from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

DEFAULT_VARIANT = "scalar_rgb"


class RenderError(Exception):
    """A render could not run; the message is one line for the user."""


# Mitsuba reports a failed plugin constructor as "[parser.cpp:N] At FILE (line L, col C): failed to
# instantiate … plugin …: Traceback … \nSomeError: message"; the user needs FILE:L and the message.
_AT_LOCATION = re.compile(r"At (.+?) \(line (\d+), col \d+\)")
_EXCEPTION_PREFIX = re.compile(r"^(?:[A-Za-z_][\w.]*(?:Error|Exception)): ")


def one_line(error: BaseException) -> str:
    """The user-facing one-line form of an exception raised while loading or rendering a scene."""
    text = str(error).strip()
    if not text:
        return type(error).__name__
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    last = lines[-1]
    message = _EXCEPTION_PREFIX.sub("", last) if len(lines) > 1 else _EXCEPTION_PREFIX.sub("", lines[0])
    # Mitsuba's own messages start with "[file.cpp:line] "; keep only the text.
    message = re.sub(r"^\[[\w.]+:\d+\]\s*", "", message)
    at = _AT_LOCATION.search(text)
    if at and at.group(1) not in message:
        message = f"{at.group(1)}:{at.group(2)}: {message}"
    return message


# ----------------------------------------------------------------- progress


class Progress:
    """Progress of one render: an updating line on a terminal, plain lines otherwise."""

    def __init__(self, label: str, total: int, enabled: bool = True, stream=None):
        self.label, self.total, self.enabled = label, total, enabled
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()

    def update(self, done: int):
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        eta = el / done * (self.total - done) if done else float("nan")
        eta_s = f", ETA {eta:5.1f} s" if done and done < self.total else ""
        line = f"{self.label}: {done}/{self.total} chunks, {el:5.1f} s{eta_s}"
        if self.tty:
            self.stream.write("\r" + line + " " * 8)
            if done == self.total:
                self.stream.write("\n")
        elif done > 0:
            self.stream.write(line + "\n")
        self.stream.flush()

    def close(self):
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


# ----------------------------------------------------------------- workers

_scenes: dict = {}  # per process: (variant, path, params) -> loaded scene


def setup_variant(variant: str, workers: int = 1):
    """Sets the Mitsuba variant and registers msx_posfree. Render threads: with the native back end the
    cores are shared among the `workers` processes; the Python back end of the scalar variants runs one
    thread (Python BSDFs serialise on the GIL, more threads only add contention)."""
    import drjit as dr
    import mitsuba as mi

    try:
        mi.set_variant(variant)
    except Exception as e:
        raise RenderError(f"unknown or unavailable Mitsuba variant '{variant}' ({one_line(e)})") from None
    import msx

    msx.register()  # LLVM variants: also turns drjit's symbolic modes off
    if variant.startswith("scalar"):
        cores = os.cpu_count() or 1
        dr.set_thread_count(max(1, cores // max(1, workers)) if msx.backend() == "native" else 1)
    return mi


_workers = 1  # worker processes of the current render (sets each one's thread count)


def load_scene(mi, scene: str, **params):
    """mi.load_file with at least 2 Dr.Jit threads: with one thread, Mitsuba 3.9 deadlocks reading an EXR
    (OpenEXR's tasks wait for a pool worker that never comes); the render's own thread count is restored."""
    import drjit as dr

    threads = dr.thread_count()
    if threads < 2:
        dr.set_thread_count(2)
    try:
        return mi.load_file(scene, **params)
    finally:
        if threads < 2:
            dr.set_thread_count(threads)


def _load(variant: str, scene: str, params: dict):
    key = (variant, scene, tuple(sorted(params.items())))
    if key not in _scenes:
        mi = setup_variant(variant, _workers)
        try:
            _scenes[key] = load_scene(mi, scene, **params)
        except Exception as e:
            raise RenderError(one_line(e)) from None
    return _scenes[key]


def _render_chunk(variant: str, scene: str, params: dict, seed: int, spp: int):
    """One chunk: (seed, spp, image, seconds). Every failure becomes a RenderError (picklable, one line)."""
    import mitsuba as mi
    import numpy as np

    s = _load(variant, scene, params)
    t0 = time.perf_counter()
    try:
        img = mi.render(s, seed=seed, spp=spp)
    except Exception as e:
        raise RenderError(f"{Path(scene).name}: render failed: {one_line(e)}") from None
    return seed, spp, np.array(img, dtype=np.float64), time.perf_counter() - t0


def _worker_init(workers):
    global _workers
    _workers = workers
    # Ctrl-C reaches the whole process group: the parent stops the workers itself.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _stop(executor: ProcessPoolExecutor):
    """Ends the workers now (running chunks included)."""
    procs = list(getattr(executor, "_processes", {}).values())
    executor.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)
        if p.is_alive():
            p.kill()


def _exit_codes(executor: ProcessPoolExecutor):
    """Exit codes of dead workers, without the SIGTERM the executor sends to the others when the pool breaks."""
    return sorted({p.exitcode for p in getattr(executor, "_processes", {}).values()
                   if p.exitcode not in (None, 0, -signal.SIGTERM)})


def with_assets(scene: str, params: dict) -> dict:
    """Generates the assets a scene refers to as `$assets/...` (msx/assets.py): into the scene's own
    `assets/` folder (its default), or, where that is not writable, into the cache (then passed as the
    `assets` parameter)."""
    from . import assets

    path = Path(scene)
    if "$assets" not in path.read_text():
        return params
    if "assets" in params:
        assets.ensure(params["assets"])
        return params
    try:
        assets.ensure(path.parent / "assets")
        return params
    except OSError:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "msx" / "assets"
        assets.ensure(cache)
        return dict(params, assets=str(cache))


def _chunks(spp: int, n: int):
    n = max(1, min(n, spp))
    base, extra = divmod(spp, n)
    return [base + (1 if k < extra else 0) for k in range(n)]


def render_chunks(scene: str, tasks, *, variant: str, params: dict, workers: int, on_result):
    """Renders the (seed, spp) `tasks` of `scene`, calling `on_result(chunk)` as each finishes.

    The first failure (scene load, render, a dying worker, Ctrl-C) stops every
    worker and raises: RenderError, or KeyboardInterrupt."""
    if workers <= 1 or len(tasks) <= 1:
        for seed, spp in tasks:
            on_result(_render_chunk(variant, scene, params, seed, spp))
        return
    ctx = mp.get_context("spawn")
    n = min(workers, len(tasks))
    executor = ProcessPoolExecutor(n, mp_context=ctx, initializer=_worker_init, initargs=(n,))
    try:
        pending = {executor.submit(_render_chunk, variant, scene, params, seed, spp) for seed, spp in tasks}
        while pending:
            done, pending = wait(pending, return_when=FIRST_EXCEPTION)
            for f in done:
                on_result(f.result())  # re-raises the worker's RenderError
    except BrokenProcessPool:
        codes = _exit_codes(executor)
        how = f" (exit code {', '.join(map(str, codes))})" if codes else ""
        _stop(executor)
        raise RenderError(f"{Path(scene).name}: a render worker process died{how}") from None
    except BaseException:
        _stop(executor)
        raise
    executor.shutdown(wait=True)


def render_scene(scene: str, *, variant: str = DEFAULT_VARIANT, spp: int | None = None, params: dict | None = None,
                 workers: int = 1, seed: int = 0, chunks: int | None = None, progress: bool = True, label: str = ""):
    """Renders `scene`; returns (image as float64 array [H, W, C], [(spp, image)] per chunk, wall seconds).

    The samples are split into `chunks` renders with distinct seeds (default
    max(workers, 4)), run on `workers` processes and averaged (weighted by
    spp). The chunk seeds depend only on `seed` and the chunk index, so the
    same call gives the same image whatever `workers` is."""
    import numpy as np

    scene = resolve_scene(scene)
    params = with_assets(scene, {k: str(v) for k, v in (params or {}).items()})
    if spp is None:
        spp = int(params.get("spp", 16))
    if spp < 1:
        raise RenderError(f"spp must be ≥ 1 (got {spp})")
    params["spp"] = str(spp)
    counts = _chunks(spp, chunks or max(workers, 4))
    tasks = [(seed * 1000 + k, c) for k, c in enumerate(counts)]
    results = []
    bar = Progress(label or Path(scene).name, len(tasks), progress)
    t0 = time.perf_counter()

    def collect(r):
        results.append(r)
        bar.update(len(results))

    try:
        render_chunks(scene, tasks, variant=variant, params=params, workers=workers, on_result=collect)
    except BaseException:
        bar.close()
        raise
    wall = time.perf_counter() - t0
    results.sort(key=lambda r: r[0])
    total = sum(r[1] for r in results)
    image = sum(r[2] * r[1] for r in results) / total
    if not np.all(np.isfinite(image)):
        raise RenderError(f"non-finite pixels in the render of {scene}")
    return image, [(r[1], r[2]) for r in results], wall


def write_image(path: Path, image, variant: str = DEFAULT_VARIANT):
    """Writes an EXR (linear) and a PNG (sRGB) next to each other."""
    import mitsuba as mi
    import numpy as np

    if mi.variant() is None:
        mi.set_variant(variant)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.ascontiguousarray(image, dtype=np.float32)
    fmt = mi.Bitmap.PixelFormat.RGB if arr.ndim == 3 and arr.shape[-1] == 3 else mi.Bitmap.PixelFormat.Y
    bmp = mi.Bitmap(arr, pixel_format=fmt)
    # Writing an EXR deadlocks like reading one with a single Dr.Jit thread (the Python back end's setting).
    import drjit as dr

    threads = dr.thread_count()
    if threads < 2:
        dr.set_thread_count(2)
    try:
        bmp.write(str(path.with_suffix(".exr")))
    finally:
        if threads < 2:
            dr.set_thread_count(threads)
    bmp.convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True).write(str(path.with_suffix(".png")))


def resolve_scene(scene) -> str:
    """`scene` as given if it exists, else the shipped scene of that name (``msx render fig01_metals.xml``
    works from any directory); a clear error naming the shipped scenes otherwise."""
    if os.path.exists(scene):
        return str(scene)
    hint = ""
    if os.path.dirname(str(scene)) == "":  # a bare name: look among the shipped scenes
        try:
            shipped = scenes_dir()
        except RenderError:
            shipped = None
        if shipped is not None:
            if (shipped / str(scene)).exists():
                return str(shipped / str(scene))
            hint = "; shipped scenes: " + ", ".join(sorted(p.name for p in shipped.glob("*.xml")))
    raise RenderError(f"scene file not found: {scene}{hint}")


def scenes_dir() -> Path:
    """The scene files: shipped inside the installed package (``msx/scenes``),
    or the repository's ``scenes/`` when running from a checkout (editable install)."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "scenes", here.parent.parent / "scenes"):
        if (candidate / "fig09_copper_sphere.xml").exists():
            return candidate
    raise RenderError("the scene files were not found (neither in the installed package nor in a checkout); "
                      "pass --scenes DIR")
