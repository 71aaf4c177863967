"""model="single" must equal Mitsuba's roughconductor (README.md's parameter table, docs/paper-notes.md).

Mitsuba computes in float32, the Rust core in float64. Where Mitsuba's own
float32 arithmetic is ill-conditioned the two legitimately differ by more
than 1e-4; such cases are classified, counted and printed (run pytest with
-s to see them), and must stay a small fraction. Everything else is
asserted at relative 1e-4 (+ a float32-level absolute floor).
"""

import math
import random

import pytest

from conftest import close, direction_pairs, set_variant

N_PAIRS = 1000
RTOL = 1e-4
ATOL = 1e-6
# Float32 conditioning thresholds used to classify mismatches.
GRAZING_COS = 1e-2  # cos θ below this: Mitsuba's float32 Λ / G1 are ill-conditioned
EDGE_SAMPLE = 1e-3  # sample2 within this of 0 or 1: float32 erfinv / tan of the inverse CDF
MAX_EXCLUDED_FRACTION = 0.02

CONFIGS = [
    (dist, alpha, material)
    for dist in ("beckmann", "ggx")
    for alpha in ({"alpha": 0.2}, {"alpha_u": 0.3, "alpha_v": 0.1})
    for material in ("none", "Cu", "Au")
]


def config_id(c):
    dist, alpha, material = c
    a = "iso" if "alpha" in alpha else "aniso"
    return "%s-%s-%s" % (dist, a, material)


def load_pair(mi, dist, alpha, material):
    common = dict(distribution=dist, material=material, **alpha)
    ours = mi.load_dict(dict(type="msx_posfree", model="single", **common))
    ref = mi.load_dict(dict(type="roughconductor", **common))
    return ours, ref


def channels(mi, spec):
    return [float(spec[i]) for i in range(len(spec))]


class Stats:
    def __init__(self, label):
        self.label = label
        self.checked = 0
        self.failures = []  # unexplained
        self.excluded = {}  # reason -> count
        self.max_rel = 0.0
        self.below_horizon = 0  # sampled wo below the horizon (see run_comparison)

    def compare(self, what, a, b, reason=None):
        self.checked += 1
        if close(a, b, RTOL, ATOL):
            d = abs(a - b)
            if min(abs(a), abs(b)) > 1e-3:  # relative error of non-tiny values
                self.max_rel = max(self.max_rel, d / max(abs(a), abs(b)))
            return True
        if reason is not None:
            self.excluded[reason] = self.excluded.get(reason, 0) + 1
        else:
            self.failures.append((what, a, b))
        return False

    def report(self, n_cases):
        excl = sum(self.excluded.values())
        print(
            "\n[%s] %d comparisons, max rel. diff (values > 1e-3) %.2e, excluded %d (%s), unexplained %d, "
            "samples below the horizon (both weight 0) %d"
            % (self.label, self.checked, self.max_rel, excl, self.excluded or "none", len(self.failures),
               self.below_horizon)
        )
        for f in self.failures[:10]:
            print("   unexplained:", f)
        assert not self.failures, "%s: %d mismatches beyond 1e-4, e.g. %s" % (
            self.label, len(self.failures), self.failures[:3])
        assert excl <= MAX_EXCLUDED_FRACTION * n_cases, "%s: too many excluded cases: %s" % (
            self.label, self.excluded)


def grazing(w):
    return w[2] < GRAZING_COS


def run_comparison(mi, ours, ref, seed, label, spectral=False):
    rng = random.Random(seed)
    ctx = mi.BSDFContext()
    stats = Stats(label)
    pairs = direction_pairs(seed, N_PAIRS)
    for wi, wo in pairs:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wi)
        if spectral:
            si.wavelengths = mi.Spectrum(*[rng.uniform(360.0, 830.0) for _ in range(4)])
        v_wo = mi.Vector3f(*wo)
        reason = "grazing direction (cos θ < %g)" % GRAZING_COS if (grazing(wi) or grazing(wo)) else None

        e1, e2 = channels(mi, ours.eval(ctx, si, v_wo)), channels(mi, ref.eval(ctx, si, v_wo))
        for a, b in zip(e1, e2):
            stats.compare(("eval", wi, wo), a, b, reason)
        stats.compare(("pdf", wi, wo), float(ours.pdf(ctx, si, v_wo)), float(ref.pdf(ctx, si, v_wo)), reason)
        (ev1, p1), (ev2, p2) = ours.eval_pdf(ctx, si, v_wo), ref.eval_pdf(ctx, si, v_wo)
        for a, b in zip(channels(mi, ev1), channels(mi, ev2)):
            stats.compare(("eval_pdf.value", wi, wo), a, b, reason)
        stats.compare(("eval_pdf.pdf", wi, wo), float(p1), float(p2), reason)

        # sample with identical random numbers
        s1, u, v = rng.random(), rng.random(), rng.random()
        bs1, w1 = ours.sample(ctx, si, s1, mi.Point2f(u, v))
        bs2, w2 = ref.sample(ctx, si, s1, mi.Point2f(u, v))
        s_reason = reason
        if min(u, v, 1.0 - u, 1.0 - v) < EDGE_SAMPLE:
            s_reason = "sample2 within %g of 0 or 1" % EDGE_SAMPLE
        wo2 = [float(bs2.wo[i]) for i in range(3)]
        if float(bs2.pdf) > 0 and wo2[2] <= 0.0:
            # Microfacet normal reflected wi below the horizon: Mitsuba keeps wo and
            # pdf but returns zero weight; msx reports an invalid sample (pdf 0,
            # weight 0). Equivalent for every integrator: the weights must agree.
            stats.below_horizon += 1
            assert float(bs1.pdf) == 0.0
            for a, b in zip(channels(mi, w1), channels(mi, w2)):
                assert a == 0.0 and b == 0.0
        else:
            # A sampled direction itself may be grazing (Mitsuba's float32 G1 then ill-conditioned)
            if s_reason is None and float(bs2.pdf) > 0 and wo2[2] < GRAZING_COS:
                s_reason = "sampled direction grazing (cos θ < %g)" % GRAZING_COS
            for i in range(3):
                # unit-vector components: the absolute floor applies
                stats.compare(("sample.wo", wi, (s1, u, v)), float(bs1.wo[i]), wo2[i], s_reason)
            stats.compare(("sample.pdf", wi, (s1, u, v)), float(bs1.pdf), float(bs2.pdf), s_reason)
            for a, b in zip(channels(mi, w1), channels(mi, w2)):
                stats.compare(("sample.weight", wi, (s1, u, v)), a, b, s_reason)
        assert all(math.isfinite(x) for x in e1 + channels(mi, w1)) and math.isfinite(float(bs1.pdf))
        if float(bs1.pdf) > 0:
            assert int(bs1.sampled_type) == int(mi.BSDFFlags.GlossyReflection)
            assert int(bs1.sampled_component) == 0 and float(bs1.eta) == 1.0
    stats.report(stats.checked)
    return stats


@pytest.mark.parametrize("config", CONFIGS, ids=config_id)
def test_single_equals_roughconductor_rgb(config):
    mi = set_variant("scalar_rgb")
    ours, ref = load_pair(mi, *config)
    assert ours.flags() == ref.flags()
    run_comparison(mi, ours, ref, seed=1234, label="scalar_rgb " + config_id(config))


@pytest.mark.parametrize("config", CONFIGS, ids=config_id)
def test_single_equals_roughconductor_spectral(config):
    mi = set_variant("scalar_spectral")
    ours, ref = load_pair(mi, *config)
    assert ours.flags() == ref.flags()
    run_comparison(mi, ours, ref, seed=4321, label="scalar_spectral " + config_id(config), spectral=True)


def test_specular_reflectance_matches(rgb):
    mi = rgb
    common = dict(distribution="ggx", alpha=0.4, material="Au",
                  specular_reflectance={"type": "rgb", "value": [0.2, 0.5, 0.9]})
    ours = mi.load_dict(dict(type="msx_posfree", model="single", **common))
    ref = mi.load_dict(dict(type="roughconductor", **common))
    run_comparison(mi, ours, ref, seed=99, label="scalar_rgb specular_reflectance")


def test_textured_alpha_matches(rgb):
    """A spatially varying alpha (checkerboard) takes the per-call path."""
    mi = rgb
    tex = {"type": "checkerboard", "color0": 0.05, "color1": 0.5}
    common = dict(distribution="beckmann", alpha=tex, material="Cu")
    ours = mi.load_dict(dict(type="msx_posfree", model="single", **common))
    ref = mi.load_dict(dict(type="roughconductor", **common))
    ctx = mi.BSDFContext()
    rng = random.Random(5)
    stats = Stats("scalar_rgb textured alpha")
    for wi, wo in direction_pairs(5, 300, grazing_fraction=0.0):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wi)
        si.uv = mi.Point2f(rng.random(), rng.random())
        for a, b in zip(channels(mi, ours.eval(ctx, si, mi.Vector3f(*wo))), channels(mi, ref.eval(ctx, si, mi.Vector3f(*wo)))):
            stats.compare("eval", a, b)
    stats.report(stats.checked)
