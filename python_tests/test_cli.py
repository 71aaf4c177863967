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
# Only failure paths are timed: a run still alive this long after a bad input, a dying worker or a signal has
# hung (the runs end in well under 2 s, even beside two busy processes: docs/testing.md). Never a measure of
# the machine's speed.
HUNG = 60.0


@pytest.fixture(scope="module", autouse=True)
def native_plugin_built():
    """The first scene load of a fresh install compiles the native plugin once (several seconds, announced
    on stderr, then cached): done here, so that the deadlines below time the failure paths themselves."""
    code = "import mitsuba as mi; mi.set_variant('scalar_rgb'); import msx; msx.register()"
    subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, check=True)


def msx(*args, timeout=HUNG, **kw):
    """`python -m msx ARGS`; `render` in scalar_rgb unless ARGS name a variant: these tests are about the
    worker processes of the scalar route (the default, `auto`, may pick llvm_ad_rgb: one process)."""
    if args[0] == "render" and "--variant" not in args:
        args = (*args, "--variant", "scalar_rgb")
    try:
        return subprocess.run([sys.executable, "-m", "msx", *args], capture_output=True, text=True, timeout=timeout,
                              **kw)
    except subprocess.TimeoutExpired:
        pytest.fail(f"msx {' '.join(args)} was still running after {timeout:.0f} s")


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("define, names", [
    ("model=invariant", "'model'"),
    ("alpha=-1", "'alpha'"),
    ("alpha=nan", "'alpha'"),
])
def test_bad_parameter_ends_fast_with_one_line(tmp_path, workers, define, names):
    """A bad parameter ends the run (a pool that respawned failing workers would run until HUNG) with one line."""
    t0 = time.perf_counter()
    r = msx("render", SCENE, "-D", define, "--workers", str(workers), "--spp", "8", "-o", str(tmp_path / "x.exr"))
    took = time.perf_counter() - t0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    print(f"\n[{define}, workers {workers}] exit {r.returncode} in {took:.2f} s: {lines}")
    assert r.returncode == 1
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


FIG09_PARAMS = "alpha, bsdf, distribution, estimator, height, material, max_depth, model, spp, width"


def _one_error_line(r, *fragments):
    """The run failed with exactly one line on stderr, an error naming every fragment, and no traceback."""
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 1, (r.returncode, r.stderr)
    assert len(lines) == 1, lines
    assert lines[0].startswith("msx: error: ") and "Traceback" not in r.stderr, lines
    assert "--verbose" not in lines[0], f"a user's mistake reported as an unexpected error: {lines[0]}"
    for f in fragments:
        assert f in lines[0], f"{f!r} not in {lines[0]!r}"
    return lines[0]


@pytest.mark.parametrize("workers", [1, 2])
def test_a_misspelled_define_is_named_with_a_suggestion(tmp_path, workers):
    """`-D alhpa=0.5` (Mitsuba: "Found unused parameters") names what was typed, suggests the close name and
    lists the scene's parameters, with the scene loaded in the CLI's process or in the workers."""
    r = msx("render", "fig09_copper_sphere.xml", "-D", "alhpa=0.5", "--workers", str(workers), "--spp", "4",
            "-o", str(tmp_path / "x.exr"), cwd=tmp_path)
    line = _one_error_line(r, "-D alhpa=0.5", "unknown parameter 'alhpa'", "did you mean 'alpha'?",
                           f"the scene's parameters: {FIG09_PARAMS}")
    assert not (tmp_path / "x.exr").exists(), line


def test_unused_defines_are_named(tmp_path):
    """A name the scene does not have, and a name it has but does not read with the other values (`model`
    with Mitsuba's roughconductor): both named; the list holds what the scene reads with these values."""
    r = msx("render", SCENE, "-D", "surface=dielectric", "--workers", "1", "-o", str(tmp_path / "x.exr"))
    line = _one_error_line(r, "-D surface=dielectric: unknown parameter 'surface'", FIG09_PARAMS)
    assert "did you mean" not in line  # nothing close to 'surface'
    r = msx("render", SCENE, "-D", "bsdf=roughconductor", "-D", "model=heitz", "--workers", "1",
            "-o", str(tmp_path / "x.exr"))
    _one_error_line(r, "-D model=heitz: 'model' is not used with these values",
                    "the scene's parameters: alpha, bsdf, distribution, height, material, max_depth, spp, width")


def test_a_scene_without_spp_renders(tmp_path):
    """A user's scene without a $spp parameter: --spp goes to the render alone (passing it to the scene too
    was rejected as an unused parameter)."""
    scene = tmp_path / "mine.xml"
    scene.write_text('<scene version="3.0.0"><integrator type="path"/><sensor type="perspective">'
                     '<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>'
                     '</sensor><shape type="sphere"><bsdf type="msx_posfree"/></shape>'
                     '<emitter type="constant"/></scene>')
    r = msx("render", str(scene), "--spp", "2", "--workers", "1", "-o", str(tmp_path / "x.exr"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "x.exr").exists()


def test_bad_inputs_give_one_line(tmp_path, capsys):
    """Unknown scenes, unreadable files, bad values and unwritable outputs, in render, compare, simulate and
    assets: one line naming what was typed, before any work is done (msx.cli.main in this process: fast)."""
    from types import SimpleNamespace

    from msx import cli

    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder")
    (tmp_path / "folder.xml").mkdir()
    cases = [
        (("render", "nope.xml"), ["scene file not found: nope.xml", "shipped scenes: "]),
        (("render", str(tmp_path / "folder.xml")), ["the scene is a folder, not a file: "]),
        (("render", SCENE, "-D", "spp=many"), ["-D spp=many", "integer"]),
        (("render", SCENE, "-D", "alpha"), ["-D expects key=value, got 'alpha'"]),
        (("render", SCENE, "-o", str(a_file / "x.exr")), [f"-o {a_file / 'x.exr'}", "is not a folder"]),
        (("compare", "--variant", "scalar_bogus", "--out", str(tmp_path / "c")), ["--variant scalar_bogus",
                                                                                  "scalar_rgb"]),
        (("compare", "--out", str(a_file)), [f"--out {a_file}", "is not a folder"]),
        (("compare", "--scenes", str(a_file), "--out", str(tmp_path / "c")), [f"--scenes {a_file}: not a folder"]),
        (("compare", "--cache", str(a_file / "c"), "--out", str(tmp_path / "c")), [f"--cache {a_file / 'c'}"]),
        (("assets", str(a_file)), [f"msx assets {a_file}", "is not a folder"]),
        (("simulate", "--surface", "conductor", "--alpha", "-1", "--theta-i", "0.5", "--rays", "100",
          "--out", str(tmp_path / "s")), ["alpha must lie in"]),
        (("simulate", "--surface", "conductor", "--alpha", "0.5", "--theta-i", "0.5", "--rays", "-5",
          "--out", str(tmp_path / "s")), ["--rays must be an integer ≥ 1 (got -5)"]),
        (("simulate", "--surface", "conductor", "--alpha", "0.5", "--theta-i", "0.5", "--rays", "100",
          "--out", str(a_file)), [f"--out {a_file}", "is not a folder"]),
    ]
    usage = [  # argparse's checks: one line too (exit status 2), naming the option and the value
        (("render", SCENE, "--seed", "abc"), ["msx render: error: argument --seed: invalid int value: 'abc'"]),
        (("render", SCENE, "--workers", "0"), ["msx render: error: argument --workers: ", "(got 0)"]),
        (("simulate", "--surface", "plastic"), ["msx simulate: error: argument --surface: invalid choice: 'plastic'"]),
        (("bogus",), ["msx: error: argument command: invalid choice: 'bogus'"]),
    ]
    for args, fragments in usage:
        with pytest.raises(SystemExit) as e:
            cli.main(list(args))
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert e.value.code == 2 and len(err) == 1, (args, err)
        assert all(f in err[0] for f in fragments) and err[0].endswith("--help)"), (args, err)
    for args, fragments in cases:
        code = cli.main([*args, "--workers", "1", "--variant", "scalar_rgb"] if args[0] == "render" else list(args))
        r = SimpleNamespace(returncode=code, stderr=capsys.readouterr().err)
        _one_error_line(r, *fragments)
        assert "chunks" not in r.stderr and "%" not in r.stderr, f"{args}: the error came after the work"


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


def _like_a_terminal_job():
    """In the child, before exec: the stop signals' default actions, as for a terminal's foreground job (the
    tests may run in the background, which ignores SIGINT, or under nohup, which ignores SIGHUP; msx keeps an
    ignored signal ignored)."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)


def _start_long_render(tmp_path, workers=2, env=None):
    """A render that would run for many minutes; returns the process once its workers exist (or, with one
    worker, once it had time to start rendering in-process)."""
    p = subprocess.Popen([sys.executable, "-m", "msx", "render", SCENE, "--workers", str(workers), "--spp", "100000",
                          "--variant", "scalar_rgb", "-o", str(tmp_path / "x.exr")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, preexec_fn=_like_a_terminal_job,
                         env=None if env is None else {**os.environ, **env})
    if workers == 1:
        time.sleep(3.0)  # usually inside mi.render by now; earlier or later ends the same way (asserted alike)
        return p, []
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < HUNG:
        kids = _children(p.pid)
        if len(kids) >= workers:
            time.sleep(1.0)  # let them load the scene and start rendering
            return p, kids
        time.sleep(0.1)
    os.killpg(p.pid, signal.SIGKILL)
    pytest.fail(f"the render did not start {workers} workers in {HUNG:.0f} s")


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
    """(stderr, seconds) once the process has exited; fails (and kills its group) if it is alive after HUNG."""
    t0 = time.perf_counter()
    try:
        err = p.communicate(timeout=HUNG)[1]
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        pytest.fail(f"{failure}: still alive after {HUNG:.0f} s")
    return err, time.perf_counter() - t0


def _blocked(pid):
    """The signals a process blocks (its SigBlk mask in /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigBlk:"):
            mask = int(line.split()[1], 16)
            return {s for s in range(1, 64) if mask >> (s - 1) & 1}
    return set()


needs_proc = pytest.mark.skipif(not Path("/proc/self/task").exists(),
                                reason="needs Linux /proc to find the worker processes")


@needs_proc
def test_a_dying_worker_ends_the_run(tmp_path):
    p, kids = _start_long_render(tmp_path)
    os.kill(kids[0], signal.SIGKILL)
    err, took = _ends(p, "the run went on after a worker died")
    print(f"\n[worker killed] exit {p.returncode} after {took:.2f} s: {err.strip()!r}")
    assert p.returncode == 1
    assert err.strip() == "msx: error: fig09_copper_sphere.xml: a render worker process died (exit code -9)"
    assert not any(_alive(k) for k in kids)


STOPS = [("SIGINT", 130, "msx: interrupted"), ("SIGTERM", 143, "msx: terminated (SIGTERM)"),
         ("SIGHUP", 129, "msx: hang-up (SIGHUP: the terminal closed)")]


@needs_proc
@pytest.mark.parametrize("name, code, line", STOPS, ids=[s[0] for s in STOPS])
def test_ctrl_c_stops_everything(tmp_path, name, code, line):
    """Ctrl-C (or SIGTERM, or a closed terminal's SIGHUP) sent to the whole process group, as a terminal does,
    ends a render with two workers: one line, exit code 128 + the signal, no worker left. The last-resort exit
    is off (MSX_STOP_GRACE=inf): the run must end by itself. It once hung 1 run in 20 beside two busy processes
    (a worker stopped while sending its result left the executor's reader thread waiting forever)."""
    p, kids = _start_long_render(tmp_path, env={"MSX_STOP_GRACE": "inf"})
    for k in kids:  # the workers leave stop signals to the parent (Mitsuba's render would act on SIGINT)
        assert {signal.SIGINT, signal.SIGTERM, signal.SIGHUP} <= _blocked(k), f"worker {k} acts on stop signals"
    os.killpg(p.pid, getattr(signal, name))  # what a terminal sends to the whole foreground group
    err, took = _ends(p, f"{name} did not stop the run")
    print(f"\n[{name}] exit {p.returncode} after {took:.2f} s: {err.strip()!r}")
    assert p.returncode == code
    assert err.strip() == line
    assert not any(_alive(k) for k in kids), "a worker outlived the run"


@pytest.mark.parametrize("name, code, line", STOPS[1:], ids=[s[0] for s in STOPS[1:]])
def test_a_stop_signal_ends_an_in_process_render(tmp_path, name, code, line):
    """With one worker the render runs in the main process, inside Mitsuba, where a SIGTERM's Python handler
    cannot run until the render returns: the watcher ends the run after MSX_STOP_GRACE (here 1 s)."""
    p, _ = _start_long_render(tmp_path, workers=1, env={"MSX_STOP_GRACE": "1"})
    os.killpg(p.pid, getattr(signal, name))
    err, took = _ends(p, f"{name} did not stop the in-process render")
    print(f"\n[{name}, 1 worker] exit {p.returncode} after {took:.2f} s: {err.strip()!r}")
    assert p.returncode == code
    assert err.strip().startswith(line) and len(err.strip().splitlines()) == 1


def test_ctrl_c_stops_compare(tmp_path):
    """`msx compare` renders in its own process (Mitsuba's threads): Ctrl-C cancels the running render and
    ends the run by itself (the last-resort exit is off) with one line."""
    p = subprocess.Popen([sys.executable, "-m", "msx", "compare", "--quick", "--out", str(tmp_path / "out"),
                          "--cache", str(tmp_path / "cache")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True, preexec_fn=_like_a_terminal_job,
                         env={**os.environ, "MSX_STOP_GRACE": "inf"})
    time.sleep(4.0)  # into the first sweep's renders, usually; before or after ends the same way
    os.killpg(p.pid, signal.SIGINT)
    err, took = _ends(p, "Ctrl-C did not stop msx compare")
    print(f"\n[compare, SIGINT] exit {p.returncode} after {took:.2f} s: {err.strip().splitlines()[-1]!r}")
    assert p.returncode == 130, err
    assert err.strip().splitlines()[-1] == "msx: interrupted" and "Traceback" not in err


def test_ctrl_c_inside_a_native_callback_is_an_interrupt(tmp_path, capsys, monkeypatch):
    """Ctrl-C while Mitsuba's loader runs msx's plugin constructor (Python called from C++): the
    KeyboardInterrupt comes back wrapped in Mitsuba's error. The run still ends as interrupted (exit 130,
    "msx: interrupted"), not as an error (it did: 1 run in 10 of the Ctrl-C test of msx compare, under load)."""
    from msx import _render, cli

    def load_scene(mi, scene, **params):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(HUNG)  # the handler raises here
        except KeyboardInterrupt:
            raise RuntimeError(f"At {scene} (line 1, col 1): failed to instantiate plugin: KeyboardInterrupt: ")
        pytest.fail("SIGINT was not handled")

    monkeypatch.setattr(_render, "load_scene", load_scene)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal (pytest may run in the
    try:  # background, SIGINT ignored)
        code = cli.main(["render", SCENE, "--workers", "1", "--variant", "scalar_rgb", "--spp", "1", "-o",
                         str(tmp_path / "x.exr")])
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # main() restored it
    finally:
        signal.signal(signal.SIGINT, before)
    err = capsys.readouterr().err
    assert (code, err.strip()) == (130, "msx: interrupted")


def test_a_stop_raised_inside_a_finalizer_is_not_lost(tmp_path):
    """The handler of a stop signal can run inside a __del__ (garbage collection in the main thread), where
    Python prints the exception and goes on: the run must still stop, not finish as if nothing happened."""
    code = ("import os, signal, sys, time\nfrom msx import cli\n"
            "class Finalized:\n    def __del__(self):\n        os.kill(os.getpid(), signal.SIGTERM)\n"
            "        for _ in range(1000):  # the handler runs here, its exception unraisable\n            pass\n"
            "def run(args):\n    Finalized()  # freed at once: __del__ runs\n    time.sleep(float(sys.argv[2]))\n"
            "    print('went on')\n"
            "cli.cmd_assets = run\nsys.exit(cli.main(['assets', sys.argv[1]]))\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path), str(HUNG / 2)], capture_output=True, text=True,
                       timeout=HUNG, env={**os.environ, "MSX_STOP_GRACE": "inf"}, preexec_fn=_like_a_terminal_job)
    assert (r.returncode, r.stderr.strip(), r.stdout) == (143, "msx: terminated (SIGTERM)", "")


def test_an_ignored_hangup_stays_ignored(tmp_path):
    """`nohup msx …` (SIGHUP ignored by whoever started msx) survives a closed terminal: msx must not install
    its own SIGHUP handler over the inherited SIG_IGN."""
    code = ("import signal, sys\nfrom msx import cli\nsignal.signal(signal.SIGHUP, signal.SIG_IGN)\n"
            "def hang_up(args):\n    signal.raise_signal(signal.SIGHUP)\n    print('survived')\n"
            "cli.cmd_assets = hang_up\nsys.exit(cli.main(['assets', sys.argv[1]]))\n")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=HUNG)
    assert (r.returncode, r.stdout.strip()) == (0, "survived"), r.stderr


def test_variant_auto_takes_the_fastest_route_and_says_which(tmp_path):
    """`--variant auto`: llvm_ad_rgb with the Dr.Jit engine where Mitsuba's LLVM variant works here (said on
    stderr), and scalar_rgb with the native back end for a configuration the engine does not run."""
    from msx._variants import llvm_problem

    problem = llvm_problem()
    r = msx("render", "fig09_copper_sphere.xml", "--variant", "auto", "--spp", "4", "-o", str(tmp_path / "a.exr"),
            timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "a.exr").exists()
    expected = "scalar_rgb (the native back end; " if problem else "llvm_ad_rgb (the Dr.Jit engine)"
    assert f"msx: rendering with {expected}" in r.stderr, r.stderr[-2000:]
    if problem:
        return
    r = msx("render", "fig08_diffuse.xml", "--variant", "auto", "-D", "model=invariance", "--spp", "1",
            "-o", str(tmp_path / "b.exr"), timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "rendering with scalar_rgb (the native back end) instead" in r.stderr, r.stderr[-2000:]
    assert (tmp_path / "b.exr").exists()


@pytest.mark.parametrize("define", ["model=invariant", "alpha=-1", "alhpa=0.5"])
def test_a_bad_parameter_reads_the_same_in_both_engines(tmp_path, define):
    """The Dr.Jit engine (llvm_ad_rgb) and the native back end (scalar_rgb) name a bad parameter in the same
    one line."""
    from msx._variants import llvm_problem

    if llvm_problem():
        pytest.skip(llvm_problem())
    lines = {}
    for variant in ("scalar_rgb", "llvm_ad_rgb"):
        r = msx("render", SCENE, "-D", define, "--variant", variant, "--workers", "1", "--spp", "1",
                "-o", str(tmp_path / "x.exr"), timeout=600)
        assert r.returncode == 1, (variant, r.stderr[-2000:])
        lines[variant] = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines[variant]) == 1 and lines[variant][0].startswith("msx: error: "), (variant, r.stderr)
    assert lines["scalar_rgb"] == lines["llvm_ad_rgb"]
