"""The command line ends every failure quickly with one clear line: bad scene
parameters (with one or several worker processes), a worker that dies, and
Ctrl-C. Each case runs `python -m msx` as a user would."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(ROOT / "scenes" / "fig09_copper_sphere.xml")
DEADLINE = 5.0  # seconds a bad input may take to end the run
STOP_DEADLINE = 15.0  # seconds for a dying worker or Ctrl-C to end a running render (generous under load)


@pytest.fixture(scope="module", autouse=True)
def native_plugin_built():
    """The first scene load of a fresh install compiles the native plugin once (several seconds, announced
    on stderr, then cached): done here, so that the deadlines below time the failure paths themselves."""
    code = "import mitsuba as mi; mi.set_variant('scalar_rgb'); import msx; msx.register()"
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)


def msx(*args, timeout=60, **kw):
    return subprocess.run([sys.executable, "-m", "msx", *args], capture_output=True, text=True, timeout=timeout, **kw)


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("define, names", [
    ("model=invariant", "'model'"),
    ("alpha=-1", "'alpha'"),
    ("alpha=nan", "'alpha'"),
])
def test_bad_parameter_ends_fast_with_one_line(tmp_path, workers, define, names):
    t0 = time.perf_counter()
    r = msx("render", SCENE, "-D", define, "--workers", str(workers), "--spp", "8", "-o", str(tmp_path / "x.exr"),
            timeout=60)
    took = time.perf_counter() - t0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    print(f"\n[{define}, workers {workers}] exit {r.returncode} in {took:.2f} s: {lines}")
    assert r.returncode == 1
    assert took < DEADLINE
    assert len(lines) == 1 and lines[0].startswith("msx: error: ")
    assert names in lines[0] and "Traceback" not in r.stderr
    assert not (tmp_path / "x.exr").exists()


def test_verbose_shows_the_traceback(tmp_path):
    r = msx("render", SCENE, "-D", "model=invariant", "--workers", "1", "--verbose", "-o", str(tmp_path / "x.exr"))
    assert r.returncode == 1
    assert "Traceback" in r.stderr and r.stderr.strip().splitlines()[-1].startswith("msx: error: ")


def test_dielectric_equal_iors_are_named():
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    import msx as msx_pkg

    msx_pkg.register()
    with pytest.raises(Exception) as e:
        mi.load_dict({"type": "msx_posfree", "surface": "dielectric", "int_ior": 1.5, "ext_ior": 1.5})
    last = str(e.value).strip().splitlines()[-1]
    assert "'int_ior'" in last and "'ext_ior'" in last and "differ" in last
    assert "> 0" not in last  # the values are valid IORs: the message must not say otherwise


def test_missing_scene_and_bad_spp(tmp_path):
    r = msx("render", str(tmp_path / "nope.xml"))
    assert r.returncode == 1 and r.stderr.strip() == f"msx: error: scene file not found: {tmp_path / 'nope.xml'}"
    r = msx("render", SCENE, "--spp", "0")
    assert r.returncode != 0 and "--spp" in r.stderr and "Traceback" not in r.stderr


def test_a_shipped_scene_renders_by_name(tmp_path):
    """`msx render fig09_copper_sphere.xml` finds the shipped scene from any directory; an unknown bare name
    lists the shipped ones."""
    r = msx("render", "fig09_copper_sphere.xml", "--spp", "1", "--workers", "1", "-o", str(tmp_path / "x.exr"),
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "x.exr").exists()
    r = msx("render", "nope.xml", "--workers", "1", cwd=tmp_path)
    assert r.returncode == 1 and "shipped scenes: " in r.stderr and "fig09_copper_sphere.xml" in r.stderr


def _children(pid):
    """Worker processes of `pid` (multiprocessing spawn children, not its resource tracker)."""
    out = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            try:
                cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except FileNotFoundError:
                continue
            if "spawn_main" in cmd:
                out.append(int(child))
    return out


def _start_long_render(tmp_path):
    """A render with two workers that runs for a while; returns the process once both workers exist."""
    p = subprocess.Popen([sys.executable, "-m", "msx", "render", SCENE, "--workers", "2", "--spp", "100000",
                          "-o", str(tmp_path / "x.exr")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 30:
        kids = _children(p.pid)
        if len(kids) >= 2:
            time.sleep(1.0)  # let them load the scene and start rendering
            return p, kids
        time.sleep(0.1)
    p.kill()
    pytest.fail("the render did not start two workers in 30 s")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (exited, not reaped) counts as gone
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _ends(p, failure):
    """The process's stderr once it has exited; fails (and kills it) if it runs past STOP_DEADLINE."""
    try:
        return p.communicate(timeout=STOP_DEADLINE)[1]
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        pytest.fail(failure)


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc to find the worker processes")
def test_a_dying_worker_ends_the_run(tmp_path):
    p, kids = _start_long_render(tmp_path)
    os.kill(kids[0], signal.SIGKILL)
    t0 = time.perf_counter()
    err = _ends(p, "the run went on after a worker died")
    print(f"\n[worker killed] exit {p.returncode} after {time.perf_counter() - t0:.2f} s: {err.strip()!r}")
    assert p.returncode == 1
    assert "a render worker process died" in err and "Traceback" not in err
    assert not any(_alive(k) for k in kids)


@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc to find the worker processes")
def test_ctrl_c_stops_everything(tmp_path):
    p, kids = _start_long_render(tmp_path)
    os.killpg(p.pid, signal.SIGINT)  # what a terminal sends to the whole foreground group
    t0 = time.perf_counter()
    err = _ends(p, "Ctrl-C did not stop the run")
    print(f"\n[Ctrl-C] exit {p.returncode} after {time.perf_counter() - t0:.2f} s: {err.strip()!r}")
    assert p.returncode == 130
    assert "interrupted" in err and "Traceback" not in err
    deadline = time.perf_counter() + STOP_DEADLINE
    while any(_alive(k) for k in kids) and time.perf_counter() < deadline:
        time.sleep(0.1)
    assert not any(_alive(k) for k in kids)
