"""``msx.scene_path(name)``: a shipped scene, ready for ``mi.load_file`` from any directory."""

from __future__ import annotations

import shutil
from pathlib import Path


def scene_path(name: str) -> str:
    """The path of the shipped scene `name` (``"fig01_metals.xml"``; the ``.xml`` may be left out), with the
    generated assets it refers to (``assets/sky.exr``, ``assets/blob.ply``, ``assets/normalmap.exr``: see
    ``msx/assets.py``) written beside it when missing, so that ``mi.load_file(msx.scene_path(name))`` works
    right after install, from any directory.

    Where the installed scenes' folder is not writable, the scenes are copied once into the cache
    (msx/_cache.py: ``scenes/<hash of the scene files and the assets' generator>``), with the assets, as one
    entry whose files are checked against their manifest on each use (a damaged copy is made again, saying
    so), and that copy's path is returned. The variant must allow writing
    images (any variant does; if none is set, ``scalar_rgb`` is set to write the assets).

    Raises FileNotFoundError, naming the shipped scenes, for an unknown name; OSError, saying what to do, if
    no folder can take the assets."""
    from . import _cache, assets
    from ._render import RenderError, read_scene, shipped_scene

    try:
        path = shipped_scene(name)
        text = read_scene(path)
    except RenderError as e:
        raise FileNotFoundError(str(e)) from None
    if "$assets" not in text:
        return str(path)
    try:
        assets.ensure(path.parent / "assets")
        return str(path)
    except OSError as e:
        beside = e
    folder = path.parent
    files = sorted(folder.rglob("*.xml"))
    # What the copy depends on: the scene files and the assets' generator.
    key = _cache.key_of(*(p.relative_to(folder).as_posix().encode() + p.read_bytes() for p in files),
                        Path(assets.__file__).read_bytes())
    copy = _cache.folder("scenes") / key[:16]

    def make(tmp):
        shutil.copytree(folder, tmp, ignore=shutil.ignore_patterns("assets", ".*"), dirs_exist_ok=True)
        assets.ensure(tmp / "assets")

    try:
        if not _cache.check_folder(copy):  # complete and intact, or made again (atomically)
            _cache.make_folder(copy, make)
    except OSError as e:
        raise OSError(f"msx.scene_path({name!r}): cannot write the scene's assets beside it ({beside}) nor into "
                      f"the cache {copy} ({e}); set MSX_CACHE_DIR to a writable folder") from None
    return str(copy / path.name)
