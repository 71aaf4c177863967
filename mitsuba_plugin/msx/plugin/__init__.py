"""The ``msx_posfree`` plugin, one module per route by which a BSDF call reaches the Rust core.

- ``parameters.py``: every route — the scene parameters (parsing, validation, messages) against the core's
  table of names (models, estimators, distributions, surfaces; ``msx/names.py``, re-exported here).
- ``base.py``: what the Python classes share (native handle, textures, lobes, flags, ``traverse``, factory).
- ``native.py``: scalar variants, the default — a C++ plugin (``native/msx_mitsuba.cpp``) compiled on first use,
  calling the core without Python.
- ``scalar.py``: scalar variants, the Python class (``backend="python"``, and the fallback of ``native``).
- ``jit_bsdf.py``: vectorized variants, the default — the Mitsuba class of the Dr.Jit engine (``msx/jit/``,
  which imports nothing from here).
- ``vectorized.py``: vectorized variants, the batched route (``backend="batched"``).
- ``vectorized_config.py``: vectorized variants, both routes — reading the parameters from Dr.Jit arrays.

``msx.register()`` (``msx/__init__.py``) picks the route.
"""
