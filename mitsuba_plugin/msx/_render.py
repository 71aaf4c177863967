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

import atexit
import multiprocessing as mp
import os
import re
import signal
import sys
import time
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


_REF = re.compile(r"\$(\w+)")
_UNUSED = re.compile(r"^\s*-\s*\$(\w+)=", re.M)


def output_folder(path, option: str) -> Path:
    """Creates the output folder `path` (given as `option`, e.g. "--out out") or raises a RenderError naming
    it and why — before any work is done, not after."""
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RenderError(f"{option}: {folder} exists and is not a folder") from None
    except OSError as e:
        raise RenderError(f"{option}: cannot create the folder {folder} ({e.strerror or e})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise RenderError(f"{option}: the folder {folder} is not writable")
    return folder


def read_scene(scene) -> str:
    """The text of a scene file, or a RenderError naming the file and why it cannot be read."""
    try:
        return Path(scene).read_text()
    except FileNotFoundError:
        raise RenderError(f"scene file not found: {scene}") from None
    except IsADirectoryError:
        raise RenderError(f"the scene is a folder, not a file: {scene}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise RenderError(f"cannot read scene file {scene}: {getattr(e, 'strerror', None) or e}") from None


def scene_parameters(scene, values: dict | None = None):
    """(names the scene reads as ``$name`` with these parameter values — in its file and the files it includes,
    ``include/conductor_$bsdf.xml`` resolved with the values —, its ``<default>`` values). What Mitsuba calls
    an unused parameter is a value passed for a name outside the first set."""
    import xml.etree.ElementTree as ET

    top = Path(scene)
    used, defaults, seen = set(), {}, set()
    try:
        root = ET.parse(top).getroot()
    except (OSError, ET.ParseError):
        return used, defaults
    for el in root.iter("default"):
        if el.get("name"):
            defaults.setdefault(el.get("name"), el.get("value", ""))
    values = {**defaults, **(values or {})}

    def visit(path: Path, root):
        seen.add(path.resolve())
        for el in root.iter():
            for text in el.attrib.values():
                used.update(_REF.findall(text))
            if el.tag == "include" and el.get("filename"):
                name = _REF.sub(lambda m: str(values.get(m.group(1), m.group(0))), el.get("filename"))
                for base in (path.parent, top.parent):
                    target = base / name
                    if target.is_file():
                        if target.resolve() not in seen:
                            try:
                                visit(target, ET.parse(target).getroot())
                            except (OSError, ET.ParseError):
                                pass
                        break

    visit(top, root)
    return used, defaults


def unused_message(scene, params: dict, names) -> str:
    """One line for -D names a scene does not read: each name as typed, a close match (difflib) when there is
    one, and the names the scene reads with these values."""
    import difflib

    used, defaults = scene_parameters(scene, params)
    parts = []
    for name in names:
        typed = f"-D {name}={params[name]}" if name in params else f"-D {name}"
        if name in defaults:
            parts.append(f"{typed}: '{name}' is not used with these values")
            continue
        close = difflib.get_close_matches(name, sorted(used | set(defaults)), n=1)
        parts.append(f"{typed}: unknown parameter '{name}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
    listed = ", ".join(sorted(used)) or "none"
    return f"{Path(scene).name}: {'; '.join(parts)}; the scene's parameters: {listed}"


def load_message(error: BaseException, scene, params: dict) -> str:
    """The one-line message of a failed scene load; unused -D names get unused_message."""
    names = _UNUSED.findall(str(error)) if "unused parameters" in str(error) else []
    if names:
        return unused_message(scene, params, names)
    return one_line(error)


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
            raise RenderError(load_message(e, scene, params)) from None
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


# Signals a worker never acts on: the parent stops the workers itself (SIGKILL), whatever stopped it. A worker
# that reacted would race with that stop: Mitsuba's render installs its own SIGINT handler (even over SIG_IGN)
# that cancels the render and returns the partial image, which the worker then sends as a result.
_WORKER_BLOCKED = {signal.SIGINT, signal.SIGTERM} | ({signal.SIGHUP} if hasattr(signal, "SIGHUP") else set())
_live: set = set()  # worker processes of this (parent) process, for stop_workers()


def _block(signals):
    """Blocks `signals` in this thread; the previous mask (None where signal masks do not exist: Windows)."""
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, signals)


def _die_with_parent():
    """Linux: the kernel kills this worker when its parent dies, however it dies (even SIGKILL)."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass


def _worker_main(conn, workers: int, parent: int):
    """A worker: renders the chunks it receives on `conn` until it gets None or the pipe closes. It starts with
    the signals of _WORKER_BLOCKED blocked (inherited from the parent's mask at spawn), so that neither a
    terminal's Ctrl-C nor a hang-up, which reach the whole process group, nor Mitsuba's own SIGINT handler act
    in it: the parent alone decides when it stops."""
    global _workers
    _workers = workers
    _block(_WORKER_BLOCKED)  # already blocked (inherited); keeps it so if spawned otherwise
    _die_with_parent()
    if os.getppid() != parent:  # the parent died before prctl: nobody will read the results
        return
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        try:
            reply = ("ok", _render_chunk(*task))
        except RenderError as e:
            reply = ("error", str(e))
        except Exception as e:  # noqa: BLE001 - sent to the parent as its one line
            reply = ("error", f"{Path(task[1]).name}: {one_line(e)}")
        try:
            conn.send(reply)
        except (BrokenPipeError, OSError):
            return


class _Workers:
    """Worker processes (spawn), one pipe each, read only by the parent's main thread.

    Not a ProcessPoolExecutor: its results come back through one shared pipe read by a management thread,
    and the parent process itself keeps that pipe's write end open. A worker stopped while writing a result
    (a rendered image is ~1 MB, far more than a pipe holds) left a partial message there; the management
    thread then waited forever for the rest, and the interpreter's exit waited forever for that thread (the
    hang of issue 17: "msx: interrupted" printed, then a futex wait). Here each worker's pipe has one writer,
    the worker: when it dies, the parent's read ends at once (EOFError), and there is no thread to join."""

    def __init__(self, n: int):
        from multiprocessing import resource_tracker

        ctx = mp.get_context("spawn")
        self.procs, self.conns = [], []
        # The resource tracker (started by the first spawn) unblocks SIGINT and SIGTERM when it starts: start
        # it before blocking, so that the workers inherit the blocked mask.
        resource_tracker.ensure_running()
        try:
            old = _block(_WORKER_BLOCKED)
            try:
                for _ in range(n):
                    mine, theirs = ctx.Pipe()
                    p = ctx.Process(target=_worker_main, args=(theirs, n, os.getpid()), daemon=True)
                    try:
                        p.start()
                    finally:
                        theirs.close()  # the worker holds the only write end of its results now
                    self.procs.append(p)
                    self.conns.append(mine)
                    _live.add(p)
            finally:
                if old is not None:  # a signal that came meanwhile is raised here
                    signal.pthread_sigmask(signal.SIG_SETMASK, old)
        except BaseException:
            self.close(kill=True)
            raise

    def exit_code(self, k: int):
        p = self.procs[k]
        p.join(timeout=2.0)
        return p.exitcode

    def close(self, kill: bool):
        """Ends the workers: at once (SIGKILL, running chunks included) or, after a complete run, by asking."""
        if not kill:
            for c in self.conns:
                try:
                    c.send(None)
                except OSError:
                    pass
        for p in self.procs:
            if kill and p.is_alive():
                p.kill()
        for p in self.procs:
            p.join(timeout=None if kill else 10.0)
            if p.is_alive():
                p.kill()
                p.join()
            _live.discard(p)
        for c in self.conns:
            c.close()


def stop_workers():
    """Kills every worker process of this process now (at exit, and for the last-resort exit of cli.py)."""
    for p in list(_live):
        try:
            p.kill()
        except (OSError, ValueError, AttributeError):
            pass


# Runs before multiprocessing's own exit handler (registered earlier, atexit runs last-in first-out), which
# would SIGTERM the workers (blocked in them) and wait for them.
atexit.register(stop_workers)


def with_assets(scene: str, params: dict) -> dict:
    """Generates the assets a scene refers to as `$assets/...` (msx/assets.py): into the scene's own
    `assets/` folder (its default), or, where that is not writable, into the cache (then passed as the
    `assets` parameter)."""
    from . import assets

    path = Path(scene)
    if "$assets" not in read_scene(path):
        return params
    if "assets" in params:
        assets.ensure(params["assets"])
        return params
    try:
        assets.ensure(path.parent / "assets")
        return params
    except OSError:
        from . import _cache

        cache = _cache.folder("assets")
        assets.ensure(cache)
        return dict(params, assets=str(cache))


def _chunks(spp: int, n: int):
    n = max(1, min(n, spp))
    base, extra = divmod(spp, n)
    return [base + (1 if k < extra else 0) for k in range(n)]


def render_chunks(scene: str, tasks, *, variant: str, params: dict, workers: int, on_result):
    """Renders the (seed, spp) `tasks` of `scene`, calling `on_result(chunk)` as each finishes.

    The first failure (scene load, render, a dying worker, Ctrl-C or another signal turned into an exception)
    stops every worker and raises: RenderError, or KeyboardInterrupt."""
    if workers <= 1 or len(tasks) <= 1:
        for seed, spp in tasks:
            on_result(_render_chunk(variant, scene, params, seed, spp))
        return
    from multiprocessing.connection import wait as wait_any

    todo = list(tasks)
    pool = None
    try:
        pool = _Workers(min(workers, len(todo)))
        busy = {}  # pipe index -> its chunk
        for k, conn in enumerate(pool.conns):
            if todo:
                conn.send((variant, scene, params, *todo.pop(0)))
                busy[k] = True
        while busy:
            ready = wait_any([pool.conns[k] for k in busy])
            for conn in ready:
                k = pool.conns.index(conn)
                try:
                    kind, value = conn.recv()
                except (EOFError, OSError):  # the worker died (mid-message or idle): its pipe closed
                    code = pool.exit_code(k)
                    how = f" (exit code {code})" if code not in (None, 0) else ""
                    raise RenderError(f"{Path(scene).name}: a render worker process died{how}") from None
                if kind == "error":
                    raise RenderError(value)
                on_result(value)
                if todo:
                    conn.send((variant, scene, params, *todo.pop(0)))
                else:
                    del busy[k]
    except BaseException:
        if pool is not None:
            pool.close(kill=True)
        raise
    pool.close(kill=False)


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
    used, defaults = scene_parameters(scene, params)
    if spp is None:
        text = params.get("spp", defaults.get("spp", "16"))
        try:
            spp = int(text)
        except ValueError:
            raise RenderError(f"spp must be an integer ≥ 1 (got -D spp={text})" if "spp" in params else
                              f"{Path(scene).name}: its default spp is not an integer ({text!r}); pass --spp") from None
    if spp < 1:
        raise RenderError(f"spp must be ≥ 1 (got {spp})")
    if "spp" in used:  # the scene's own sample count (mi.render is also given spp); a scene without $spp
        params["spp"] = str(spp)  # would reject it as an unused parameter
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
            return str(shipped_scene(scene))
        except RenderError:
            names = shipped_scenes()
            hint = "; shipped scenes: " + ", ".join(names) if names else ""
    raise RenderError(f"scene file not found: {scene}{hint}")


def shipped_scenes() -> list:
    """File names of the shipped scenes (none if the scene files are missing)."""
    try:
        return sorted(p.name for p in scenes_dir().glob("*.xml"))
    except RenderError:
        return []


def shipped_scene(name) -> Path:
    """The shipped scene `name` (a file name; ``.xml`` may be left out), or a RenderError naming the shipped
    scenes."""
    name = str(name)
    if os.path.dirname(name) == "" and name not in ("", ".", ".."):
        folder = scenes_dir()
        for candidate in (name, name + ".xml"):
            if (folder / candidate).is_file():
                return folder / candidate
    raise RenderError(f"no shipped scene {name!r}; shipped scenes: {', '.join(shipped_scenes())}")


def scenes_dir() -> Path:
    """The scene files: shipped inside the installed package (``msx/scenes``),
    or the repository's ``scenes/`` when running from a checkout (editable install)."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "scenes", here.parent.parent / "scenes"):
        if (candidate / "fig09_copper_sphere.xml").exists():
            return candidate
    raise RenderError("the scene files were not found (neither in the installed package nor in a checkout); "
                      "pass --scenes DIR")
