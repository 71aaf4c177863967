"""msx.scene_path: a shipped scene loads with mi.load_file as shipped, from any directory, its generated assets
written beside it (or, where the installed scenes are read-only, beside a copy in the cache)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import msx
from msx import _render

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def fresh_scenes(tmp_path, monkeypatch):
    """The shipped scenes as a fresh install has them: no assets folder (scene_path must write it)."""
    scenes = tmp_path / "installed" / "scenes"
    shutil.copytree(_render.scenes_dir(), scenes, ignore=shutil.ignore_patterns("assets"))
    monkeypatch.setattr(_render, "scenes_dir", lambda: scenes)
    monkeypatch.setenv("MSX_CACHE_DIR", str(tmp_path / "cache"))
    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    monkeypatch.chdir(cwd)  # a relative "assets/sky.exr" would not resolve from here
    return scenes


def _load(path):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    dr.set_thread_count(max(2, dr.thread_count()))  # other tests set 1: Mitsuba 3.9 then deadlocks reading an EXR
    msx.register()
    return mi.load_file(path, spp=1, width=8, height=8)


def test_scene_path_writes_the_assets_and_the_scene_loads(fresh_scenes):
    assert "scene_path" in msx.__all__
    path = msx.scene_path("fig01_metals.xml")
    assert Path(path) == fresh_scenes / "fig01_metals.xml"
    written = sorted(p.name for p in (fresh_scenes / "assets").iterdir())
    # Each asset with its checksum record (msx/_cache.py).
    assert written == [".blob.ply.msx", ".normalmap.exr.msx", ".sky.exr.msx", "blob.ply", "normalmap.exr", "sky.exr"]
    scene = _load(path)
    assert len(scene.shapes()) > 3 and scene.environment() is not None
    assert msx.scene_path("fig09_copper_sphere") == str(fresh_scenes / "fig09_copper_sphere.xml")  # .xml optional


def test_a_read_only_install_loads_from_a_copy_in_the_cache(fresh_scenes, tmp_path, monkeypatch):
    from msx import assets

    ensure = assets.ensure

    def read_only(folder):
        if Path(folder).resolve().is_relative_to(fresh_scenes.resolve()):
            raise PermissionError(13, "Permission denied", str(folder))
        return ensure(folder)

    monkeypatch.setattr(assets, "ensure", read_only)
    path = Path(msx.scene_path("fig07_normalmap.xml"))
    assert path.is_relative_to(tmp_path / "cache" / "scenes") and path.name == "fig07_normalmap.xml"
    assert (path.parent / "assets" / "normalmap.exr").is_file() and not (fresh_scenes / "assets").exists()
    _load(str(path))
    assert msx.scene_path("fig07_normalmap.xml") == str(path)  # the copy is made once


def test_an_unknown_name_lists_the_shipped_scenes():
    with pytest.raises(FileNotFoundError) as e:
        msx.scene_path("fig01_metal.xml")
    assert "'fig01_metal.xml'" in str(e.value) and "fig01_metals.xml" in str(e.value)


def test_the_readme_example_works_from_any_directory(tmp_path):
    """The installed package, a new process, a directory without scenes: load_file(scene_path(...)) works."""
    code = ("import mitsuba as mi; mi.set_variant('scalar_rgb'); import msx; msx.register(); "
            "s = mi.load_file(msx.scene_path('fig01_metals.xml'), spp=1, width=8, height=8); "
            "print(len(s.shapes()))")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert int(r.stdout.split()[-1]) > 3
