"""The Dr.Jit engine: the models of the Rust core (``src/``) written once as Dr.Jit code, traced into
Mitsuba's kernels in every vectorized variant (``llvm_*``, ``cuda_*``; rgb, spectral, mono).

One module per folder of the core, with the same function names, so that each Rust function's twin is
found by name (docs/engines.md):

| module | Rust twin | what |
|---|---|---|
| ``microfacet.py`` | ``src/microfacet/{mod,ggx,fresnel}.rs`` | Λ on the whole sphere, D, visible normals, Fresnel |
| ``beckmann.py`` | ``src/microfacet/{beckmann,special}.rs`` | Beckmann Λ and full-sphere visible normals in float32 |
| ``rng.py`` | ``src/rng.rs`` | each lane's random stream, derived from its inputs and ``seed`` |
| ``walk.py`` | ``src/walk/mod.rs`` | Russian roulette |
| ``tables.py`` | ``src/tables/`` | the core's tables, read through ``msx_table`` and uploaded as textures |
| ``mis.py`` | ``src/models/mis.rs`` | the walks' MIS densities |
| ``single.py`` | ``src/models/single/`` | Walter 2007 as Mitsuba computes it |
| ``posfree.py`` | ``src/models/posfree/`` | Wang 2022 position-free PT |
| ``bsdf.py`` | ``src/bsdf.rs`` + ``plugin/base.py`` | the ``msx_posfree`` class of the vectorized variants |

Everything here is traced: a function runs once per kernel, on arrays of lanes; branches are masks
(``dr.select``) and walks are ``dr.while_loop``. Nothing reads a value back from the device.
"""
