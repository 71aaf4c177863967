"""The converged reference renders of ``msx compare`` in msx's cache (``references/``, msx/_cache.py).

``evaluation.renders.reference`` renders a reference and names it by its key (``reference_key``: the scene
files, parameters, spp, row, variant, msx's and the core's versions); this wraps it so that the entry is also
keyed by the code that renders it (the compiled core's digest, and the native plugin's or the Dr.Jit engine's
source), written atomically with its checksum beside it, and a damaged one is reported in one line and
rendered again.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from . import _cache


def _route_digest(renderer) -> str:
    """The code that renders the reference: the compiled core, and the native plugin's source (scalar
    variants) or the Dr.Jit engine's modules (vectorized variants). reference_key has only version numbers,
    which do not change with the code."""
    package = Path(__file__).resolve().parent
    if renderer.variant.startswith("scalar"):
        from .plugin import native

        try:
            code = list(native._sources())
        except native.NativeUnavailable:  # not installed: the Python back end renders
            code = []
    else:
        code = sorted((package / "jit").glob("*.py"))
    return _cache.digest_files(*code) + _cache.core_digest()


def reference(renderer, scene, size, row, spp, folder, progress=None, smaller=None):
    """As ``evaluation.renders.reference`` (``smaller``: a reference at fewer spp to continue from, where
    ``renders.continues`` allows it): (h1, h2, seconds, from_cache), cached in `folder`."""
    from .evaluation import renders

    folder = Path(folder)
    params = renderer.params(scene, row, size)
    key = _cache.key_of(renders.reference_key(renderer, scene.name, params, spp, row), _route_digest(renderer))
    path = folder / f"reference-{scene.name}-{key}.npz"
    if _cache.check_file(path):
        try:
            with np.load(path) as d:
                return d["h1"], d["h2"], float(d["seconds"]), True
        except Exception as e:  # noqa: BLE001 - intact bytes that still do not load: render again
            _cache.report(path, f"unreadable ({type(e).__name__}: {e})")
            _cache.remove(path)
    folder.mkdir(parents=True, exist_ok=True)
    # Rendered into a private folder (renders.reference writes its file there, not atomically), then written
    # into the cache atomically.
    work = Path(tempfile.mkdtemp(prefix=".reference-", dir=folder))
    try:
        h1, h2, seconds, _ = renders.reference(renderer, scene, size, row, spp, work, progress, smaller)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    _cache.write_file(path, lambda tmp: np.savez_compressed(tmp, h1=h1, h2=h2, seconds=seconds), key=key)
    return h1, h2, seconds, False
