"""The report's ranking rule (msx.evaluation.uncertainty): rows equal within noise come out tied, a real
difference comes out ranked, and the standard error of bias² matches the spread of independent replicates.
Pure NumPy: no rendering. Fixed seeds."""

import math

import numpy as np
import pytest

from msx.evaluation import uncertainty as U


def synthetic_renders(rng, reference, bias, sigma, seeds=3):
    """Independent renders (seeds) of a model whose expectation is reference·(1 + bias), per-pixel noise σ."""
    return [reference * (1.0 + bias) + rng.normal(0.0, sigma, reference.shape) for _ in range(seeds)]


def entry(label, images, reference, mask):
    t = U.bias2_terms(images, reference, mask)
    b, se = U.mean_se(t)
    return dict(label=label, bias2=b, se=se, terms=t)


@pytest.fixture
def scene():
    rng = np.random.default_rng(1234)
    reference = rng.uniform(0.2, 1.0, (40, 40, 3))
    mask = np.zeros((40, 40), dtype=bool)
    mask[5:35, 5:35] = True
    return rng, reference, mask


def test_same_model_twice_is_tied(scene):
    """Two rows of the same model (independent seeds, as the sweep renders two estimators of one model):
    their bias² differ by noise only and must come out in one group, whichever seed."""
    rng, ref, mask = scene
    for _ in range(20):
        a = entry("correlated", synthetic_renders(rng, ref, 0.03, 0.05), ref, mask)
        b = entry("auto", synthetic_renders(rng, ref, 0.03, 0.05), ref, mask)
        assert a["bias2"] != b["bias2"]  # the numbers differ...
        groups = U.rank([a, b])
        assert len(groups) == 1, U.ranking_text(groups)  # ...but not beyond the noise
        assert " = " in U.ranking_text(groups)


def test_numbers_equal_within_noise_are_tied_without_terms():
    """The rule on (bias², se) alone: a difference of 1 combined standard error is a tie, 5 is a ranking."""
    a = dict(label="a", bias2=1.0e-3, se=1.0e-4)
    b = dict(label="b", bias2=1.0e-3 + math.hypot(1e-4, 1e-4), se=1.0e-4)
    c = dict(label="c", bias2=1.0e-3 + 5 * math.hypot(1e-4, 1e-4), se=1.0e-4)
    assert [[e["label"] for e in g] for g in U.rank([b, a])] == [["a", "b"]]
    assert [[e["label"] for e in g] for g in U.rank([c, a])] == [["a"], ["c"]]
    assert U.ranking_text(U.rank([c, b, a])) == "a = b < c"


def test_real_difference_is_ranked(scene):
    """A model 1 % too bright against one 4 % too bright (noise as above): ranked, the closer one first."""
    rng, ref, mask = scene
    for _ in range(20):
        good = entry("uncorrelated", synthetic_renders(rng, ref, 0.01, 0.05), ref, mask)
        bad = entry("compensated", synthetic_renders(rng, ref, 0.04, 0.05), ref, mask)
        groups = U.rank([bad, good])
        assert [[e["label"] for e in g] for g in groups] == [["uncorrelated"], ["compensated"]]


def test_bias2_standard_error_matches_replicates(scene):
    """Unbiased model (bias² = 0): the mean of the bias² estimates over replicates is 0 within their
    standard error, and the reported standard error equals the replicates' spread within the sampling error
    of a standard deviation from R replicates (3σ)."""
    rng, ref, mask = scene
    R = 400
    est, ses = [], []
    for _ in range(R):
        t = U.bias2_terms(synthetic_renders(rng, ref, 0.0, 0.05), ref, mask)
        b, se = U.mean_se(t)
        est.append(b)
        ses.append(se)
    est = np.array(est)
    spread = est.std(ddof=1)
    assert abs(est.mean()) <= 3 * spread / math.sqrt(R)
    # sd of a sample standard deviation ≈ σ / √(2(R − 1)); the mean reported se is much less noisy.
    assert abs(np.mean(ses) - spread) <= 3 * spread / math.sqrt(2 * (R - 1)) + 3 * np.std(ses) / math.sqrt(R)


def test_mean_error_sign():
    rng = np.random.default_rng(7)
    ref = rng.uniform(0.2, 1.0, (30, 30, 3))
    mask = np.ones((30, 30), dtype=bool)
    dark = U.mean_se(U.mean_terms(synthetic_renders(rng, ref, -0.06, 0.02), ref, mask))
    assert abs(dark[0] + 0.06) <= 4 * dark[1]
    assert U.sign_word(*dark) == "too dark"
    same = U.mean_se(U.mean_terms(synthetic_renders(rng, ref, 0.0, 0.02), ref, mask))
    assert U.sign_word(*same) == "within noise"


def test_time_in_range():
    assert U.time_in_range(2.0, [0.5, 1.0, 4.0]) == (2.0, 1.0)
    t, f = U.time_in_range(40.0, [0.5, 1.0, 4.0])
    assert t == 40.0 and f == pytest.approx(10.0)


def micro_rows(l1_by_model, noise=0.01):
    """Rows like microgeometry.compare's: one per (configuration, model) with its lobe L1."""
    rows = []
    for model, values in l1_by_model.items():
        for k, v in enumerate(values):
            rows.append(dict(surface="conductor", alpha="0.5", theta_i=0.1 * k, model=model, L1=v, L1_noise=noise))
    return rows


def test_microgeometry_ranking_ties_and_ranks():
    """Against the traced surfaces: heitz and invariance are one entry (the Smith model); a model closer on
    every configuration by a constant margin ranks first; a model that is closer on some configurations and
    farther on others by the same amount is tied."""
    from msx.evaluation import two_references as R

    rng = np.random.default_rng(3)
    base = rng.uniform(0.04, 0.06, 16)
    jitter = rng.normal(0.0, 0.002, 16)
    rows = micro_rows({"heitz": base, "invariance": base + 1e-4, "uncorrelated": base + 0.01,
                       "correlated": base + jitter})
    groups = R.micro_ranking(rows, "conductor")
    labels = [[e["label"] for e in g] for g in groups]
    assert labels[-1] == ["uncorrelated"]  # 0.01 worse on every configuration: ranked last
    assert sorted(labels[0]) == sorted(["Smith model (heitz, invariance)", "correlated"])  # tied: noise only
    assert sum(len(g) for g in labels) == 3  # heitz and invariance reported once


@pytest.mark.parametrize("alpha, same", [(1.0, True), (0.01, False)])
def test_auto_is_correlated_only_where_its_rule_keeps_the_walk(tmp_path, alpha, same):
    """The report groups `auto` with `correlated` only where the two give identical values at the scene's
    material (core calls, no rendering): at α = 1 auto never drops the walk, at α = 0.01 it does."""
    from msx.evaluation import driver as compare
    from msx.evaluation.common import CONDUCTOR_ROWS
    from msx.evaluation.renders import SweepScene

    (tmp_path / "s.xml").write_text(f'<scene version="3.0.0"><default name="alpha" value="{alpha}"/>'
                                    '<default name="distribution" value="ggx"/></scene>')
    scene = SweepScene("s", "test", "conductor", "roughconductor", CONDUCTOR_ROWS, "direct")
    assert compare._same_model_here(scene, tmp_path, "auto", "correlated") is same
    # The grouping: one entry per model here, auto inside correlated's entry exactly when identical.
    rng = np.random.default_rng(5)
    table = []
    for row in CONDUCTOR_ROWS:
        t = rng.normal(0.01, 0.001, 200)
        label = "built-in" if row[0] == "builtin" else row[0] if row[1] == "pt" else f"{row[0]} {row[1]}"
        table.append(dict(row=row, label=label, bias2=float(t.mean()), bias2_se=float(t.std() / math.sqrt(200)),
                          terms=t, unbiased=row[0] in ("heitz", "invariance")))
    groups = compare._model_groups(scene, table, tmp_path)
    labels = [g["label"] for g in groups]
    assert ("correlated = auto" in labels) is same and ("auto" in labels) is not same
    assert "single = built-in" in labels and sum("Smith" in x for x in labels) == 1
    rows = [r for g in groups for r in g["rows"]]
    assert sorted(rows) == sorted(CONDUCTOR_ROWS)  # every row exactly once


def test_same_computation_up_to_float_rounding_is_tied(scene):
    """single and the built-in render the same samples: their images differ by float32 rounding only, the
    paired standard error is then ~0, and rounding must not read as a ranking (nor as members that differ)."""
    rng, ref, mask = scene
    imgs = synthetic_renders(rng, ref, -0.5, 0.05)
    a = entry("built-in", imgs, ref, mask)
    b = entry("single", [np.float32(i).astype(np.float64) * (1 + 1e-7) for i in imgs], ref, mask)
    assert a["bias2"] != b["bias2"] and U.diff_se(a, b) < 1e-6 * a["bias2"]
    assert len(U.rank([a, b])) == 1 and not U.differ(a, b)
    c = entry("uncorrelated", synthetic_renders(rng, ref, -0.45, 0.05), ref, mask)
    assert U.differ(a, c)


class FakeRenderer:
    """renders.sweep's renderer on synthetic images: row `model` renders reference·(1 + bias) plus Gaussian
    noise σ/√spp per pixel and channel, from a generator seeded by the render's seed (reproducible, like
    mi.render with a seed); a render takes 1 ms per spp."""

    def __init__(self, reference, rows):
        self.reference, self.rows, self.calls = reference, rows, []

    def params(self, scene, row, size=None):
        return {"model": row[0]}

    def warm_up(self, name, params):
        pass

    def release(self):
        pass

    def render(self, name, params, spp, seed):
        bias, sigma = self.rows[params["model"]]
        self.calls.append((params["model"], spp, seed))
        rng = np.random.default_rng(seed)
        noise = rng.normal(0.0, sigma / math.sqrt(spp), self.reference.shape)
        return self.reference * (1.0 + bias) + noise, 1e-3 * spp


def test_adaptive_sweep_measured_extrapolated_not_reachable(scene):
    """Issue 18 item 3: the adaptive sweep (renders.sweep with compare's rule) doubles a row's spp while a
    target is predicted within the cap; a row whose 3 % target lies inside its (extended) sweep comes out
    "measured", one whose target the fit puts beyond the cap "extrapolated ×f" with f = the spp needed ÷ the
    largest spp, a row with a 5 % bias "not reachable" with its floor measured. The same command renders the
    same spps (the decision uses the images only)."""
    from types import SimpleNamespace

    from msx.evaluation import driver as compare
    from msx.evaluation import renders

    _, ref, mask = scene
    r2 = float(np.mean(ref[mask] ** 2))
    # rel MSE at n spp = bias² + σ² / (n · mean(R²)); the spp for 3 % RMS: σ² / (9e-4 · mean(R²)).
    rows = {"builtin": (0.0, 1e-3), "fine": (0.0, 0.1), "noisy": (0.0, 0.4), "biased": (0.05, 0.05)}
    need = {m: s * s / ((0.03 ** 2 - b * b) * r2) for m, (b, s) in rows.items()}
    assert 16 < need["fine"] <= 32 and need["noisy"] > 128  # inside the cap (8 × 16) / beyond it
    st = SimpleNamespace(size=40, spps=[1, 2, 4, 8], seeds=3)
    sc = renders.SweepScene("synthetic", "test", "conductor", "roughconductor",
                            [(m, "pt" if m != "builtin" else "-") for m in rows], "direct")
    cap = 8 * 16
    targets = (10.0, 3.0)  # the rule's, on a synthetic scene (the real scenes': common.SWEEP_TARGETS)

    def more(row, by_spp):
        rs, _ = renders.statistics(sc, {row: by_spp}, ref, 0.0, mask)
        return U.wants_more(compare._statuses(rs, targets), max(by_spp), cap)

    runs = []
    for _ in range(2):
        fake = FakeRenderer(ref, rows)
        data = renders.sweep(fake, sc, st, more=more, cap_spp=cap)
        runs.append(fake.calls)
    assert runs[0] == runs[1]  # reproducible: same spps, same seeds
    stats, _ = renders.statistics(sc, data, ref, 0.0, mask)
    status = {}
    for m in rows:
        rs = [r for r in stats if r["model"] == m]
        status[m] = {s["target"]: s for s in compare._statuses(rs, targets)}
        assert [r["spp"] for r in rs] == sorted(data[(m, "pt" if m != "builtin" else "-")])
    # "fine": 3 % not reached at 8 spp (rel RMS ≈ 5.5 %), so the sweep went on to 32 spp and measured it.
    assert max(data[("fine", "pt")]) == 32
    assert status["fine"][3.0]["status"] == U.MEASURED and status["fine"][3.0]["factor"] == 1.0
    # "noisy": 3 % needs ≈ 430 spp > the cap, so the sweep extended only for 10 % (≈ 39 spp: to 64).
    assert max(data[("noisy", "pt")]) == 64
    assert status["noisy"][10.0]["status"] == U.MEASURED
    s = status["noisy"][3.0]
    assert s["status"] == U.EXTRAPOLATED
    # k from the seed variances (3 seeds × 2700 pixel channels per spp: relative s.e. of a variance ≈ 2 %),
    # the median over 7 spps: 10 % is > 4 standard errors.
    assert s["factor"] == pytest.approx(need["noisy"] / 64, rel=0.1)
    # "biased": 5 % bias (floor 5 % RMS) above 3 %: not reachable, the floor measured within 3 s.e.
    s = status["biased"][3.0]
    assert s["status"] == U.NOT_REACHABLE
    assert abs(s["floor_pct"] - 5.0) <= 3 * s["floor_se_pct"] + 0.05
    assert max(data[("biased", "pt")]) == 8  # nothing to gain from more spp: not extended
    assert set(targets) == set(status["fine"])
    # The page's cells say which is which.
    from msx.evaluation import report

    assert "(measured)" in report._time_cell((1.0, 1.0), status["fine"][3.0])
    assert "extrapolated ×" in report._time_cell((4.0, status["noisy"][3.0]["factor"]), status["noisy"][3.0])
    assert "not reachable: bias floor 5.0" in report._time_cell((float("inf"), float("nan")), status["biased"][3.0])


def test_scene_targets_from_one_table():
    """Issue 18 item 3: each sweep scene names the targets its cap can measure, in one table
    (common.SWEEP_TARGETS): every sweep scene has its entry, the settings' caps come from it (full run and
    --quick), the fit's statuses are those targets, and the page's note names them with the reason and says
    per target whether the reference resolves it (noise ≤ 1/10 of the target's relative MSE)."""
    import html

    from msx.evaluation import common, driver, report

    names = [s.name for s in driver.SWEEP_SCENES]
    assert set(common.SWEEP_TARGETS) == set(names)
    full, quick = common.settings(False, "scalar_rgb"), common.settings(True, "scalar_rgb")
    for name in names:
        entry = common.SWEEP_TARGETS[name]
        targets = common.targets_rms(name)
        assert targets == entry.targets_rms and list(targets) == sorted(targets, reverse=True)
        assert full.cap_spp(name) == max(full.spps) * entry.extend
        assert quick.cap_spp(name) == max(quick.spps) * entry.extend_quick
        # One row, bias 0, k = 1 (variance × spp): the statuses are the scene's targets, in its order.
        rs = [dict(spp=n, variance=1.0 / n, bias2=0.0, bias2_se=1e-6) for n in (1, 2, 4, 8)]
        statuses = driver._statuses(rs, targets)
        assert [s["target"] for s in statuses] == list(targets)
        table = [dict(status={s["target"]: s for s in statuses})]
        smallest = (min(targets) / 100) ** 2
        for noise, word in ((0.05 * smallest, "resolved by the reference"), (0.2 * smallest, "not resolved")):
            rep = dict(targets=targets, targets_why=entry.why, cap=full.cap_spp(name), table=table,
                       ref=dict(noise=noise))
            note = report._targets_note(rep)
            assert "This scene's targets: <b>" + ", ".join(f"{x:g} %" for x in targets) + "</b>" in note
            assert f"cap of {full.cap_spp(name)} spp" in note and html.escape(entry.why) in note
            assert word in note


def test_reference_doubling_renders_only_what_it_lacks(scene, tmp_path):
    """The reference's refinement (driver: its spp doubles) continues the smaller reference where the chunks
    allow it (renders.continues): only the spp it lacks are rendered, and the result is bit-identical to
    rendering it whole (same seeds per chunk, a half's sum recovered exactly from its mean)."""
    from msx.evaluation import renders

    _, ref, _ = scene
    (tmp_path / "s.xml").write_text("<scene/>")
    sc = renders.SweepScene("s", "test", "conductor", "roughconductor", [("invariance", "pt")], "direct")

    class Fake(FakeRenderer):
        variant = "fake"

        def scene_path(self, name):
            return tmp_path / f"{name}.xml"

    row = ("invariance", "pt")
    for small, big, continued in ((512, 1024, True), (1024, 4096, True), (64, 128, False)):
        whole = Fake(ref, {"invariance": (0.0, 0.1)})
        h1, h2, secs, _ = renders.reference(whole, sc, (40, 40), row, big, tmp_path / f"whole{big}")
        part = Fake(ref, {"invariance": (0.0, 0.1)})
        s = renders.reference(part, sc, (40, 40), row, small, tmp_path / f"small{small}")
        calls_small = len(part.calls)
        g1, g2, secs2, _ = renders.reference(part, sc, (40, 40), row, big, tmp_path / f"cont{big}",
                                             smaller=(s[0], s[1], s[2], small))
        assert renders.continues((s[0], s[1], s[2], small), big) is continued
        assert np.array_equal(h1, g1) and np.array_equal(h2, g2)  # bit-identical either way
        assert secs2 == pytest.approx(secs)  # the whole reference's render time either way
        added = part.calls[calls_small:]
        if continued:
            assert sorted(added + part.calls[:calls_small]) == sorted(whole.calls)  # each chunk rendered once
        else:
            assert sorted(added) == sorted(whole.calls)
