"""The native back end's build cache: a failed compile is remembered with its reason (the render workers do
not each retry it) until its inputs change or its folder is deleted; outside POSIX the fallback can say why."""

import os
import shutil
import stat
import subprocess
import sys

import pytest

from msx.plugin import native as nb

REMEMBERED = "remembered from an earlier build"


@pytest.fixture
def failing_compiler(tmp_path, monkeypatch):
    """CXX: a compiler that refuses, counting its runs; an empty cache folder."""
    calls = tmp_path / "calls"
    cxx = tmp_path / "refusing-c++"
    cxx.write_text(f"#!/bin/sh\necho run >> '{calls}'\necho 'msx_mitsuba.cpp:1: error: this compiler refuses' >&2\n"
                   "exit 1\n")
    cxx.chmod(cxx.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("CXX", str(cxx))
    monkeypatch.setenv("MSX_CACHE_DIR", str(tmp_path / "cache"))
    return lambda: len(calls.read_text().split()) if calls.exists() else 0


def _build_error():
    with pytest.raises(nb.NativeUnavailable) as e:
        nb.build()
    return str(e.value)


def test_a_failed_build_is_remembered_until_its_folder_goes(failing_compiler, tmp_path):
    first = _build_error()
    assert "this compiler refuses" in first and REMEMBERED not in first and failing_compiler() == 1
    again = _build_error()
    assert "this compiler refuses" in again and REMEMBERED in again and failing_compiler() == 1
    # A worker process (same inputs) does not compile either.
    code = ("from msx.plugin import native as nb\ntry:\n    nb.build()\nexcept nb.NativeUnavailable as e:\n"
            "    print(e)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=os.environ)
    assert REMEMBERED in r.stdout and failing_compiler() == 1, r.stdout + r.stderr
    [folder] = (tmp_path / "cache" / "native").iterdir()
    assert not list(folder.glob("*.so")), "a failed build left its partial output"
    shutil.rmtree(folder)
    assert REMEMBERED not in _build_error() and failing_compiler() == 2


def test_a_compiler_stopped_by_a_signal_is_not_remembered(tmp_path, monkeypatch):
    cxx = tmp_path / "killed-c++"
    cxx.write_text("#!/bin/sh\nkill -KILL $$\n")
    cxx.chmod(cxx.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("CXX", str(cxx))
    monkeypatch.setenv("MSX_CACHE_DIR", str(tmp_path / "cache"))
    _build_error()
    assert REMEMBERED not in _build_error()  # not the inputs' fault: tried again


def test_without_fcntl_the_fallback_says_why(tmp_path):
    """fcntl does not exist on Windows: importing the back end must still work and build() say why."""
    code = ("import sys\nsys.modules['fcntl'] = None\nfrom msx.plugin import native as nb\ntry:\n    nb.build()\n"
            "except nb.NativeUnavailable as e:\n    print('unavailable:', e)\n")
    env = dict(os.environ, MSX_CACHE_DIR=str(tmp_path / "cache"))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith("unavailable: the native back end needs a POSIX system"), r.stdout
