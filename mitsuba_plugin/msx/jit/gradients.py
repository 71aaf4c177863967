"""Gradients of the random walks in the Dr.Jit engine (docs/gradients.md, "The position-free walks").

A walk's estimate is differentiable without bias when its directions are drawn with the parameters
detached and each step carries the ratio of its density to the detached one (``posfree.pt_walk``'s
``mf_sample``). drjit differentiates that walk in forward mode through its ``dr.while_loop``; reverse mode
through the loop is not available, so :func:`attach` computes each differentiated parameter's tangent by
forward mode inside the call and returns f̄ + Σ (p − p̄)·∂f/∂p, f̄ and ∂f/∂p detached: the derivative
enters Mitsuba's graph through the parameters alone (and through the textures they come from).

Mitsuba's ``prb`` divides the re-evaluated BSDF by the sample weight × pdf of the path it replays; that is
the BSDF only if ``sample`` draws ω_o from the density it reports. So while a walk model is differentiated,
``sample`` draws ω_o from :func:`proposal_pdf` — visible-normal reflection mixed with a cosine lobe —
and weighs it by the walk's ``eval`` estimate over that density (the same estimate ``eval`` gives there),
and ``pdf`` reports the same density.
"""

import contextlib
import os

import drjit as dr
import mitsuba as mi

from . import mis
from .microfacet import INV_PI, Microfacet, reflect

# Share of the cosine lobe in the proposal, the walk's multiple-scattering mass 1 − E_1(ω_i), clamped so
# that neither lobe vanishes.
COSINE_SHARE_MIN, COSINE_SHARE_MAX = 0.05, 0.95


def clamped(dist, alpha_u, alpha_v):
    """The statistics of α values that a ``Microfacet`` has clamped already (its own, or the loop state's copy
    of them): built without clamping them again, which changes no bit of a value or of a derivative (the
    clamp is the identity there, derivative 1) but recorded three operations per α each time, in every walk
    loop body (benches/README.md, "Gradient steps of the walks ≤ 3× the built-in")."""
    if not trimmed():
        return Microfacet(dist, alpha_u, alpha_v)
    mf = Microfacet.__new__(Microfacet)
    mf.dist, mf.alpha_u, mf.alpha_v = dist, alpha_u, alpha_v
    return mf


def detached(mf):
    return clamped(mf.dist, dr.detach(mf.alpha_u), dr.detach(mf.alpha_v))


class LoopValues:
    """What a differentiated walk's ``dr.while_loop`` carries of its call, as the last entries of the loop
    state (drjit 1.5 rejects differentiable reads of wide values from outside a loop inside a symbolic call):
    α_u, α_v, Λ(ω_o) and the walk's own further values (its material, a tangent), ``rest``.
    ``LoopValues.state(mf, lambda_o, *rest)`` is what the loop starts with; ``LoopValues(dist, piped)`` in the
    loop's body gives the statistics with the parameters attached (``mf``: the walk's values) and detached
    (``mf_sample``: the walk's draws), ``lambda_o`` and ``rest``; ``piped(*rest)`` the entries again, with a
    new ``rest``."""

    def __init__(self, dist, piped):
        self.alpha_u, self.alpha_v, self.lambda_o = piped[:3]
        self.rest = tuple(piped[3:])
        self.mf = clamped(dist, self.alpha_u, self.alpha_v)
        self.mf_sample = clamped(dist, dr.detach(self.alpha_u), dr.detach(self.alpha_v))

    @staticmethod
    def state(mf, lambda_o, *rest):
        return (mf.alpha_u, mf.alpha_v, mi.Float(lambda_o)) + rest

    @staticmethod
    def unpack(traced, mf, lambda_o, rest, piped):
        """(statistics attached, detached, Λ(ω_o), rest) in a walk's loop body: the loop's entries ``piped``
        while ``traced``, else the call's own ``mf`` (both), ``lambda_o`` and ``rest``."""
        if not traced:
            return mf, mf, lambda_o, rest
        lv = LoopValues(mf.dist, piped)
        return lv.mf, lv.mf_sample, lv.lambda_o, lv.rest

    def piped(self, *rest):
        return (self.alpha_u, self.alpha_v, self.lambda_o) + rest


# Tests' record of the lanes ``attach`` drops (``record_dropped``): None, or a list of per-pass counts.
_DROPPED = [None]


def record_dropped(on=True):
    """Starts (or stops) recording, per forward pass of :func:`attach`, how many lanes had a non-finite
    derivative (set to 0 there); returns the list the counts go to (drjit scalars, evaluated when read).
    For tests: a walk's derivative should have none, and a test of it must not read only sanitised values."""
    _DROPPED[0] = [] if on else None
    return _DROPPED[0]


# How :func:`attach` arranges its work (docs/gradients.md, "What a gradient step costs"): "lean"
# records the walks' loops without drjit's loop optimisation (one recording of a loop body instead of two) and
# returns the value with the derivative attached by ``dr.replace_grad``, so that the forward pass is code of the
# kernel only where a derivative is propagated; "plain" is the arrangement before, "replace" and "noopt" each
# change alone (kept to measure against: benches/gradient_bench.py --arrangements, or the environment variable
# MSX_GRADIENT_ARRANGEMENT, read at import). "trim" (the default since 2026-11-28) is "lean" without the work a
# call records where nothing it is given is differentiated (:func:`trimmed`). All give the same values and
# derivatives; any other name is "trim".
ARRANGEMENT = os.environ.get("MSX_GRADIENT_ARRANGEMENT", "trim")


def trimmed():
    """Whether the arrangement leaves out what a call records but does not need where nothing it is given is
    differentiated ("trim", the default; not "plain", "replace", "noopt", "lean", kept to measure against): no
    tangent coordinates for directions that do not move (:class:`TangentCoordinates`), no second clamp of
    clamped α values (:func:`clamped`), the proposal's cosine share looked up once (:func:`proposal_sample`),
    and Heitz's walk on conductor and Lambertian facets run as written when traced with nothing differentiated,
    its ω_o out of the loop state when ω_o carries no derivative (``heitz.eval_from``)."""
    return ARRANGEMENT not in ("plain", "replace", "noopt", "lean")


def attach(estimate, params, primal=None):
    """``estimate(*values)`` (a Spectrum) with the derivative with respect to each of ``params`` (Floats or
    Spectra; a Spectrum parameter acts on its own channel only, as η and k do) that has gradients enabled,
    taken by forward mode inside the call; the others pass through detached. ``primal(*values)``, if given,
    is the value returned in place of the estimate's own (another unbiased estimate of the same function:
    the derivative stays the estimate's)."""
    if ARRANGEMENT == "plain":
        return _attach(estimate, params, primal, lean=False)
    if ARRANGEMENT == "replace":
        return _attach(estimate, params, primal, lean=True)
    if ARRANGEMENT == "noopt":
        with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
            return _attach(estimate, params, primal, lean=False)
    # drjit's OptimizeLoops records every loop body twice (the second time without the loop-invariant state it
    # found); the walks' invariant state is a few values, and the recording is most of a step's time at small
    # wavefronts (benches/README.md, "Gradient steps"). The flag is restored on leaving.
    with dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False):
        return _attach(estimate, params, primal, lean=True)


def recording():
    """The scope in which a differentiated walk's loops are recorded outside :func:`attach` (``sample``'s walk on
    the dielectric and diffuse surfaces, which does not go through it): ``OptimizeLoops`` off as in ``attach``,
    unless the arrangement is one that keeps it ("plain", "replace")."""
    if ARRANGEMENT in ("plain", "replace"):
        return contextlib.nullcontext()
    return dr.scoped_set_flag(dr.JitFlag.OptimizeLoops, False)


def _attach(estimate, params, primal, lean):
    values = [dr.detach(p) for p in params]
    value = None
    tangents = []
    for i, p in enumerate(params):
        if not dr.grad_enabled(p):
            continue
        with dr.isolate_grad():
            t = type(values[i])(values[i])
            dr.enable_grad(t)
            y = estimate(*[t if k == i else v for k, v in enumerate(values)])
            dr.forward_from(t, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
            g = dr.grad(y)
            # A lane whose walk degenerates (a direction exactly along the normal meets a horizontal facet,
            # weight 0) can carry 0·∞ in its derivative: such a lane contributes nothing, and 0 is its value.
            if _DROPPED[0] is not None:
                _DROPPED[0].append(dr.count(~dr.all(dr.isfinite(g))))
            g = dr.select(dr.isfinite(g), g, 0.0)
        value = dr.detach(y)
        tangents.append((p - values[i]) * dr.detach(g))
    if value is None:
        return estimate(*values) if primal is None else primal(*values)
    if primal is not None:
        value = dr.detach(primal(*values))
    attached = value
    for t in tangents:
        attached = attached + t
    if not lean:
        return attached
    # The value's own variable, with the tangents' derivative: (θ − θ̄)·g is 0 in value, and as a term of the
    # value it made the forward passes part of every kernel that reads the value (in prb's adjoint pass, the
    # recording of the BSDF call that gives the value, besides the one that propagates its derivative).
    return dr.replace_grad(value, attached)


def attach_walk(call, material, run, primal=None):
    """A walk's PT estimate with its derivative in the call's α values and in ``material`` (a list of the
    material values the walk takes after the statistics, as in the call): ``run(mf, mf_sample, *material)``
    evaluates the walk with the statistics ``mf`` built from the differentiated α and draws its directions
    from their detached copy ``mf_sample`` (docs/gradients.md). ``primal(mf, *material)``, if given, is the
    value returned instead of the PT estimate's (the BDPT estimate: its value with the PT walk's
    derivative, both unbiased)."""
    mf, n_alpha = call.mf, len(call.alphas)

    def split(values):
        au, av = (values[0], values[0]) if n_alpha == 1 else values[:2]
        return Microfacet(mf.dist, au, av), values[n_alpha:]

    def estimate(*values):
        m, rest = split(values)
        return run(m, detached(m), *rest)

    def value(*values):
        m, rest = split(values)
        return primal(m, *rest)

    return attach(estimate, list(call.alphas) + list(material), None if primal is None else value)


class TangentCoordinates:
    """The moving part of unit directions as parameters for :func:`attach`: a unit direction moves in its
    tangent plane, so its derivative is carried by two coordinates s = (ω − ω̄)·t along a basis (t, b) of that
    plane at the detached ω̄ (value 0; they carry ω's gradient), and a moving direction costs two forward passes
    of a walk, not three. ``values`` are the coordinates (two per direction); ``directions(coords)`` rebuilds
    the directions ω̄ + s_t·t + s_b·b from the values ``attach`` passes (equal to the directions in value)."""

    def __init__(self, *directions):
        self.values = []
        if trimmed() and not any(dr.grad_enabled(d) for d in directions):
            # No direction moves (α or the material differentiated alone, and every call with gradients
            # suspended): no coordinates, and the walks get the directions themselves, not ω̄ + 0·t + 0·b —
            # the frames and the rebuilt directions were recorded in every call (benches/README.md, "Gradient
            # steps of the walks ≤ 3× the built-in").
            self.frames, self.fixed = None, directions
            return
        self.frames = [(dr.detach(d), mi.Frame3f(dr.detach(d))) for d in directions]
        for d, (base, fr) in zip(directions, self.frames):
            offset = d - base
            self.values += [dr.dot(offset, fr.s), dr.dot(offset, fr.t)]

    def directions(self, coords):
        if self.frames is None:
            return self.fixed
        return tuple(base + coords[2 * k] * fr.s + coords[2 * k + 1] * fr.t
                     for k, (base, fr) in enumerate(self.frames))

    def tangent(self, coords):
        """(s, tangents of the directions in s) while one coordinate s among ``coords`` is differentiated
        (attach's forward pass over it), else None."""
        for i, c in enumerate(coords):
            if dr.grad_enabled(c):
                k, basis = divmod(i, 2)
                zero = mi.Vector3f(0.0)
                t = self.frames[k][1].t if basis else self.frames[k][1].s
                return (c,) + tuple(t if n == k else zero for n in range(len(self.frames)))
        return None


def cosine_share(exit, mf, wi):
    e1 = mis._e1_table(exit, mf.dist).at(dr.sqrt(mf.alpha_u * mf.alpha_v), dr.abs(wi[2]))
    return dr.detach(dr.clip(1.0 - e1, COSINE_SHARE_MIN, COSINE_SHARE_MAX))


def proposal_pdf(exit, mf, wi, wo, c=None):
    """The density ``sample`` draws ω_o from while differentiated: (1 − c)·D_ωi reflection + c·cos/π (``c``: the
    cosine share when the caller has it)."""
    mf = detached(mf)
    c = cosine_share(exit, mf, wi) if c is None or not trimmed() else c
    pdf = (1.0 - c) * mf.reflect_pdf(wi, wo) + c * dr.maximum(wo[2], 0.0) * INV_PI
    return dr.select((wo[2] > 0.0) & (wi[2] > 0.0), pdf, 0.0)


def proposal_sample(exit, mf, wi, sample1, u1, u2):
    """(ω_o, pdf, valid) from :func:`proposal_pdf`."""
    mf = detached(mf)
    c = cosine_share(exit, mf, wi)
    cosine = sample1 < c
    m, valid_m = mf.sample_visible(wi, u1, u2)
    wo = dr.select(cosine, mi.warp.square_to_cosine_hemisphere(mi.Point2f(u1, u2)), reflect(wi, m))
    valid = (cosine | valid_m) & (wo[2] > 0.0) & (wi[2] > 0.0)
    return wo, proposal_pdf(exit, mf, wi, wo, c), valid
