"""The ``msx_posfree`` plugin, one module per route by which a BSDF call reaches the Rust core.

- ``parameters.py``: every route — the scene parameters (parsing, validation, messages) and the core's table
  of names (models, estimators, distributions, surfaces; src/config.rs through ``msx_choice*``).
- ``base.py``: what the Python classes share (native handle, textures, lobes, flags, ``traverse``, factory).
- ``native.py``: scalar variants, the default — a C++ plugin (``native/msx_mitsuba.cpp``) compiled on first use,
  calling the core without Python.
- ``scalar.py``: scalar variants, the Python class (``backend="python"``, and the fallback of ``native``).
- ``vectorized.py``: vectorized variants, the batched route (``backend="batched"``); the default there is the
  Dr.Jit engine, ``msx/jit/``.
- ``vectorized_config.py``: vectorized variants, both routes — reading the parameters from Dr.Jit arrays.

``msx.register()`` (``msx/__init__.py``) picks the route.
"""
