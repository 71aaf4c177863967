"""The Dr.Jit engine: the models of the Rust core (``src/``) written once as Dr.Jit code, traced into
Mitsuba's kernels in every vectorized variant (``llvm_*``, ``cuda_*``; rgb, spectral, mono).

One module per folder of the core, with the same function names, so that each Rust function's twin is
found by name (docs/engines.md):

| module | Rust twin | what |
|---|---|---|
| ``microfacet.py`` | ``src/microfacet/{mod,ggx,fresnel}.rs`` | Λ on the whole sphere, D, visible normals, conductor Fresnel, half vector |
| ``special.py`` | ``src/microfacet/special.rs`` | float32 erfc/erfcx, norm_inv, expm1/log1p, L·B(L, 1+Λ) |
| ``beckmann.py`` | ``src/microfacet/beckmann.rs`` | Beckmann Λ and full-sphere visible normals in float32 |
| ``dielectric.py`` | ``src/microfacet/dielectric.rs`` | the dielectric interface: η seen, Fresnel, refraction, half vector |
| ``rng.py`` | ``src/rng.rs`` | each lane's random stream, derived from its inputs and ``seed`` |
| ``walk.py`` | ``src/walk/mod.rs`` | Russian roulette, cosine directions, a sampled vertex's numbers, named loop state |
| ``tables.py`` | ``src/tables/`` | the core's tables, read through ``msx_table`` and uploaded as textures |
| ``mis.py`` | ``src/models/mis.rs`` | the walks' MIS densities |
| ``model.py`` | ``ScatteringModel`` in ``src/models/mod.rs`` | the model interface |
| ``single.py`` | ``src/models/single/`` | Walter 2007 as Mitsuba computes it |
| ``posfree.py`` | ``src/models/posfree/`` | Wang 2022 position-free PT |
| ``posfree_dielectric.py`` | ``src/models/posfree/dielectric.rs`` | Wang 2022 through a rough dielectric |
| ``bdpt.py`` | ``src/walk/bdpt.rs`` | the bidirectional estimator |
| ``heitz.py`` | ``src/walk/height.rs`` | Heitz 2016 random walk with explicit heights |
| ``invariance.py`` | ``src/models/invariance/mod.rs`` | Cui 2023: the model's walks on the three surfaces (its tables) |
| ``invariance_recursion.py`` | ``src/models/invariance/recursion.rs`` | exit probabilities of monotone paths in registers |
| ``invariance_conductor.py`` | ``src/models/invariance/conductor.rs`` | Cui 2023 on conductor facets: PT eval, sample, BDPT |
| ``invariance_general.py`` | ``src/models/invariance/general.rs`` | Cui 2023 on Lambertian facets (complete recursion) |
| ``invariance_dielectric.py`` | ``src/models/invariance/dielectric.rs`` | Cui 2023 through a rough dielectric |
| ``analytic.py`` | ``src/models/analytic/`` | Fast-MSX, energy compensation |
| ``auto.py`` | ``src/models/auto/`` | ``auto``: ``correlated`` with a per-lane bounce cap |
| ``gradients.py``, ``glass_traced.py`` | — | gradients of the walks (docs/gradients.md) |
| ``bsdf.py`` | ``src/bsdf.rs`` | what the engine runs, its refusals, the per-surface adapters |

The Mitsuba class over them is ``plugin/jit_bsdf.py``; nothing here imports from ``plugin/``.

Everything here is traced: a function runs once per kernel, on arrays of lanes; branches are masks
(``dr.select``) and walks are ``dr.while_loop``. Nothing reads a value back from the device.
"""
