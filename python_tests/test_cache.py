"""msx's cache (msx/_cache.py): one folder, entries written atomically with a checksum record, and every kind
of entry — reference render, native build, microgeometry simulation, scene copy, generated asset — found
damaged (truncated, corrupted, without its record) is reported in one line and recomputed. `msx cache`."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import msx
from msx import _cache

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache folder for this test."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("MSX_CACHE_DIR", str(folder))
    return folder


def truncate(path: Path):
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def flip_a_byte(path: Path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def damaged_lines(err: str, path: Path):
    """The lines of stderr that report `path` damaged (exactly one is expected)."""
    return [ln for ln in err.splitlines() if ln.startswith(f"msx: {path} is ") and "recomputing it" in ln]


# ---------------------------------------------------------------- where


def test_one_cache_root_for_everything(tmp_path, monkeypatch):
    monkeypatch.delenv("MSX_CACHE_DIR", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _cache.root() == tmp_path / "home" / ".cache" / "msx"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _cache.root() == tmp_path / "xdg" / "msx"
    monkeypatch.setenv("MSX_CACHE_DIR", str(tmp_path / "mine"))
    assert _cache.root() == tmp_path / "mine"
    # Every user of the cache asks _cache for its folder: no other module reads the variables.
    package = Path(msx.__file__).parent
    for f in package.rglob("*.py"):
        if f.name != "_cache.py":
            text = f.read_text()
            assert 'environ.get("XDG_CACHE_HOME")' not in text and 'environ.get("MSX_CACHE_DIR")' not in text, f
    from msx import microgeometry

    assert microgeometry.simulation_path({"a": 1}).parent == tmp_path / "mine" / "simulations"


# ---------------------------------------------------------------- the mechanism


def test_an_interrupted_write_leaves_nothing(cache):
    target = cache / "simulations" / "x.npz"

    def produce(tmp):
        Path(tmp).write_bytes(b"partial")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _cache.write_file(target, produce)
    assert list((cache / "simulations").iterdir()) == []


@pytest.mark.parametrize("damage, reason", [(truncate, "truncated"), (flip_a_byte, "checksum does not match"),
                                            (lambda p: _cache.record_path(p).unlink(), "without its checksum record"),
                                            (lambda p: _cache.record_path(p).write_text("{"), "unreadable")])
def test_a_damaged_file_entry_is_reported_once_and_removed(cache, capsys, damage, reason):
    target = cache / "references" / "r.npz"
    _cache.write_file(target, lambda tmp: np.savez_compressed(tmp, a=np.arange(1000.0)))
    assert _cache.check_file(target)
    damage(target)
    assert not _cache.check_file(target)
    [line] = damaged_lines(capsys.readouterr().err, target)
    assert reason in line
    assert not target.exists() and not _cache.record_path(target).exists()


def test_an_entry_from_other_inputs_is_stale(cache, capsys):
    target = cache / "assets" / "sky.exr"
    _cache.write_file(target, lambda tmp: Path(tmp).write_bytes(b"x" * 100), key="old")
    assert _cache.check_file(target, key="old")
    assert not _cache.check_file(target, key="new")
    assert "stale" in damaged_lines(capsys.readouterr().err, target)[0]


# ---------------------------------------------------------------- every kind


def test_reference_render(cache, capsys, monkeypatch):
    """The reference of msx compare (a tiny one): cached, then truncated -> rendered again, with the line."""
    from msx import _references
    from msx._render import scenes_dir
    from msx.evaluation.driver import SWEEP_SCENES
    from msx.evaluation import renders

    renderer = renders.Renderer("scalar_rgb", scenes_dir())
    scene, row, folder = SWEEP_SCENES[0], ("heitz", "pt"), cache / "references"
    h1, h2, _, cached = _references.reference(renderer, scene, (8, 8), row, 4, folder)
    assert not cached
    [entry] = folder.glob("reference-*.npz")
    again = _references.reference(renderer, scene, (8, 8), row, 4, folder)
    assert again[3] and np.array_equal(again[0], h1)
    truncate(entry)
    h1b, h2b, _, cached = _references.reference(renderer, scene, (8, 8), row, 4, folder)
    assert not cached and np.array_equal(h1b, h1) and np.array_equal(h2b, h2)  # the same seeds
    assert len(damaged_lines(capsys.readouterr().err, entry)) == 1
    assert _cache.valid_file(entry) and sorted(p.name for p in folder.iterdir()) == [f".{entry.name}.msx", entry.name]
    # Another core (a rebuilt Rust library) renders its own reference.
    monkeypatch.setattr(_cache, "core_digest", lambda: "another core")
    assert not _references.reference(renderer, scene, (8, 8), row, 4, folder)[3]
    assert len(list(folder.glob("reference-*.npz"))) == 2 and not damaged_lines(capsys.readouterr().err, entry)
    renderer.release()


def test_native_build(cache, capfd):
    """A truncated native plugin is found before it is loaded, reported and compiled again."""
    from msx.plugin import native as nb

    os.environ.pop("MSX_CACHE_DIR")
    built = nb.build()  # the build of the usual cache (compiled once per install)
    os.environ["MSX_CACHE_DIR"] = str(cache)
    target = cache / built.relative_to(built.parents[2])  # native/<key>/msx_native.so
    shutil.copytree(built.parent, target.parent)
    assert nb.build() == target  # reused as it is
    capfd.readouterr()
    truncate(target)
    assert nb.build() == target and _cache.valid_file(target)
    err = capfd.readouterr().err
    assert len(damaged_lines(err, target)) == 1 and "compiling the native plugin" in err
    # It loads and passes its self-check (in a new process: this one may have loaded another build).
    code = ("import mitsuba as mi; mi.set_variant('scalar_rgb'); import msx; msx.register(backend='native'); "
            "print(msx.backend())")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=os.environ)
    assert r.stdout.strip() == "native" and "compiling" not in r.stderr, r.stderr


def test_simulation(cache, capsys, monkeypatch):
    from msx import microgeometry as mg

    params = dict(surface="conductor", alpha=0.5, alpha_v=0.5, theta_i=0.3, rays=4000, grid=64, corr_cells=8.0,
                  surfaces=2, theta_bins=8, phi_bins=8, seed=0, ior=1.5, albedo=1.0)
    res, fresh = mg.cached_simulation(params, progress=False)
    assert fresh
    path = mg.simulation_path(params)
    res2, fresh = mg.cached_simulation(params, progress=False)
    assert not fresh and np.array_equal(res2.lobes, res.lobes)
    for damage in (truncate, flip_a_byte):
        damage(path)
        res3, fresh = mg.cached_simulation(params, progress=False)
        assert fresh and np.array_equal(res3.lobes, res.lobes)
        assert len(damaged_lines(capsys.readouterr().err, path)) == 1
    assert _cache.valid_file(path)
    monkeypatch.setattr(_cache, "core_digest", lambda: "another core")  # another simulator: another entry
    assert mg.simulation_path(params) != path and mg.cached_simulation(params, progress=False)[1]


@pytest.fixture
def read_only_install(tmp_path, monkeypatch):
    """Shipped scenes whose folder cannot take the assets: msx.scene_path copies them into the cache."""
    from msx import _render, assets

    scenes = tmp_path / "installed" / "scenes"
    shutil.copytree(_render.scenes_dir(), scenes, ignore=shutil.ignore_patterns("assets"))
    monkeypatch.setattr(_render, "scenes_dir", lambda: scenes)
    ensure = assets.ensure

    def read_only(folder):
        if Path(folder).resolve().is_relative_to(scenes.resolve()):
            raise PermissionError(13, "Permission denied", str(folder))
        return ensure(folder)

    monkeypatch.setattr(assets, "ensure", read_only)
    return scenes


def _loads(path):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    dr.set_thread_count(max(2, dr.thread_count()))  # Mitsuba 3.9 deadlocks reading an EXR with one thread
    msx.register()
    return len(mi.load_file(str(path), spp=1, width=8, height=8).shapes()) > 0


def test_scene_copy(cache, read_only_install, capsys):
    path = Path(msx.scene_path("fig01_metals.xml"))
    copy = path.parent
    assert copy.parent == cache / "scenes"
    sky = copy / "assets" / "sky.exr"
    truncate(sky)
    assert Path(msx.scene_path("fig01_metals.xml")) == path
    [line] = damaged_lines(capsys.readouterr().err, copy)
    assert "assets/sky.exr" in line
    assert _loads(path)
    (copy / "fig01_metals.xml").unlink()  # a file missing
    msx.scene_path("fig01_metals.xml")
    assert "fig01_metals.xml is missing" in damaged_lines(capsys.readouterr().err, copy)[0] and path.is_file()


@pytest.mark.parametrize("name", ["sky.exr", "blob.ply", "normalmap.exr"])
def test_generated_asset(tmp_path, capsys, name):
    """Assets in the cache (scenes in a read-only folder) or beside the scenes: the same check."""
    from msx import assets

    folder = assets.ensure(tmp_path / "assets")
    before = (folder / name).read_bytes()
    truncate(folder / name)
    assets.ensure(folder)
    assert len(damaged_lines(capsys.readouterr().err, folder / name)) == 1
    assert (folder / name).read_bytes() == before  # the generator is deterministic


# ---------------------------------------------------------------- msx cache


def _msx(*args, env):
    return subprocess.run([sys.executable, "-m", "msx", *args], capture_output=True, text=True, timeout=120, env=env)


def test_msx_cache_shows_and_clears(cache):
    env = dict(os.environ, MSX_CACHE_DIR=str(cache))
    r = _msx("cache", env=env)
    assert r.returncode == 0 and str(cache) in r.stdout and "not created yet" in r.stdout
    _cache.write_file(cache / "references" / "reference-a.npz", lambda t: Path(t).write_bytes(b"1" * 3000))
    _cache.write_file(cache / "simulations" / "s.npz", lambda t: Path(t).write_bytes(b"2" * 5000))
    _cache.make_folder(cache / "scenes" / "abc", lambda t: (t / "x.xml").write_text("<scene/>"))
    (cache / "reference-old.npz").write_bytes(b"3" * 10)  # what an older msx left at the top
    (cache / "notes.txt").write_text("mine")  # not msx's
    r = _msx("cache", env=env)
    assert r.returncode == 0, r.stderr
    lines = {ln.split()[0]: ln for ln in r.stdout.splitlines()[1:]}
    for kind in ("references", "simulations"):
        size = sum(p.stat().st_size for p in (cache / kind).iterdir())  # the entry and its record
        assert 3000 < size < 6000 and f"1 entry      {size / 1024:.1f} KB" in lines[f"{kind}/"], lines
    assert "1 entry" in lines["scenes/"] and "notes.txt" in lines and "--clear" in r.stdout
    r = _msx("cache", "--clear", env=env)
    assert r.returncode == 0, r.stderr
    for kind in ("references", "simulations", "scenes"):
        assert f"deleted {cache / kind} (1 entry" in r.stdout
    assert f"deleted {cache / 'reference-old.npz'}" in r.stdout and f"left {cache / 'notes.txt'}" in r.stdout
    assert sorted(p.name for p in cache.iterdir()) == ["notes.txt"]
    (cache / "notes.txt").unlink()
    r = _msx("cache", "--clear", env=env)
    assert r.returncode == 0 and "nothing to delete" in r.stdout
