"""Mitsuba 3.9.1 deadlocks reading or writing an OpenEXR file while Dr.Jit's thread pool has a single thread,
which is how the scalar Python back end renders. The places where msx touches EXRs guard against it:
`msx render`'s output image and the generated scene assets (msx/assets.py). Each check runs in a subprocess
with a timeout, since a deadlock cannot be interrupted in-process."""

import os
import subprocess
import sys
from pathlib import Path

SCENES = Path(__file__).resolve().parent.parent / "scenes"


def run(args, env=None, timeout=240):
    return subprocess.run([sys.executable] + args, capture_output=True, text=True, timeout=timeout,
                          env=dict(os.environ, **(env or {})))


def test_render_writes_its_exr_with_one_thread(tmp_path):
    """The Python back end with one worker renders in-process with one Dr.Jit thread."""
    out = tmp_path / "fig07"
    r = run(["-m", "msx", "render", str(SCENES / "fig07_normalmap.xml"), "--spp", "1", "--workers", "1",
             "--variant", "scalar_rgb", "-D", "width=16", "-D", "height=16", "-D", f"assets={tmp_path / 'assets'}", "-o", str(out)],
            env={"MSX_BACKEND": "python"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.with_suffix(".exr").stat().st_size > 0 and out.with_suffix(".png").stat().st_size > 0


def test_assets_are_written_with_one_thread(tmp_path):
    code = ("import drjit as dr, mitsuba as mi\n"
            "mi.set_variant('scalar_rgb'); dr.set_thread_count(1)\n"
            "import msx.assets as a\n"
            f"a.ensure({str(tmp_path)!r})\n"
            "assert dr.thread_count() == 1\n"
            "print('ok')\n")
    r = run(["-c", code])
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr[-2000:]
    assets = ["blob.ply", "normalmap.exr", "sky.exr"]
    # Each asset with its checksum record beside it (msx/_cache.py), nothing else.
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(assets + [f".{a}.msx" for a in assets])
