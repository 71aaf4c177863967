"""What the Dr.Jit engine runs, and how one BSDF call reaches a model: twin of ``src/bsdf.rs``.

The table of what runs (``ENGINE_MODELS``, ``bdpt_models``, ``DIFFERENTIABLE_MODELS``; each model module
provides its own entries, checked at import against the core's table of names, ``msx.names``), the refusals
of what does not (one line each), and the per-surface adapters (``ConductorModel``, ``DielectricModel``,
``DiffuseModel``) that turn one call (``Call``) into a model's value, density or sample, with Mitsuba's tints
applied. The Mitsuba class that builds on them is ``plugin/jit_bsdf.py``: data flows from ``plugin/`` to
``jit/``, never back.

Everything here is traced: Mitsuba calls the class's methods once per kernel with symbolic arrays, and the
models' walks become loops inside the integrator's kernel. Nothing here changes drjit's flags, except while a
differentiated walk is recorded: ``OptimizeLoops`` is off in that scope and restored on leaving it
(jit/gradients.py, ``attach`` and ``recording``).
"""

import drjit as dr
import mitsuba as mi

from ..names import MODEL_INFO, PLUGIN
from . import analytic, auto, gradients, heitz, invariance, mis, posfree, posfree_dielectric
from .microfacet import ConductorFresnel
from .posfree import CORRELATED
from .rng import clean_uniform

# The random walks of the engine, by surface and model name: each model module provides its own table.
CONDUCTOR_WALKS = {**posfree.CONDUCTOR_WALKS, **heitz.CONDUCTOR_WALKS, **invariance.CONDUCTOR_WALKS}
CONDUCTOR_ANALYTIC = {**analytic.CONDUCTOR_ANALYTIC}
DIELECTRIC_ANALYTIC = {**analytic.DIELECTRIC_ANALYTIC}
DIELECTRIC_WALKS = {**posfree_dielectric.DIELECTRIC_WALKS, **heitz.DIELECTRIC_WALKS, **invariance.DIELECTRIC_WALKS}
DIFFUSE_WALKS = {**posfree.DIFFUSE_WALKS, **heitz.DIFFUSE_WALKS, **invariance.DIFFUSE_WALKS}


def _check_names(surface, models):
    """The engine's names are the core's (its table of names, src/config.rs via ``msx.names.MODEL_INFO``): a
    model the engine runs on a surface is one the core implements there."""
    for name in models:
        info = MODEL_INFO.get(name)
        if info is None or surface not in info.surfaces:
            raise RuntimeError("msx.jit: the engine runs model %r on surface '%s', which the core's table of names "
                               "does not list there (its models there: %s)"
                               % (name, surface, ", ".join(n for n, c in MODEL_INFO.items() if surface in c.surfaces)))
    return models


def _with_auto(models):
    """``auto`` runs wherever the model it shortcuts (``correlated``, the table's ``runs``) does: it is that
    model with a per-lane bounce cap (jit/auto.py)."""
    return models + (("auto",) if MODEL_INFO["auto"].runs in models else ())


# The models the engine runs, per surface (the others are refused with a message naming the alternatives).
ENGINE_MODELS = {
    "conductor": _check_names("conductor", _with_auto(tuple(CONDUCTOR_ANALYTIC) + tuple(CONDUCTOR_WALKS))),
    "dielectric": _check_names("dielectric", _with_auto(tuple(DIELECTRIC_ANALYTIC) + tuple(DIELECTRIC_WALKS))),
    "diffuse": _check_names("diffuse", _with_auto(tuple(DIFFUSE_WALKS))),
}

# While a walk is differentiated, the eval key sees ω_o on this grid (``_eval_key``).
WO_KEY_GRID = 1024.0

# Largest material value the core accepts (src/bsdf.rs, MATERIAL_VALUE_MAX).
MATERIAL_VALUE_MAX = 1e4
# Bounce cap when the scene sets none (the core's MSX_DEFAULT_MAX_BOUNCES).
DEFAULT_MAX_BOUNCES = 64
# |η − 1| below which an interface is index-matched and does not scatter (src/bsdf.rs, INDEX_MATCHED).
INDEX_MATCHED = 1e-6


def bdpt_models(surface):
    """The models whose bidirectional estimator the engine runs on a surface."""
    walks = CONDUCTOR_WALKS if surface == "conductor" else {}
    return tuple(name for name, w in walks.items() if getattr(w, "eval_bdpt", None) is not None)


# Walks that keep per-path arrays in dr.alloc_local: drjit 1.5's LLVM backend fails to compile a local
# array inside a symbolic call ("use of undefined value '%arr_1'", then an abort), and Mitsuba calls every
# BSDF through one, so a scene cannot use them (docs/engines.md, "What runs where").
WALKS_BY_SURFACE = {"conductor": CONDUCTOR_WALKS, "dielectric": DIELECTRIC_WALKS, "diffuse": DIFFUSE_WALKS}


# Direct calls of a BSDF's methods (outside a render: tests, studies) compile local arrays fine; setting
# this to True lets such walks load for them.
ALLOW_LOCAL_ARRAYS = False


def needs_local_arrays(cfg):
    walk = WALKS_BY_SURFACE.get(cfg.surface, {}).get(walk_name(cfg))
    return bool(getattr(walk, "needs_local_arrays", False)) and not ALLOW_LOCAL_ARRAYS


# What a user can do instead, ending every refusal.
ALTERNATIVES = ("render it in a scalar variant (scalar_rgb: the native back end), or register the batched route, "
                "msx.register(backend='batched'), which turns drjit's symbolic loops off for the process")


def engine_support(cfg):
    """None when the engine runs this configuration, else the message that says what to do instead."""
    if needs_local_arrays(cfg):
        return ("%s: model='%s' on surface '%s' keeps per-path arrays (dr.alloc_local), which drjit 1.5's LLVM "
                "backend cannot compile inside Mitsuba's BSDF calls; %s" % (PLUGIN, cfg.model, cfg.surface,
                                                                            ALTERNATIVES))
    models = ENGINE_MODELS.get(cfg.surface, ())
    if cfg.model in models and cfg.estimator == "pt":
        return None
    if cfg.estimator == "bdpt" and cfg.model in bdpt_models(cfg.surface):
        return None
    what = "model='%s'" % cfg.model if cfg.estimator == "pt" else "model='%s' with estimator='%s'" % (
        cfg.model, cfg.estimator)
    runs = ", ".join(models) if models else "none yet"
    bdpt = bdpt_models(cfg.surface)
    return ("%s: %s on surface '%s' does not run in the Dr.Jit engine of the vectorized variants yet (there, "
            "surface '%s' runs: %s with estimator 'pt'%s); %s"
            % (PLUGIN, what, cfg.surface, cfg.surface, runs,
               ", and %s with 'bdpt'" % ", ".join(bdpt) if bdpt else "", ALTERNATIVES))


# The models whose gradients the engine computes: the closed forms, differentiated by drjit's AD as they
# are, and the walks whose eval draws its directions detached (``differentiable``,
# jit/gradients.py). AD of any other walk as written is biased (its random decisions depend on the
# parameters; docs/gradients.md): such a model refuses to be differentiated rather than return a wrong
# gradient.
# ``auto`` differentiates where the walk it runs does: its per-lane bounce cap is piecewise constant in α,
# and its derivative is that of the piece a lane is on (the jump at the rule's threshold is a discontinuity
# of the model in α, which a gradient does not see, as prb does not see a visibility edge).
DIFFERENTIABLE_MODELS = {
    surface: (tuple(analytic) + tuple(n for n, w in walks.items() if w.differentiable)
              + (("auto",) if getattr(walks.get("correlated"), "differentiable", False) else ()))
    for surface, analytic, walks in (("conductor", CONDUCTOR_ANALYTIC, CONDUCTOR_WALKS),
                                     ("dielectric", DIELECTRIC_ANALYTIC, DIELECTRIC_WALKS),
                                     ("diffuse", {}, DIFFUSE_WALKS))
}


def differentiable_walk(cfg):
    """The walk whose PT estimate the engine differentiates (jit/gradients.py), or None."""
    walk = WALKS_BY_SURFACE.get(cfg.surface, {}).get(walk_name(cfg))
    if walk is None or not walk.differentiable:
        return None
    # BDPT differentiates with its PT walk's derivative estimate (ConductorModel.differentiable_estimate).
    return walk if cfg.estimator == "pt" or getattr(walk, "eval_bdpt", None) is not None else None


def gradient_problem(cfg):
    """None when the engine differentiates this configuration, else the one-line message of the refusal."""
    models = DIFFERENTIABLE_MODELS.get(cfg.surface, ())
    is_walk = walk_name(cfg) in WALKS_BY_SURFACE.get(cfg.surface, {})
    if cfg.model in models and (not is_walk or differentiable_walk(cfg) is not None):
        return None
    where = ", ".join("%s (%s)" % (", ".join(m), surface) for surface, m in DIFFERENTIABLE_MODELS.items() if m)
    where += " — the walks with estimator 'pt', and 'bdpt' where the engine runs it"
    return ("%s: model='%s' on surface '%s' is not differentiable: gradients of its random walk are not "
            "implemented (docs/gradients.md); the differentiable models are %s — or keep this BSDF's parameters "
            "out of the gradient (dr.disable_grad)" % (PLUGIN, cfg.model, cfg.surface, where))


def eta_gradient_problem(cfg):
    """None unless ``cfg`` is a random walk through the dielectric whose derivative in ``eta`` is not
    unbiased (its walk's ``eta_differentiable`` is false): in the space of directions such a walk draws from,
    the density of a refracted direction jumps to zero where the generalized half-vector turns horizontal
    (GGX's D there is α²/π, not 0), that edge moves with η, and a score-function estimate misses its term
    (measured: docs/gradients.md, "The IOR of the glass walks"). Their α differentiates."""
    walk = WALKS_BY_SURFACE.get("dielectric", {}).get(walk_name(cfg)) if cfg.surface == "dielectric" else None
    if walk is None or walk.eta_differentiable:
        return None
    able = ", ".join(m for m in DIFFERENTIABLE_MODELS["dielectric"]
                     if getattr(WALKS_BY_SURFACE["dielectric"].get(walk_name_of(m)), "eta_differentiable", True))
    return ("%s: model='%s' on surface 'dielectric' is not differentiable in 'eta': this walk's derivative "
            "in the IOR would be biased (docs/gradients.md); its 'alpha' is differentiable, and %s differentiate "
            "in 'eta' — or keep 'eta' out of the gradient (dr.disable_grad)" % (PLUGIN, cfg.model, able))


def directions_differentiable(cfg):
    """Whether the walk ``cfg`` runs differentiates through ω_i and ω_o without bias (its traced PT estimate:
    the normals drawn detached, the directions reflected about them attached; docs/gradients.md,
    "Directions through the walks")."""
    walk = differentiable_walk(cfg)
    return walk is not None and cfg.distribution in getattr(walk, "direction_distributions", ())


def _direction_walks():
    """'model (surface, distribution)' of every walk configuration that differentiates through directions."""
    out = []
    for surface, walks in WALKS_BY_SURFACE.items():
        for name, walk in walks.items():
            dists = getattr(walk, "direction_distributions", ()) if walk.differentiable else ()
            if dists:
                runs_it = [m for m in ENGINE_MODELS.get(surface, ()) if walk_name_of(m) == name]
                out.append("%s (%s, %s)" % ("/".join(runs_it), surface, "/".join(dists)))
    return "; ".join(out)


def differentiate_directions_problem(cfg):
    """None unless ``differentiate_directions`` is set on a walk whose derivative through directions would be
    biased (refused when the scene loads, every route)."""
    if not cfg.differentiate_directions or walk_name(cfg) not in WALKS_BY_SURFACE.get(cfg.surface, {}):
        return None
    if directions_differentiable(cfg):
        return None
    return ("%s: differentiate_directions=true is not available for model='%s' on surface '%s' (distribution "
            "'%s'): the derivative of this walk with respect to the directions is not implemented "
            "(docs/gradients.md); the walks that have it: %s; the closed forms (single, fastmsx, compensated) "
            "differentiate through directions without it"
            % (PLUGIN, cfg.model, cfg.surface, cfg.distribution, _direction_walks()))


def direction_gradient_problem(cfg):
    """None unless ``cfg`` runs a random walk that cannot take directions carrying a gradient, else the one-line
    refusal.

    A walk differentiates through ω_i and ω_o (a differentiated shading normal — Mitsuba's ``normalmap``,
    ``bumpmap`` — or differentiated geometry) where ``directions_differentiable`` and the scene asks for it
    with ``differentiate_directions``: then ``sample`` draws from the proposal whose density it reports, which
    is what ``prb``'s re-evaluation of the BSDF along a replayed path needs (docs/gradients.md). Elsewhere AD
    of the walk as written is biased (measured: GGX α 1, F = 1, ``correlated`` −0.086 against −0.131 ± 0.002
    by central differences; ``heitz`` −0.121 against −0.226 ± 0.003). The closed forms differentiate through
    directions exactly."""
    if walk_name(cfg) not in WALKS_BY_SURFACE.get(cfg.surface, {}):
        return None
    if directions_differentiable(cfg):
        if cfg.differentiate_directions:
            return None
        return ("%s: model='%s' on surface '%s' received directions that carry a gradient (a differentiated "
                "shading normal such as normalmap/bumpmap, or differentiated geometry); set "
                "<boolean name=\"differentiate_directions\" value=\"true\"/> on this BSDF so that its sampling "
                "pairs with the derivative (docs/gradients.md) — or keep the normals and geometry out of the "
                "gradient (dr.disable_grad)" % (PLUGIN, cfg.model, cfg.surface))
    closed = ", ".join(m for m in DIFFERENTIABLE_MODELS.get(cfg.surface, ()) if walk_name_of(m) not in
                       WALKS_BY_SURFACE.get(cfg.surface, {}))
    return ("%s: model='%s' on surface '%s' (distribution '%s') received directions that carry a gradient (a "
            "differentiated shading normal such as normalmap/bumpmap, or differentiated geometry); the derivative "
            "of its random walk with respect to the directions is not available and would be biased "
            "(docs/gradients.md) — use %s, a walk that has it (%s) with differentiate_directions=true, or keep "
            "the normals and geometry out of the gradient (dr.disable_grad)"
            % (PLUGIN, cfg.model, cfg.surface, cfg.distribution,
               "model=" + " or ".join("'%s'" % m for m in closed.split(", ")) if closed else "a scalar variant",
               _direction_walks()))


def moving_directions(problem, *directions):
    """Whether a configuration with a ``direction_gradient_problem`` received a direction attached to the AD
    graph (the class then refuses with the problem's line)."""
    return problem is not None and any(dr.grad_enabled(d) for d in directions)


# The smallest normal float32. A walk's estimate can be subnormal (a product of many small factors: 415 of
# 3·10⁶ samples of ``heitz`` on Lambertian facets), and prb divides by the sample's weight × pdf: 1/x of a
# subnormal overflows to ∞ and the gradient gets ∞ · 0 = NaN (seen with drjit's thread count 1, whose
# kernels run on the calling thread; docs/gradients.md). Values below it carry no visible energy: returned as 0.
FLT_MIN = 1.1754944e-38


def flush_subnormal(value):
    """``value`` with its subnormal channels set to 0 (FLT_MIN above)."""
    return dr.select(dr.abs(value) >= FLT_MIN, value, 0.0)


def walk_name_of(model):
    """The walk ``model`` runs (``walk_name``)."""
    info = MODEL_INFO.get(model)
    return info.runs if info is not None else model


def walk_name(cfg):
    """The walk a model runs (the table's ``runs``): ``auto`` is ``correlated`` with a per-lane bounce cap."""
    return walk_name_of(cfg.model)


class Call:
    """What one BSDF call gives a model (twin of ``Call`` in src/models/mod.rs): the microfacet statistics
    and the microsurface's material at the hit, Mitsuba's tints, the transport mode and whether the
    material is usable (``Material::usable``)."""

    def __init__(self, mf, usable, fresnel=None, eta=None, radiance=True, albedo=None, tint_r=None, tint_t=None):
        self.mf, self.usable, self.fresnel, self.eta, self.radiance = mf, usable, fresnel, eta, radiance
        self.albedo, self.tint_r, self.tint_t = albedo, tint_r, tint_t
        # While a differentiable walk's parameters carry gradients (jit/gradients.py): the α values as
        # the textures gave them (one for an isotropic surface) and the sampling mode that goes with them.
        self.alphas, self.traced = None, False


class ConductorModel:
    """An analytic conductor model (``single``, ``fastmsx``, ``compensated``) or a conductor walk with
    its MIS density."""

    def __init__(self, cfg):
        self.walk = CONDUCTOR_WALKS.get(walk_name(cfg))  # None: an analytic model
        self.analytic = CONDUCTOR_ANALYTIC.get(cfg.model)
        self.estimate = None
        if self.walk is not None:
            self.estimate = self.walk.eval_bdpt if cfg.estimator == "bdpt" else self.walk.eval_pt
        self.max_bounces = cfg.max_bounces or DEFAULT_MAX_BOUNCES
        self.rule = auto.OrderOneRule("conductor", cfg.distribution, cfg.auto_tolerance) if cfg.model == "auto" else None
        # The walks' MIS density (``mis.conductor_pdf``); differentiated walks sample their proposal instead and
        # report its own density (jit/gradients.py).
        self.mis_density = cfg.mis_density

    def bounces(self, call, wi):
        """The bounce cap of each lane (``auto``: 1 where order 1 suffices; ω_i below: the full model)."""
        if self.rule is None:
            return self.max_bounces
        return auto.cap(self.rule, call.mf, wi[2], self.max_bounces, full=wi[2] >= 0.0)

    def eval_pdf(self, call, wi, wo, key, want_value=True, want_pdf=True):
        walk, mf = self.walk, call.mf
        if walk is None:
            value, pdf = self.analytic.eval_pdf(mf, call.fresnel, wi, wo)
        elif call.traced:
            value = self.differentiable_estimate(call, wi, wo, key) if want_value else None
            pdf = gradients.proposal_pdf(walk.exit, mf, wi, wo) if want_pdf else None
        elif self.rule is not None:
            value, pdf = self.auto_eval_pdf(call, wi, wo, key, want_value, want_pdf)
        else:
            value = self.estimate(mf, call.fresnel, wi, wo, self.bounces(call, wi), key) if want_value else None
            pdf = mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo, self.mis_density) if want_pdf else None
        return (value * call.tint_r if want_value else None), pdf

    def auto_eval_pdf(self, call, wi, wo, key, want_value, want_pdf):
        """``auto``'s (value, pdf) (either None where not wanted): order 1 in closed form with its sampler's
        density on the lanes the rule reduces (src/models/auto/mod.rs), the full walk and the walks' MIS
        density elsewhere — behind a symbolic if, so that a packet whose lanes all reduce runs no walk. A lane
        whose ω_o is not above the surface takes the closed form too: both give 0 there (the PT walk does not
        start, the MIS density is 0; auto runs the PT estimator only), and an emitter sample below the surface
        then makes no packet walk."""
        walk, mf = self.walk, call.mf
        one = auto.order_one(self.rule, mf, wi[2], full=wi[2] > 0.0, lanes=key) | ~(wo[2] > 0.0)
        auto.record_branch(one)
        closed = (lambda: auto.order_one_eval(mf, call.fresnel, wi, wo), lambda: auto.order_one_pdf(mf, wi, wo))
        full = (lambda: self.estimate(mf, call.fresnel, wi, wo, self.max_bounces, key),
                lambda: mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo, self.mis_density))
        return auto.eval_pdf(one, closed, full, want_value, want_pdf, "msx_auto_order_one")

    def differentiable_estimate(self, call, wi, wo, key):
        """The walk's PT estimate with its derivative in α, η and k (jit/gradients.py), and in the
        components of ω_i and ω_o where they carry gradients (``direction_gradient_problem`` has let them in
        only where the walk's derivative through them is unbiased)."""
        fresnel, bounces = call.fresnel, self.bounces(dr.detach(call), dr.detach(wi))
        material_values = [] if fresnel.mirror else [fresnel.eta, fresnel.k]
        n_material = len(material_values)

        def material(eta_k):
            return fresnel if fresnel.mirror else ConductorFresnel(*eta_k)

        moving = gradients.TangentCoordinates(wi, wo)

        def split(values):
            """(material values, ω_i, ω_o) from the values ``attach`` passes: the material, then the directions'
            tangent coordinates."""
            return (values[:n_material],) + moving.directions(values[n_material:])

        def run(m, m_sample, *values):
            eta_k, wi_, wo_ = split(values)
            tangent = moving.tangent(values[n_material:])
            return self.walk.eval_pt(m, material(eta_k), wi_, wo_, bounces, key, mf_sample=m_sample,
                                     **({"direction_tangent": tangent} if tangent is not None else {}))

        # BDPT: its own estimate as the value, the PT walk's derivative (both unbiased; docs/gradients.md).
        primal = None
        if self.estimate is not self.walk.eval_pt:
            def primal(m, *values):
                eta_k, wi_, wo_ = split(values)
                return self.estimate(m, material(eta_k), wi_, wo_, bounces, key)

        return gradients.attach_walk(call, material_values + moving.values, run, primal)

    def sample_traced(self, call, wi, s1, u1, u2, eval_key):
        """``sample`` while differentiated: ω_o from the proposal, weighed by the walk's estimate there (the
        one ``eval`` gives, lane key ``eval_key(ω_o)``) over the proposal's density. ω_o is drawn with ω_i and
        the parameters detached, and the weight is ``eval``'s differentiable estimate over that detached
        density: its derivative is that of ∫ f·L dω_o by a detached draw (docs/gradients.md), in the
        parameters and in ω_i. (The walk as written, read inside a symbolic call, would drop its parameters'
        derivatives: they come from outside its loop.)"""
        walk, mf = self.walk, call.mf
        wo, pdf, valid = gradients.proposal_sample(walk.exit, mf, dr.detach(wi), s1, u1, u2)
        pdf = dr.detach(pdf)
        value = self.differentiable_estimate(call, wi, wo, eval_key(wo))
        weight = dr.select(valid & (pdf > 0.0), value / pdf, 0.0)
        return wo, pdf, weight * call.tint_r, valid

    def sample(self, call, wi, s1, u1, u2, key):
        """(ω_o, pdf, weight, valid)."""
        walk, mf = self.walk, call.mf
        if walk is None:
            wo, pdf, weight, valid = self.analytic.sample(mf, call.fresnel, wi, u1, u2)
        elif self.rule is not None:
            # auto: the walk's first vertex on every lane, order 1 in closed form from it where it suffices, the
            # rest of the walk behind a per-packet branch (jit/auto.py ``sample``).
            one = auto.order_one(self.rule, mf, wi[2], full=wi[2] > 0.0, site=1, lanes=key)
            wo, pdf, weight, valid = auto.sample(
                mf, call.fresnel, wi, s1, u1, u2, one, self.max_bounces, key,
                lambda wo: mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo, self.mis_density))
        else:
            wo, weight, valid = walk.sample_walk(mf, call.fresnel, wi, s1, u1, u2, self.bounces(call, wi), key)
            pdf = mis.conductor_pdf(walk.exit, walk.below, mf, wi, wo, self.mis_density)
        return wo, pdf, weight * call.tint_r, valid


class DielectricModel:
    """``single`` (Mitsuba's roughdielectric) or a dielectric walk with its MIS density; values are one
    channel, tinted by ``specular_reflectance`` or ``specular_transmittance``."""

    def __init__(self, cfg):
        self.walk = DIELECTRIC_WALKS.get(walk_name(cfg))  # None: an analytic model
        self.analytic = DIELECTRIC_ANALYTIC.get(cfg.model)
        self.analytic_single = DIELECTRIC_ANALYTIC["single"]  # the sampler of the walks' MIS density
        self.max_bounces = cfg.max_bounces or DEFAULT_MAX_BOUNCES
        # auto: the rule at the relative IOR seen from ω_i (η outside, 1/η inside).
        self.rule = auto.SidedRule(cfg.distribution, cfg.auto_tolerance, cfg.ior) if cfg.model == "auto" else None

    def bounces(self, call, wi):
        if self.rule is None:
            return self.max_bounces
        return auto.cap(self.rule, call.mf, wi[2], self.max_bounces)

    @staticmethod
    def tinted(call, wi, wo, value):
        return mi.Spectrum(value) * dr.select(wi[2] * wo[2] > 0.0, call.tint_r, call.tint_t)

    def eval_pdf(self, call, wi, wo, key, want_value=True, want_pdf=True):
        walk, mf, eta = self.walk, call.mf, call.eta
        value = pdf = None
        if self.rule is not None and not call.traced:
            value, pdf = self.auto_eval_pdf(call, wi, wo, key, want_value, want_pdf)
            return (self.tinted(call, wi, wo, value) if want_value else None), pdf
        if want_value:
            if walk is None:
                value = self.analytic.eval(mf, eta, call.radiance, wi, wo)
            elif call.traced:
                value = self.differentiable_estimate(call, wi, wo, key)
            else:
                value = walk.eval_pt(mf, eta, call.radiance, wi, wo, self.bounces(call, wi), key)
            value = self.tinted(call, wi, wo, value)
        if want_pdf:
            if walk is None:
                pdf = self.analytic.pdf(mf, eta, wi, wo)
            elif call.traced:  # the proposal's density, detached as the proposal is
                pdf = mis.dielectric_pdf(gradients.detached(mf), dr.detach(eta), wi, wo)
            else:
                pdf = mis.dielectric_pdf(mf, eta, wi, wo)
        return value, pdf

    def auto_eval_pdf(self, call, wi, wo, key, want_value, want_pdf):
        """``auto``'s (value, pdf) (either None where not wanted), untinted: order 1 in closed form with the
        density of the walk's first vertex on the lanes the rule reduces (either side of the surface;
        src/models/auto/mod.rs), the full walk and the walks' MIS density elsewhere — behind a symbolic if
        (``auto.eval_pdf``), so that a packet whose lanes all reduce runs no walk."""
        walk, mf, eta = self.walk, call.mf, call.eta
        one = auto.order_one(self.rule, mf, wi[2], lanes=key)
        auto.record_branch(one)
        closed = (lambda: posfree_dielectric.order_one_eval(CORRELATED, mf, eta, call.radiance, wi, wo),
                  lambda: posfree_dielectric.order_one_pdf(mf, eta, wi, wo))
        full = (lambda: walk.eval_pt(mf, eta, call.radiance, wi, wo, self.max_bounces, key),
                lambda: mis.dielectric_pdf(mf, eta, wi, wo))
        return auto.eval_pdf(one, closed, full, want_value, want_pdf, "msx_auto_order_one_dielectric")

    def differentiable_estimate(self, call, wi, wo, key):
        """The walk's PT estimate with its derivative in α and η (jit/gradients.py), and in ω_i and ω_o where
        they carry gradients (as ``ConductorModel.differentiable_estimate``)."""
        bounces = self.bounces(call, dr.detach(wi))
        if not (dr.grad_enabled(wi) or dr.grad_enabled(wo)):  # the walk as it was without moving directions
            def run(m, m_sample, eta):
                return self.walk.eval_pt(m, eta, call.radiance, wi, wo, bounces, key, mf_sample=m_sample)

            return gradients.attach_walk(call, [call.eta], run)
        moving = gradients.TangentCoordinates(wi, wo)

        def run(m, m_sample, eta, *coords):
            wi_, wo_ = moving.directions(coords)
            tangent = moving.tangent(coords)
            return self.walk.eval_pt(m, eta, call.radiance, wi_, wo_, bounces, key, mf_sample=m_sample,
                                     **({"direction_tangent": tangent} if tangent is not None else {}))

        return gradients.attach_walk(call, [call.eta] + moving.values, run)

    def sample_traced(self, call, wi, s1, u1, u2, eval_key):
        """``sample`` while differentiated: ω_o from the MIS density (single scattering mixed with a cosine
        lobe on both sides, drawn exactly), weighed by the walk's estimate there (the one ``eval`` gives,
        lane key ``eval_key(ω_o)``) over that density. Drawn and weighed with the parameters and ω_i detached:
        this weight carries no derivative (``prb`` takes its derivatives from ``eval``)."""
        mf, eta, wi = gradients.detached(call.mf), dr.detach(call.eta), dr.detach(wi)
        k = mis.diffuse_fraction(mf)
        cosine = s1 < k
        # s1 rescaled within its branch: the cosine lobe's side, or the single sampler's own choice.
        r = dr.select(cosine, s1 / k, (s1 - k) / (1.0 - k))
        r = clean_uniform(r)
        wo_s, _, w_s, valid_s = self.analytic_single.sample(mf, eta, call.radiance, wi, r, u1, u2)
        # A reflection that ends below the surface (or a refraction above) has weight 0 (G1(ω_o, m) = 0) and
        # is not part of the density single's pdf gives: it is dropped, so the drawn directions have that
        # density.
        valid_s &= w_s > 0.0
        wo_c = mi.warp.square_to_cosine_hemisphere(mi.Point2f(u1, u2))
        wo_c = mi.Vector3f(wo_c[0], wo_c[1], dr.select(r < 0.5, wo_c[2], -wo_c[2]))
        wo = dr.select(cosine, wo_c, wo_s)
        pdf = mis.dielectric_pdf(mf, eta, wi, wo)
        # The differentiated walk's own estimate (its draws differ from the plain walk's: the position-free
        # walks draw normals and choices otherwise while differentiated), with the parameters detached.
        with gradients.recording():
            value = self.walk.eval_pt(mf, eta, call.radiance, wi, wo, self.bounces(call, wi), eval_key(wo),
                                      mf_sample=mf)
        valid = (cosine | valid_s) & (wo[2] != 0.0) & (pdf > 0.0)
        return wo, pdf, self.tinted(call, wi, wo, dr.select(valid, value / pdf, 0.0)), valid

    def sample(self, call, wi, s1, u1, u2, key):
        walk, mf, eta = self.walk, call.mf, call.eta
        if walk is None:
            wo, pdf, weight, valid = self.analytic.sample(mf, eta, call.radiance, wi, s1, u1, u2)
        elif self.rule is not None:
            # auto: the walk's first vertex on every lane, order 1 in closed form from it where it suffices, the
            # rest of the walk elsewhere, each only in packets that have lanes of it (a packet of both kinds
            # draws the first normal once).
            first = posfree_dielectric.sample_first_vertex(mf, eta, wi, s1, u1, u2, key)

            def reduced(first):
                return posfree_dielectric.order_one_finish(CORRELATED, mf, eta, call.radiance, wi, first)

            def walking(first):
                wo, weight, valid = walk.sample_walk(mf, eta, call.radiance, wi, s1, u1, u2, self.max_bounces, key,
                                                     first_vertex=first)
                return wo, mis.dielectric_pdf(mf, eta, wi, wo), weight, valid

            wo, pdf, weight, valid = dr.if_stmt((first,), auto.order_one(self.rule, mf, wi[2], site=1, lanes=key), reduced,
                                                walking, label="msx_auto_order_one_dielectric_sample")
        else:
            wo, weight, valid = walk.sample_walk(mf, eta, call.radiance, wi, s1, u1, u2, self.bounces(call, wi), key)
            pdf = mis.dielectric_pdf(mf, eta, wi, wo)
        return wo, pdf, self.tinted(call, wi, wo, weight), valid


class DiffuseModel:
    """A walk on Lambertian facets with a cosine-lobe MIS density."""

    def __init__(self, cfg):
        self.walk = DIFFUSE_WALKS[walk_name(cfg)]
        self.max_bounces = cfg.max_bounces or DEFAULT_MAX_BOUNCES
        self.rule = auto.OrderOneRule("diffuse", cfg.distribution, cfg.auto_tolerance) if cfg.model == "auto" else None

    def bounces(self, call, wi):
        if self.rule is None:
            return self.max_bounces
        return auto.cap(self.rule, call.mf, wi[2], self.max_bounces)

    def eval_pdf(self, call, wi, wo, key, want_value=True, want_pdf=True):
        value = None
        if want_value and call.traced:
            value = self.differentiable_estimate(call, wi, wo, key)
        elif want_value:
            value = self.walk.eval_pt(call.mf, call.albedo, wi, wo, self.bounces(call, wi), key)
        return value, (mis.diffuse_pdf(wi, wo) if want_pdf else None)

    def differentiable_estimate(self, call, wi, wo, key):
        """The walk's PT estimate with its derivative in α and the albedo (jit/gradients.py), and in the
        components of ω_i and ω_o where they carry gradients (as ``ConductorModel.differentiable_estimate``)."""
        bounces = self.bounces(dr.detach(call), dr.detach(wi))
        moving = gradients.TangentCoordinates(wi, wo)

        def run(m, m_sample, albedo, *coords):
            wi_, wo_ = moving.directions(coords)
            return self.walk.eval_pt(m, albedo, wi_, wo_, bounces, key, mf_sample=m_sample)

        return gradients.attach_walk(call, [call.albedo] + moving.values, run)

    def sample_traced(self, call, wi, s1, u1, u2, eval_key):
        """``sample`` while differentiated: ω_o from the cosine lobe (the MIS density, exact; it depends on
        neither ω_i nor the parameters), weighed by ``eval``'s differentiable estimate there (lane key
        ``eval_key(ω_o)``) over that density: its derivative is that of ∫ f·L dω_o, in the parameters and in
        ω_i (``ConductorModel.sample_traced``)."""
        wo = mi.warp.square_to_cosine_hemisphere(mi.Point2f(u1, u2))
        pdf = mis.diffuse_pdf(dr.detach(wi), wo)
        value = self.differentiable_estimate(call, wi, wo, eval_key(wo))
        valid = (wi[2] > 0.0) & (pdf > 0.0)
        return wo, pdf, dr.select(valid, value / pdf, 0.0), valid

    def sample(self, call, wi, s1, u1, u2, key):
        wo, weight, valid = self.walk.sample_walk(call.mf, call.albedo, wi, s1, u1, u2, self.bounces(call, wi), key)
        return wo, mis.diffuse_pdf(wi, wo), weight, valid


MODELS_BY_SURFACE = {"conductor": ConductorModel, "dielectric": DielectricModel, "diffuse": DiffuseModel}
