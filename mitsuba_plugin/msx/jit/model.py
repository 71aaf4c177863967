"""The one model interface of the Dr.Jit engine: twin of ``ScatteringModel`` in ``src/models/mod.rs``.

Each model module ends with a table of what it provides, by model name (``CONDUCTOR_WALKS``,
``DIELECTRIC_WALKS``, ``DIFFUSE_WALKS``); ``bsdf.py`` collects the tables, so adding a model to the engine
is its module plus one line there. Values exclude Mitsuba's tints (``bsdf.py`` applies them); every
function takes and returns arrays of lanes and is traced.
"""


class ConductorWalk:
    """A conductor random-walk model:

    - ``eval_pt(mf, fresnel, wi, wo, max_bounces, key)`` → one estimate of f·cos θ_o (mi.Spectrum);
    - ``sample_walk(mf, fresnel, wi, sample1, u1, u2, max_bounces, key)`` → (ω_o, weight, valid);
    - ``exit``: the order-1 exit of its MIS density (``mis.SEPARABLE`` or ``mis.HEIGHT_CORRELATED``);
    - ``below``: whether the walk also starts below the macro surface (normal mapping);
    - ``eval_bdpt`` (optional, same signature as ``eval_pt``): the bidirectional estimator, None where the
      engine has none (the scene is then refused with a message);
    - ``differentiable``: ``eval_pt`` accepts ``mf_sample=`` (docs/gradients.md);
    - ``direction_distributions``: the distributions for which that traced ``eval_pt`` also differentiates
      through ω_i and ω_o without bias (docs/gradients.md, "Directions through the walks").
    """

    def __init__(self, eval_pt, sample_walk, exit, below, eval_bdpt=None, differentiable=False,
                 direction_distributions=()):
        self.eval_pt, self.sample_walk, self.exit, self.below = eval_pt, sample_walk, exit, below
        self.eval_bdpt = eval_bdpt
        # Whether ``eval_pt`` takes ``mf_sample`` (jit/gradients.py): its PT estimate then differentiates.
        self.differentiable = differentiable
        self.direction_distributions = tuple(direction_distributions)


class ConductorAnalytic:
    """An analytic conductor model (deterministic; ``single``'s sampler and density):

    - ``eval_pdf(mf, fresnel, wi, wo)`` → (f·cos θ_o, pdf);
    - ``sample(mf, fresnel, wi, u1, u2)`` → (ω_o, pdf, weight, valid).
    """

    def __init__(self, eval_pdf, sample):
        self.eval_pdf, self.sample = eval_pdf, sample


class DielectricAnalytic:
    """An analytic dielectric model (deterministic, one channel; ``single``'s sampler and density):

    - ``eval(mf, eta, radiance, wi, wo)`` → f·|cos θ_o|; ``pdf(mf, eta, wi, wo)``;
    - ``sample(mf, eta, radiance, wi, sample1, u1, u2)`` → (ω_o, pdf, weight, valid).
    """

    def __init__(self, eval, pdf, sample):
        self.eval, self.pdf, self.sample = eval, pdf, sample


class _Walk:
    """What every walk on a non-conductor surface provides: ``eval_pt`` and ``sample_walk`` (signatures below),
    ``differentiable``: ``eval_pt`` accepts ``mf_sample=`` (docs/gradients.md), and ``needs_local_arrays``: it
    keeps a ``dr.alloc_local`` buffer, which drjit 1.5's LLVM backend cannot compile inside a symbolic call
    (jit/bsdf.py refuses it in scenes; docs/engines.md); ``direction_distributions``: as ``ConductorWalk``'s."""

    def __init__(self, eval_pt, sample_walk, differentiable=False, needs_local_arrays=False,
                 direction_distributions=()):
        self.eval_pt, self.sample_walk = eval_pt, sample_walk
        self.differentiable = differentiable
        self.needs_local_arrays = needs_local_arrays
        self.direction_distributions = tuple(direction_distributions)


class DielectricWalk(_Walk):
    """A dielectric random-walk model (``eta`` the relative IOR η_int/η_ext, a Python float or mi.Float;
    ``radiance`` a Python bool, Mitsuba's transport mode; values are one channel, mi.Float):

    - ``eval_pt(mf, eta, radiance, wi, wo, max_bounces, key)`` → one estimate of f·|cos θ_o|;
    - ``sample_walk(mf, eta, radiance, wi, sample1, u1, u2, max_bounces, key)`` → (ω_o, weight, valid).

    Its MIS density is ``mis.dielectric_pdf`` (the single-scattering density mixed with a cosine lobe).
    - ``differentiable``: ``eval_pt`` accepts ``mf_sample=`` (docs/gradients.md);
    - ``eta_differentiable``: its derivative in ``eta`` is unbiased too (docs/gradients.md, "The IOR of the
      glass walks"); otherwise a call with ``eta`` differentiated refuses;
    - ``direction_distributions``: the distributions for which that traced ``eval_pt`` also differentiates
      through ω_i and ω_o (it accepts ``direction_tangent=``; docs/gradients.md, "Directions through the walks").
    """

    def __init__(self, eval_pt, sample_walk, differentiable=False, eta_differentiable=False,
                 direction_distributions=()):
        super().__init__(eval_pt, sample_walk, differentiable, direction_distributions=direction_distributions)
        self.eta_differentiable = eta_differentiable


class DiffuseWalk(_Walk):
    """A walk on a microsurface of Lambertian facets (``albedo`` mi.Spectrum):

    - ``eval_pt(mf, albedo, wi, wo, max_bounces, key)`` → one estimate of f·cos θ_o (mi.Spectrum);
    - ``sample_walk(mf, albedo, wi, sample1, u1, u2, max_bounces, key)`` → (ω_o, weight, valid).

    Its MIS density is a cosine lobe.
    - ``differentiable``: ``eval_pt`` accepts ``mf_sample=`` (docs/gradients.md);
    - ``direction_distributions``: as ``ConductorWalk``'s.
    """
