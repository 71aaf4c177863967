"""Position-free multiple scattering, Wang et al. 2022, in the Dr.Jit engine: twin of
``src/models/posfree/`` (``mod.rs``: the segment factors and the roulette; ``conductor.rs``: the PT
estimator with next-event estimation and the random-walk sampler).

A path is d_0 = −ω_i, …, d_k = ω_o; with L_j = |Λ(d_j)| the pair factors of the segment models are
(``mod.rs`` has the table and its derivation):

| pair                    | uncorrelated | correlated |
|---|---|---|
| middle, d_{j+1} upward   | Λ/(1+Λ)      | Λ/(L_j+Λ)  |
| last (ω_o upward)        | 1/(L_j(1+Λ_o)) | 1/(L_j+Λ_o) |

The walks are ``dr.while_loop``s whose state is the vertex index, the direction the light comes from,
L_j, the throughput, the estimate and the lane's random stream (key, counter).
"""

from functools import partial

import drjit as dr
import mitsuba as mi

from . import mis, walk
from .model import ConductorWalk, DiffuseWalk
from .microfacet import INV_PI, dot, max_channel, reflect
from .rng import Stream

UNCORRELATED = "uncorrelated"
CORRELATED = "correlated"

# src/models/posfree/mod.rs and conductor.rs: where roulette starts, the weight of the next-event value
# and of the last-segment factor in the roulette's importance (measured there; the same values here).
RR_START = 1
RR_NEE_GAIN = 30.0
RR_LAST_WEIGHT = 0.05


def continue_up(segments, l, lam):
    """L_j·(p_j e_{j+1}) of a middle segment going upward with Λ = Λ(d_{j+1}); 1 for an infinite Λ."""
    v = lam / (1.0 + lam) if segments == UNCORRELATED else lam / (l + lam)
    return dr.select(dr.isinf(lam), 1.0, v)


def last(segments, l, lambda_o):
    """p_j·e_k of the last segment towards ω_o."""
    if segments == UNCORRELATED:
        return 1.0 / (l * (1.0 + lambda_o))
    return 1.0 / (l + lambda_o)


def roulette_importance(nee, last_factor, gain):
    """Importance per unit throughput of a walk at a vertex (mod.rs ``roulette_importance``)."""
    return dr.maximum(dr.maximum(gain * nee, RR_LAST_WEIGHT * last_factor), 1.0)


def nee_term(mf, w, wo, last_factor):
    """The conductor's next-event term without the Fresnel factor: (w·h, D(h)·last/(4|w_z|), valid)."""
    h = w + wo
    length = dr.norm(h)
    h = h / length
    cos_wh = dot(w, h)
    valid = (length > 0.0) & (cos_wh > 0.0) & (dot(wo, h) > 0.0)
    value = mf.d(h) * last_factor / (4.0 * dr.abs(w[2]))
    return cos_wh, dr.select(valid, value, 0.0), valid


def eval_pt(segments, mf, fresnel, wi, wo, max_bounces, key):
    """One PT estimate of f(ω_i, ω_o)·cos θ_o (Wang eqs. 24–26), all orders 1..max_bounces: the walk
    closes the path towards ω_o at every vertex and samples the next direction from the visible normals.
    ω_i may lie below the macro surface (normal mapping); ω_o must point up."""
    lambda_o = mf.lambda_(wo)
    start = (wi[2] != 0.0) & (wo[2] > 0.0)

    def body(j, w, l, thr, result, active, counter):
        rng = Stream(key, counter)
        active &= (l > 0.0) & dr.isfinite(l) & (max_channel(thr) > 0.0)
        last_factor = last(segments, l, lambda_o)
        cos_wh, nee, nee_ok = nee_term(mf, w, wo, last_factor)
        u_rr, _ = rng.next2()
        kept_thr, survived = walk.russian_roulette_keep(
            thr, u_rr, 1.0 / roulette_importance(nee, last_factor, RR_NEE_GAIN))
        play = j >= RR_START
        thr = dr.select(play, kept_thr, thr)
        active &= ~play | survived
        result = dr.select(active & nee_ok, result + thr * fresnel.eval(cos_wh) * nee, result)
        active &= j + 1 < max_bounces
        # The next direction, from the visible normals of w.
        u1, u2 = rng.next2()
        m, valid = mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        d_next = reflect(w, m)
        thr = thr * fresnel.eval(cos_wm)
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        thr = dr.select(up, thr * continue_up(segments, l, lam), thr)
        active &= valid & (cos_wm > 0.0)
        return j + 1, -d_next, lam, thr, result, active, rng.counter

    width = dr.width(wi)
    state = (mi.UInt32(0), mi.Vector3f(wi), mf.abs_lambda(-wi), dr.full(mi.Spectrum, 1.0, width),
             dr.zeros(mi.Spectrum, width), mi.Bool(start), mi.UInt32(0))
    state = dr.while_loop(state, lambda *s: s[5], body, label="msx_posfree_conductor_pt")
    return state[4]


def sample_walk(segments, mf, fresnel, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampler (Wang §4.3): at each upward direction the walk leaves with probability
    1 − continue_up, so the weight is the product of the Fresnel terms. The first vertex uses Mitsuba's
    (sample1, sample2), later ones the lane's stream. Returns (ω_o, weight, valid)."""

    def body(j, w, l, weight, done, active, counter, u_exit, u1, u2):
        rng = Stream(key, counter)
        m, valid = mf.sample_visible(w, u1, u2)
        cos_wm = dot(w, m)
        valid &= cos_wm > 0.0
        d_next = reflect(w, m)
        weight = weight * fresnel.eval(cos_wm)
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        leaves = up & (u_exit >= continue_up(segments, l, lam))
        done = valid & leaves
        active = valid & ~leaves & (j + 1 < max_bounces)
        a, b = rng.next2()
        c, _ = rng.next2()
        return j + 1, -d_next, lam, weight, done, active, rng.counter, c, a, b

    width = dr.width(wi)
    state = (mi.UInt32(0), mi.Vector3f(wi), mf.abs_lambda(-wi), dr.full(mi.Spectrum, 1.0, width),
             dr.full(mi.Bool, False, width), mi.Bool(wi[2] != 0.0), mi.UInt32(0), mi.Float(sample1),
             mi.Float(u1), mi.Float(u2))
    state = dr.while_loop(state, lambda *s: s[5], body, label="msx_posfree_conductor_sample")
    wo = -state[1]
    return wo, state[3], state[4]


# ------------------------------------------------------------------ diffuse facets (diffuse.rs)


def diffuse_eval_pt(segments, mf, albedo, wi, wo, max_bounces, key):
    """PT estimate of f(ω_i, ω_o)·cos θ_o on Lambertian facets of albedo ``albedo`` (diffuse.rs
    ``eval_pt``): per vertex a visible normal m serves the next event, L_j·(a/π)⟨ω_o, m⟩⁺·last, and the
    Lambertian continuation about m; roulette after every vertex."""
    lambda_o = mf.lambda_(wo)
    start = (wi[2] > 0.0) & (wo[2] > 0.0)
    width = dr.width(wi)

    def body(j, w, l, thr, result, active, counter):
        rng = Stream(key, counter)
        active &= (l > 0.0) & dr.isfinite(l) & (max_channel(thr) > 0.0)
        u1, u2 = rng.next2()
        m, valid = mf.sample_visible(w, u1, u2)
        active &= valid
        c = dot(wo, m)
        nee = albedo * (c * INV_PI * l * last(segments, l, lambda_o))
        result = dr.select(active & (c > 0.0), result + thr * nee, result)
        active &= j + 1 < max_bounces
        u3, u4 = rng.next2()
        d_next = walk.cosine_about(m, u3, u4)
        thr = thr * albedo
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        thr = dr.select(up, thr * continue_up(segments, l, lam), thr)
        play = j + 1 >= RR_START
        kept, survived = walk.russian_roulette(thr, rng.next())
        thr = dr.select(play, kept, thr)
        active &= ~play | survived
        return j + 1, -d_next, lam, thr, result, active, rng.counter

    state = (mi.UInt32(0), mi.Vector3f(wi), 1.0 + mf.lambda_(wi), dr.full(mi.Spectrum, 1.0, width),
             dr.zeros(mi.Spectrum, width), mi.Bool(start), mi.UInt32(0))
    return dr.while_loop(state, lambda *s: s[5], body, label="msx_posfree_diffuse_pt")[4]


def diffuse_sample_walk(segments, mf, albedo, wi, sample1, u1, u2, max_bounces, key):
    """Random-walk sampler on Lambertian facets (diffuse.rs ``sample_walk``): (ω_o, weight = Π albedo,
    valid)."""
    width = dr.width(wi)

    def body(j, w, l, weight, done, active, counter, u_exit, u1, u2):
        rng = Stream(key, counter)
        m, valid = mf.sample_visible(w, u1, u2)
        u3, u4 = rng.next2()
        d_next = walk.cosine_about(m, u3, u4)
        weight = weight * albedo
        up = d_next[2] > 0.0
        lam = mf.abs_lambda(d_next)
        leaves = up & (u_exit >= continue_up(segments, l, lam))
        done = valid & leaves
        active = valid & ~leaves & (j + 1 < max_bounces) & (lam > 0.0) & dr.isfinite(lam)
        a, b = rng.next2()
        c, _ = rng.next2()
        return j + 1, -d_next, lam, weight, done, active, rng.counter, c, a, b

    state = (mi.UInt32(0), mi.Vector3f(wi), 1.0 + mf.lambda_(wi), dr.full(mi.Spectrum, 1.0, width),
             dr.full(mi.Bool, False, width), mi.Bool(wi[2] > 0.0), mi.UInt32(0), mi.Float(sample1),
             mi.Float(u1), mi.Float(u2))
    state = dr.while_loop(state, lambda *s: s[5], body, label="msx_posfree_diffuse_sample")
    return -state[1], state[3], state[4]


# The conductor walks this module provides, by model name (jit/bsdf.py collects them).
CONDUCTOR_WALKS = {
    name: ConductorWalk(partial(eval_pt, name), partial(sample_walk, name), exit, below=True)
    for name, exit in ((UNCORRELATED, mis.SEPARABLE), (CORRELATED, mis.HEIGHT_CORRELATED))
}
DIFFUSE_WALKS = {name: DiffuseWalk(partial(diffuse_eval_pt, name), partial(diffuse_sample_walk, name))
                 for name in (UNCORRELATED, CORRELATED)}
