"""Whether Mitsuba's llvm_ad_rgb variant works in this process (shared by the
test modules that render or run mitsuba.chi2 in LLVM; python_tests/test_llvm.py
keeps its own copy of the same logic).

Import this module before drjit initialises its LLVM backend: it points
DRJIT_LIBLLVM_PATH at libLLVM 19 when that file exists and the variable is
unset (Debian's default libLLVM 15 crashes drjit, docs/mitsuba.md).
"""

import os
import subprocess
import sys

LLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM19):
    os.environ["DRJIT_LIBLLVM_PATH"] = LLVM19

_PROBE = (
    "import mitsuba as mi, drjit as dr\n"
    "mi.set_variant('llvm_ad_rgb')\n"
    "x = dr.maximum(mi.Float([1.0, 2.0]), mi.Float([2.0, 1.0])) * 2\n"
    "assert x.numpy().tolist() == [4.0, 4.0]\n"
    "print('ok')\n"
)

_REASON = []


def llvm_unusable_reason():
    """None if llvm_ad_rgb works here, else why not (probed once, first in a
    subprocess since a bad libLLVM can crash the process)."""
    if _REASON:
        return _REASON[0]
    import drjit as dr
    import mitsuba as mi

    reason = None
    if "llvm_ad_rgb" not in mi.variants():
        reason = "this Mitsuba build has no llvm_ad_rgb variant"
    else:
        try:
            r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
            if r.returncode != 0 or "ok" not in r.stdout:
                reason = ("llvm_ad_rgb unusable (needs libLLVM >= 19: apt-get install libllvm19 and set "
                          "DRJIT_LIBLLVM_PATH=%s): %s" % (LLVM19, (r.stderr or r.stdout).strip().splitlines()[-1:]))
        except Exception as e:  # pragma: no cover
            reason = "LLVM probe failed: %s" % e
        if reason is None:
            previous = mi.variant()
            try:
                mi.set_variant("llvm_ad_rgb")
                x = mi.Float([1.0, 2.0]) + 1
                dr.eval(x)
            except Exception as e:
                reason = ("llvm_ad_rgb cannot be set in this process (LLVM initialised before "
                          "DRJIT_LIBLLVM_PATH?): %s" % e)
            finally:
                if previous:
                    mi.set_variant(previous)
    _REASON.append(reason)
    return reason


def drjit_default_mode():
    """Context manager for the Dr.Jit engine's test modules: drjit's default symbolic loops and calls (the
    mode users render in) while the module runs, the previous flags afterwards. The batched route's tests
    turn both flags off for the rest of the process (that route's documented side effect), so a module that
    runs after them would otherwise test the engine in evaluated mode."""
    import contextlib

    import drjit as dr

    @contextlib.contextmanager
    def mode():
        flags = (dr.JitFlag.SymbolicLoops, dr.JitFlag.SymbolicCalls)
        saved = [dr.flag(f) for f in flags]
        for f in flags:
            dr.set_flag(f, True)
        try:
            yield
        finally:
            for f, v in zip(flags, saved):
                dr.set_flag(f, v)

    return mode()
