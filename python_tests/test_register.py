"""msx.register()'s failures: one line naming what was typed and the alternatives; the native back end's
platform check and self-check (a slip in the plugin's dielectric or diffuse fields is caught before use)."""

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(code, env=None, timeout=300):
    full = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=full)


def _failure(call, variant="scalar_rgb", env=None):
    """(exception type, message) of `call` in a new process (register's state is per process)."""
    code = ("import mitsuba as mi, msx\n"
            + (f"mi.set_variant({variant!r})\n" if variant else "")
            + f"try:\n    {call}\nexcept Exception as e:\n    print(type(e).__name__)\n    print(e)\n"
            "else:\n    print('no error')\n")
    r = _run(code, env)
    assert r.returncode == 0, r.stderr
    kind, _, message = r.stdout.partition("\n")
    return kind, message.strip()


@pytest.mark.parametrize("call, variant, env, kind, words", [
    ("msx.register()", None, None, "RuntimeError",
     ["msx.register(): no Mitsuba variant is set", "mi.set_variant", "scalar_rgb", "llvm_ad_rgb"]),
    ("msx.register(backend='nativ')", "scalar_rgb", None, "ValueError",
     ["backend='nativ'", "did you mean 'native'", "auto, native, python, jit, batched"]),
    ("msx.register(backend=3)", "scalar_rgb", None, "ValueError", ["backend=3", "auto, native, python, jit, batched"]),
    ("msx.register()", "scalar_rgb", {"MSX_BACKEND": "pyton"}, "ValueError",
     ["MSX_BACKEND='pyton'", "did you mean 'python'", "auto, native, python, jit, batched"]),
    ("msx.register(backend='jit')", "scalar_rgb", None, "RuntimeError",
     ["backend='jit'", "vectorized variants", "use 'native' or 'python'"]),
    ("msx.register(backend='native')", "llvm_ad_rgb", None, "RuntimeError",
     ["backend='native'", "scalar variants", "'jit'", "'batched'"]),
    ("msx.register()", "scalar_spectral_polarized", None, "NotImplementedError",
     ["'scalar_spectral_polarized' is polarized", "scalar_rgb", "scalar_spectral"]),
    ("msx.register(backend='native')", "scalar_rgb", {"MSX_CACHE_DIR": "/proc/msx-cannot-write-here"}, "RuntimeError",
     ["backend='native'", "cannot write the native build into /proc/msx-cannot-write-here", "MSX_CACHE_DIR",
      "backend='python'"]),
])
def test_every_failure_is_one_line_naming_the_input_and_the_alternatives(call, variant, env, kind, words):
    import mitsuba as mi

    if variant and variant not in mi.variants():
        pytest.skip(f"{variant} is not installed")
    if variant and variant.startswith("llvm") and "DRJIT_LIBLLVM_PATH" not in os.environ:
        env = dict(env or {}, DRJIT_LIBLLVM_PATH="/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
    got, message = _failure(call, variant, env)
    assert got == kind, message
    assert "\n" not in message and all(w in message for w in words), message


def test_a_compile_failure_is_one_line_with_the_compilers_error(tmp_path):
    cxx = tmp_path / "refusing-c++"
    cxx.write_text("#!/bin/sh\necho 'In file included from x.h:1,' >&2\n"
                   "echo 'msx_mitsuba.cpp:12: error: this compiler refuses' >&2\nexit 1\n")
    cxx.chmod(cxx.stat().st_mode | stat.S_IXUSR)
    env = {"CXX": str(cxx), "MSX_CACHE_DIR": str(tmp_path / "cache")}
    for attempt in ("first", "remembered"):
        kind, message = _failure("msx.register(backend='native')", env=env)
        assert kind == "RuntimeError" and "\n" not in message, message
        assert "compiling the native plugin failed" in message and "this compiler refuses" in message
        assert "backend='python'" in message
        assert ("remembered" in message) == (attempt == "remembered")
    # The default falls back, saying why in one line.
    r = _run("import mitsuba as mi, msx\nmi.set_variant('scalar_rgb')\nmsx.register()\nprint(msx.backend())", env)
    warning = [ln for ln in r.stderr.splitlines() if "native back end is unavailable" in ln]
    assert r.stdout.strip() == "python" and len(warning) == 1 and "this compiler refuses" in warning[0], r.stderr


@pytest.mark.parametrize("platform", ["darwin", "win32"])
def test_outside_linux_the_python_back_end_is_used_saying_why(tmp_path, platform):
    """The platform is checked before anything POSIX-only (fcntl) is imported: msx.register() falls back."""
    code = (f"import sys\nsys.modules['fcntl'] = None\nimport mitsuba as mi, msx\nsys.platform = {platform!r}\n"
            "mi.set_variant('scalar_rgb')\nmsx.register()\nprint(msx.backend())\n"
            "try:\n    msx.register(backend='native')\nexcept RuntimeError as e:\n    print(e)\n")
    r = _run(code, {"MSX_CACHE_DIR": str(tmp_path / "cache")})
    assert r.returncode == 0, r.stderr
    backend, refusal = r.stdout.strip().splitlines()
    assert backend == "python"
    assert f"built on Linux only (tested on x86-64); this is {platform}" in refusal
    assert f"this is {platform}); using the Python back end" in r.stderr
    assert not (tmp_path / "cache").exists()  # nothing was attempted


# ---------------------------------------------------------------- the self-check

SOURCE = ROOT / "native" / "msx_mitsuba.cpp"
# Slips the self-check must catch: (what, the source line, its mutant, words of the refusal).
SLIPS = [
    ("refraction's component", "            bs.sampled_component = 1;", "            bs.sampled_component = 0;",
     "refract) component"),
    ("eta from inside", "            bs.eta = si.wi.z() > 0.f ? m_ior : 1.f / m_ior;", "            bs.eta = m_ior;",
     "refract from inside) eta"),
    ("transmission weight", "        return { bs, spectrum(r.weight) };",
     "        return { bs, transmit ? spectrum(r.weight) * 0.5f : spectrum(r.weight) };", "refract) weight"),
    ("diffuse albedo", "            put(m.reflectance, m_reflectance->eval(si, true));",
     "            (void) 0;  // the albedo left at 1", "diffuse correlated eval"),
]


@pytest.mark.parametrize("what, line, mutant, words", SLIPS, ids=[s[0] for s in SLIPS])
def test_the_self_check_catches_a_slip(tmp_path, what, line, mutant, words):
    """A plugin with one slip (compiled here, a few seconds each) is refused by the self-check, naming it."""
    from msx.plugin import native as nb

    src, hdr = nb._sources()
    text = src.read_text()
    assert text.count(line + "\n") == 1, f"the line to mutate is gone: {line}"
    bad = tmp_path / "msx_mitsuba.cpp"
    bad.write_text(text.replace(line + "\n", mutant + "\n"))
    code = ("import sys\nfrom pathlib import Path\nimport mitsuba as mi\nmi.set_variant('scalar_rgb')\n"
            "from msx.plugin import native as nb\n"
            f"nb._sources = lambda: (Path({str(bad)!r}), Path({str(hdr)!r}))\n"
            "try:\n    nb.make_factory(mi)\nexcept nb.NativeUnavailable as e:\n    print('refused:', e)\n"
            "else:\n    print('accepted')\n")
    r = _run(code, {"MSX_CACHE_DIR": str(tmp_path / "cache")})
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("refused: the native build fails its self-check") and words in r.stdout, r.stdout
