"""Which Mitsuba variant renders fastest here, for ``msx render`` (``--variant auto``).

The Dr.Jit engine in ``llvm_ad_rgb`` renders several times faster than the native back end in
``scalar_rgb`` (benches/README.md), when Mitsuba's LLVM variant works on this machine: it needs libLLVM ≥ 19
(Debian 12's default libLLVM 15 crashes drjit), found through ``DRJIT_LIBLLVM_PATH``. Whether it works is
probed once, in a subprocess (a bad libLLVM can abort the process that loads it), before this process
initialises drjit's LLVM backend.
"""

from __future__ import annotations

import os
import subprocess
import sys

LLVM_VARIANT = "llvm_ad_rgb"
SCALAR_VARIANT = "scalar_rgb"
# Debian's libLLVM 19 (apt-get install libllvm19).
LIBLLVM19 = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"

_PROBE = (
    "import drjit as dr, mitsuba as mi\n"
    "mi.set_variant('llvm_ad_rgb')\n"
    "x = dr.maximum(mi.Float([1.0, 2.0]), mi.Float([2.0, 1.0])) * 2\n"
    "assert x.numpy().tolist() == [4.0, 4.0]\n"
    "print('ok')\n"
)

_probed: dict = {}


def llvm_problem() -> str | None:
    """None when ``llvm_ad_rgb`` works here, else why not (one line). Points ``DRJIT_LIBLLVM_PATH`` at
    libLLVM 19 when that file exists and the variable is unset."""
    if "problem" in _probed:
        return _probed["problem"]
    if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LIBLLVM19):
        os.environ["DRJIT_LIBLLVM_PATH"] = LIBLLVM19
    problem = None
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300)
        if r.returncode != 0 or "ok" not in r.stdout:
            last = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["no output"]
            problem = f"Mitsuba's {LLVM_VARIANT} does not run here (it needs libLLVM >= 19: {last[0][:160]})"
    except (OSError, subprocess.SubprocessError) as e:
        problem = f"could not probe {LLVM_VARIANT} ({e})"
    _probed["problem"] = problem
    return problem


def fastest_variant() -> tuple[str, str]:
    """(variant, why): ``llvm_ad_rgb`` with the Dr.Jit engine where it works, else ``scalar_rgb``."""
    problem = llvm_problem()
    if problem is None:
        return LLVM_VARIANT, "the Dr.Jit engine"
    return SCALAR_VARIANT, f"the native back end; {problem}"
