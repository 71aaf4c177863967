"""``msx.scene_path(name)``: a shipped scene, ready for ``mi.load_file`` from any directory."""

from __future__ import annotations

import hashlib
import os
import shutil


def scene_path(name: str) -> str:
    """The path of the shipped scene `name` (``"fig01_metals.xml"``; the ``.xml`` may be left out), with the
    generated assets it refers to (``assets/sky.exr``, ``assets/blob.ply``, ``assets/normalmap.exr``: see
    ``msx/assets.py``) written beside it when missing, so that ``mi.load_file(msx.scene_path(name))`` works
    right after install, from any directory.

    Where the installed scenes' folder is not writable, the scenes are copied once into the cache
    (``$MSX_CACHE_DIR``, else ``$XDG_CACHE_HOME/msx``, default ``~/.cache/msx``; ``scenes/<hash of the scene
    files>``), the assets written there, and that copy's path is returned. The variant must allow writing
    images (any variant does; if none is set, ``scalar_rgb`` is set to write the assets).

    Raises FileNotFoundError, naming the shipped scenes, for an unknown name; OSError, saying what to do, if
    no folder can take the assets."""
    from . import assets
    from ._render import RenderError, cache_root, read_scene, shipped_scene

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
    key = hashlib.sha256(b"".join(p.relative_to(folder).as_posix().encode() + p.read_bytes() for p in files))
    copy = cache_root() / "scenes" / key.hexdigest()[:16]
    try:
        if not (copy / path.name).is_file():
            tmp = copy.with_name(f"{copy.name}.{os.getpid()}.tmp")
            shutil.rmtree(tmp, ignore_errors=True)
            shutil.copytree(folder, tmp, ignore=shutil.ignore_patterns("assets", "*.tmp*"))
            try:
                tmp.rename(copy)  # atomic: a copy is complete or absent
            except OSError:  # another process made it first
                shutil.rmtree(tmp, ignore_errors=True)
        assets.ensure(copy / "assets")
    except OSError as e:
        raise OSError(f"msx.scene_path({name!r}): cannot write the scene's assets beside it ({beside}) nor into "
                      f"the cache {copy} ({e}); set MSX_CACHE_DIR to a writable folder") from None
    return str(copy / path.name)
