"""Command line: ``msx render SCENE.xml``, ``msx compare``, ``msx simulate``
(ray tracing on generated microgeometry, msx/microgeometry/), ``msx assets`` and ``msx cache [--clear]``.

Errors end the run with one line on stderr naming the problem (exit code 1;
``--verbose`` adds the traceback). Ctrl-C (SIGINT), SIGTERM and a closed terminal (SIGHUP) stop every
worker and end the run with one line and exit code 128 + the signal's number (130 for Ctrl-C).

A signal's Python handler runs only when the main thread runs Python: inside a long native call (a scene
load, an in-process render that a SIGTERM does not cancel, a long Rust call of ``msx compare``) it would
wait for the call to return. A watcher thread (woken through ``signal.set_wakeup_fd``) bounds that: if the
run has not ended ``MSX_STOP_GRACE`` seconds (default 1; ``inf``: never) after the signal, it kills the
workers, prints the same line with the reason, and exits with the same code.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import socket
import sys
import threading
import time
import traceback
from pathlib import Path

from ._render import (DEFAULT_VARIANT, RenderError, one_line, output_folder, render_scene, resolve_scene,
                      write_image)

__all__ = ["main", "render_scene", "write_image"]


class UsageError(Exception):
    """Bad command-line input; the message is one line."""


class Stopped(KeyboardInterrupt):
    """SIGTERM or SIGHUP as an exception: the run unwinds (workers stopped) as on Ctrl-C."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


_STOP_SIGNALS = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated (SIGTERM)"}
if hasattr(signal, "SIGHUP"):
    _STOP_SIGNALS[signal.SIGHUP] = "hang-up (SIGHUP: the terminal closed)"


_received = []  # the stop signals received in this process (stop_received)


def stop_received() -> bool:
    """True once a stop signal arrived: code that catches errors to go on (``msx compare SCENE.xml``, one
    material at a time) must not swallow a stop that came back wrapped in Mitsuba's or Dr.Jit's error."""
    return bool(_received)


def _say(line: str):
    """One line on stderr; a closed terminal (after SIGHUP) is not an error."""
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def _grace() -> float:
    text = os.environ.get("MSX_STOP_GRACE", "1")
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value >= 0:
        raise UsageError(f"MSX_STOP_GRACE must be a number of seconds ≥ 0 or inf (got {text!r})")
    return value


class _StopSignals:
    """While the command runs: SIGTERM and SIGHUP raise Stopped in the main thread, and a watcher thread ends
    the process if a stop signal has not ended the run within the grace time (see the module's docstring)."""

    def __init__(self):
        self.active = threading.current_thread() is threading.main_thread()
        self.lock = threading.Lock()
        self.reported = False
        self.signum = None  # the first stop signal received
        self.old = {}  # the handlers replaced (none outside the main thread, where signals cannot be handled)

    def __enter__(self):
        if not self.active:
            return self
        self.grace = _grace()
        # A signal ignored by whoever started msx stays ignored: `nohup msx compare &` must survive the
        # terminal's SIGHUP, and a shell's background job its Ctrl-C.
        self.old = {sig: signal.getsignal(sig) for sig in _STOP_SIGNALS
                    if signal.getsignal(sig) is not signal.SIG_IGN}
        for sig in self.old:
            signal.signal(sig, self._raise)
        self.old_hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        self.reader, self.writer = socket.socketpair()
        self.writer.setblocking(False)
        self.old_fd = signal.set_wakeup_fd(self.writer.fileno(), warn_on_full_buffer=False)
        threading.Thread(target=self._watch, name="msx-stop-watch", daemon=True).start()
        return self

    def __exit__(self, *exc):
        if not self.active:
            return False
        self.report_done()
        sys.unraisablehook = self.old_hook
        signal.set_wakeup_fd(self.old_fd)
        for sig, handler in self.old.items():
            signal.signal(sig, handler)
        self.writer.close()  # ends the watcher
        return False

    def _raise(self, signum, frame):
        """Remembers the signal (an exception raised in a callback from native code, e.g. a plugin
        constructor called by Mitsuba's scene loader, may come back wrapped in another one) and raises
        KeyboardInterrupt (SIGINT) or Stopped."""
        if self.signum is None:
            self.signum = signum
        _received.append(signum)
        raise KeyboardInterrupt if signum == signal.SIGINT else Stopped(signum)

    def _unraisable(self, info):
        """The stop's exception, raised where Python cannot propagate it (a __del__ or a gc callback that ran in
        the main thread when the signal's handler did), would be printed and lost, and the run would go on:
        the signal is delivered again instead, to be handled once the main thread is out of there."""
        if self.signum is not None and isinstance(info.exc_value, KeyboardInterrupt) and not self.reported:
            main, sig = threading.main_thread().ident, self.signum
            # Later and from another thread: here, the handler would run at once and be lost again.
            threading.Timer(0.05, self._deliver, (main, sig)).start()
            return
        self.old_hook(info)

    def _deliver(self, thread, sig):
        with self.lock:
            if not self.reported:
                signal.pthread_kill(thread, sig)

    def stop_signal(self, error: BaseException):
        """The stop signal behind `error`, if any: its own, or one received while it unwound."""
        if isinstance(error, SystemExit):
            return None
        sig = getattr(error, "signum", None) or self.signum
        if sig is None and isinstance(error, KeyboardInterrupt):
            sig = signal.SIGINT
        return sig

    def report_done(self):
        """The main thread has reported (or finished): the watcher must not."""
        with self.lock:
            self.reported = True

    def _watch(self):
        """Reads the wakeup fd until __exit__ closes it (closing it earlier would make Python print an error on
        each later signal); the first stop signal arms the last-resort exit."""
        armed = False
        try:
            while True:
                data = self.reader.recv(64)
                if not data:
                    return
                sigs = [b for b in data if b in _STOP_SIGNALS]
                if sigs and not armed and math.isfinite(self.grace):
                    armed = True
                    threading.Thread(target=self._force_exit, args=(sigs[0],), daemon=True).start()
        finally:
            self.reader.close()

    def _force_exit(self, sig):
        time.sleep(self.grace)
        with self.lock:
            if self.reported:
                return
            from ._render import stop_workers

            stop_workers()
            _say(f"\nmsx: {_STOP_SIGNALS[sig]} (ended {self.grace:g} s later: a native call did not return)")
            os._exit(128 + sig)


def _parse_defines(items):
    params = {}
    for item in items or []:
        if "=" not in item:
            raise UsageError(f"-D expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        params[k] = v
    return params


def _positive(name):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer ≥ 1 (got {text!r})") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"{name} must be an integer ≥ 1 (got {value})")
        return value

    return parse


def cmd_render(args):
    params = _parse_defines(args.define)
    out = Path(args.output or Path(args.scene).with_suffix("").name + ".exr")
    output_folder(out.parent, f"-o {out}")  # before the render, not after it
    if args.variant == "auto":
        from ._variants import fastest_variant

        resolve_scene(args.scene)  # a missing scene is named before the route is probed

        args.variant, why = fastest_variant()
        print(f"msx: rendering with {args.variant} ({why})", file=sys.stderr)
    # Worker processes serve the scalar variants; a vectorized one uses every core in this process.
    workers = args.workers if args.variant.startswith("scalar") else 1
    try:
        img, _, wall = render_scene(args.scene, variant=args.variant, spp=args.spp, params=params,
                                    workers=workers, seed=args.seed)
    except RenderError as e:
        if not (args.variant.startswith("llvm") and "msx.register(backend='batched')" in str(e)):
            raise
        # A configuration the Dr.Jit engine does not run: the native back end runs everything.
        print(f"msx: {e}; rendering with scalar_rgb (the native back end) instead", file=sys.stderr)
        args.variant = "scalar_rgb"
        img, _, wall = render_scene(args.scene, variant=args.variant, spp=args.spp, params=params,
                                    workers=args.workers, seed=args.seed)
    try:
        write_image(out, img, args.variant)
    except (OSError, RuntimeError) as e:
        raise RenderError(f"-o {out}: cannot write the image ({one_line(e)})") from None
    where = out.resolve()  # the full path: without -o the image goes to the current directory
    print(f"wrote {where.with_suffix('.exr')} and {where.with_suffix('.png')} ({wall:.1f} s)")


def cmd_compare(args):
    if args.scene is not None:
        if args.scenes:
            raise UsageError("--scenes is for the papers' scenes; with SCENE.xml leave it out")
        from .evaluation import scene_advice

        scene_advice.run(args)
        return
    given = [o for o, v in (("-D", args.define), ("--write-scene", args.write_scene), ("--material", args.material))
             if v]
    if given:
        raise UsageError(f"{', '.join(given)}: only with a scene (msx compare SCENE.xml …)")
    from .evaluation import driver as compare

    compare.run(args)


def cmd_assets(args):
    from . import assets

    from ._render import scenes_dir

    target = args.folder or scenes_dir() / "assets"  # where the shipped scenes look ($assets = "assets")
    folder = assets.ensure(output_folder(target, f"msx assets {target}"))
    print(f"assets in {folder}: {', '.join(assets.FILES)}")


def cmd_cache(args):
    from . import _cache

    if not args.clear:
        print(_cache.describe())
        return
    try:
        deleted, kept = _cache.clear()
    except OSError as e:
        raise RenderError(f"msx cache --clear: cannot delete {e.filename or _cache.root()} "
                          f"({e.strerror or e})") from None
    if not deleted:
        print(f"msx cache: nothing to delete in {_cache.root()}")
    for path, n, size in deleted:
        print(f"deleted {path} ({n} entr{'y' if n == 1 else 'ies'}, {_cache._human(size)})")
    for path in kept:
        print(f"left {path} (not made by msx)")


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (argparse prints its usage first, several lines for msx simulate)."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser():
    workers = os.cpu_count() or 1
    common = argparse.ArgumentParser(add_help=False)
    # Subcommands accept -v too; SUPPRESS keeps a top-level `msx -v render …` from being reset.
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    p = _Parser(prog="msx", description="Multiple-scattering microfacet BSDFs for Mitsuba 3")
    p.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on errors")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render one scene", parents=[common])
    r.add_argument("scene")
    r.add_argument("-o", "--output", help="output path (.exr; a .png is written beside it)")
    r.add_argument("--spp", type=_positive("--spp"), default=None, help="samples per pixel (default: the scene's)")
    r.add_argument("--variant", default="auto",
                   help="Mitsuba variant (default 'auto': the fastest route here, said on stderr — llvm_ad_rgb "
                        "with the Dr.Jit engine where Mitsuba's LLVM variant works (one process, every core), "
                        f"else {DEFAULT_VARIANT} with the native back end, which also renders what the engine "
                        "does not run)")
    r.add_argument("--workers", type=_positive("--workers"), default=workers,
                   help="worker processes of the scalar variants (default: one per core)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("-D", "--define", action="append", help="scene parameter key=value (XML <default>)")
    r.set_defaults(func=cmd_render)

    c = sub.add_parser("compare", help="render the paper comparisons side by side with Mitsuba's built-ins; with "
                                       "SCENE.xml: which model each material of that scene needs",
                       parents=[common])
    c.add_argument("scene", nargs="?", default=None,
                   help="a Mitsuba scene (a path, or a shipped scene by name): per material msx can stand in for, "
                        "does multiple scattering change the image and which model is the cheapest that looks right "
                        "(docs/evaluation.md)")
    c.add_argument("-D", "--define", action="append", help="scene parameter key=value (XML <default>), with SCENE")
    c.add_argument("--write-scene", default=None, metavar="OUT.xml",
                   help="with SCENE: write the scene with each material set to its recommended model")
    c.add_argument("--material", action="append", default=None, metavar="KEY",
                   help="with SCENE: evaluate only this material (its id as the report names it; repeatable)")
    c.add_argument("--quick", action="store_true", help="small settings: a first look in a few minutes (CI)")
    c.add_argument("--scenes", default=None, help="folder with the scene XMLs (default: the installed scenes)")
    c.add_argument("--out", default="out", help="report folder (index.html, CSVs, PNGs)")
    c.add_argument("--variant", default=None,
                   help="Mitsuba variant (default: the fastest route here: llvm_ad_rgb with the Dr.Jit engine where "
                        "Mitsuba's LLVM variant works, rendering what the engine does not run in scalar_rgb with the "
                        "native back end; else scalar_rgb native, else scalar_rgb with the Python back end)")
    c.add_argument("--cache", default=None, help="folder of cached reference renders (default: references/ in msx's "
                                                 "cache folder, see msx cache)")
    c.set_defaults(func=cmd_compare)

    a = sub.add_parser("assets", help="write the generated scene assets (sky, sculpted mesh, normal map)",
                       parents=[common])
    a.add_argument("folder", nargs="?", default=None,
                   help="default: the shipped scenes' assets folder (where they look for them)")
    a.set_defaults(func=cmd_assets)

    k = sub.add_parser("cache", help="show msx's cache folder and its size per kind; --clear deletes it",
                       parents=[common])
    k.add_argument("--clear", action="store_true", help="delete the cache (everything in it is recomputed on use)")
    k.set_defaults(func=cmd_cache)

    from .microgeometry.cli import add_simulate_parser

    add_simulate_parser(sub, parents=[common])
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    verbose = getattr(args, "verbose", False)
    try:
        with _StopSignals() as stop:
            try:
                args.func(args)
            except BaseException as e:
                sig = stop.stop_signal(e)
                if sig is None:
                    raise
                for other in stop.old:  # a second Ctrl-C must not interrupt the report
                    signal.signal(other, signal.SIG_IGN)
                stop.report_done()
                _say(f"\nmsx: {_STOP_SIGNALS.get(sig, 'interrupted')}")
                return 128 + sig
    except (RenderError, UsageError) as e:
        if verbose:
            traceback.print_exc()
        print(f"msx: error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # unexpected: still one line unless --verbose
        if verbose:
            traceback.print_exc()
        print(f"msx: error: {one_line(e)} (run with --verbose for the traceback)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
