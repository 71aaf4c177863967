"""The invariance principle (Cui et al. 2023, with Bitterli & d'Eon 2022's exit probability) in the Dr.Jit
engine: twin of ``src/models/invariance/mod.rs``, the model's walks on the three microsurfaces, one module
per file of the Rust folder:

| module | Rust twin | what |
|---|---|---|
| ``invariance_recursion.py`` | ``recursion.rs`` | the incremental exit table of monotone paths in per-lane registers |
| ``invariance_conductor.py`` | ``conductor.rs`` | PT eval and sample on conductor facets, the BDPT's segment term |
| ``invariance_general.py`` | ``general.rs`` | the complete recursion on Lambertian facets (``dr.alloc_local``) |
| ``invariance_dielectric.py`` | ``dielectric.rs`` | the first run's exact depth law, Heitz's walk after the first refraction |
"""

from . import invariance_conductor as conductor
from . import invariance_dielectric as dielectric
from . import invariance_general as general
from . import mis
from .microfacet import BECKMANN, GGX
from .model import ConductorWalk, DielectricWalk, DiffuseWalk

# The conductor walk (jit/bsdf.py collects it): height-correlated order-1 exit in the MIS density, and no
# walk from below the macro surface (the core's eval and sample need ω_i up).
CONDUCTOR_WALKS = {"invariance": ConductorWalk(conductor.eval, conductor.sample, mis.HEIGHT_CORRELATED, below=False,
                                              eval_bdpt=conductor.eval_bdpt, differentiable=True,
                                              direction_distributions=(BECKMANN, GGX))}
# The walks on the other microsurfaces (MIS densities: ``mis.diffuse_pdf``, ``mis.dielectric_pdf``). The
# Lambertian walk keeps its table in ``dr.alloc_local``: refused in scenes (jit/invariance_general.py).
DIFFUSE_WALKS = {"invariance": DiffuseWalk(general.eval, general.sample, needs_local_arrays=True)}
DIELECTRIC_WALKS = {"invariance": DielectricWalk(dielectric.eval, dielectric.sample, differentiable=True,
                                                 eta_differentiable=True, direction_distributions=(BECKMANN, GGX))}
