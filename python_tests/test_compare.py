"""`msx compare --quick` end to end, twice: it writes every file of its
output contract, its physics checks pass (the command fails otherwise:
heitz = invariance within noise, single = built-in, unbiased variance ∝ 1/spp,
reference noise ≤ 1/10 of the smallest error), and the same command gives
the same numbers."""

import csv
import math
import re
import subprocess
import sys

import pytest

FILES = ["index.html", "results.csv", "times.csv", "atlas.csv", "energy.csv", "energy.png", "stability_conductor.png",
         "stability_dielectric_outside.png", "stability_dielectric_inside.png", "stability_extras.png",
         "lobes_conductor.png", "lobes_dielectric.png", "lobes_diffuse.png"]
SCENES = ["fig09_copper_sphere", "fig01_dielectric_slab", "fig01_dielectric_sphere"]
RESULT_COLUMNS = {"scene", "model", "estimator", "spp", "seconds", "rel_mse", "bias2", "bias2_se", "rel_rms_pct",
                  "mean_error_pct", "mean_error_se_pct", "variance"}
ATLAS_COLUMNS = {"model", "surface", "alpha", "theta_i", "furnace_error", "rel_std", "nonfinite", "max_weight",
                 "ns_per_call"}
TIMING = {"seconds", "ns_per_call"}


def run_compare(out, cache):
    r = subprocess.run([sys.executable, "-m", "msx", "compare", "--quick", "--out", str(out), "--cache", str(cache)],
                       capture_output=True, text=True, timeout=1200)
    print(r.stdout[-3000:], r.stderr[-3000:])
    assert r.returncode == 0, r.stderr[-2000:]
    return r


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("compare")
    # Separate caches: the second run renders its reference again instead of reading the first one's.
    a = run_compare(base / "a", base / "cache_a")
    b = run_compare(base / "b", base / "cache_b")
    return base / "a", base / "b", a, b


def test_output_contract(two_runs):
    out, _, run, _ = two_runs
    for f in FILES + [f"error_vs_time_{s}.png" for s in SCENES] + [f"crops_{s}.png" for s in SCENES]:
        assert (out / f).exists() and (out / f).stat().st_size > 0, f
    res = rows(out / "results.csv")
    assert RESULT_COLUMNS <= set(res[0])
    assert {r["scene"] for r in res} == set(SCENES)
    assert {"builtin", "single", "uncorrelated", "correlated", "heitz", "invariance", "auto", "compensated",
            "fastmsx"} <= {r["model"] for r in res}
    assert {("correlated", "bdpt"), ("uncorrelated", "bdpt")} <= {(r["model"], r["estimator"]) for r in res}
    atlas = rows(out / "atlas.csv")
    assert ATLAS_COLUMNS <= set(atlas[0])
    # Raw non-finite values are counted before the C ABI cleans them: none anywhere in the atlas.
    assert all(int(r["nonfinite"]) == 0 for r in atlas)
    html = (out / "index.html").read_text()
    assert "Which model should I use?" in html and "data:image/png;base64," in html
    assert "FAILED" not in run.stdout
    # Every bias² has its standard error, from the seeds: finite and positive.
    assert all(float(r["bias2_se"]) > 0 for r in res)


def local_links(html):
    """href and src values of the page that point at files (not data:, http(s):, mailto: or #anchors)."""
    from html.parser import HTMLParser

    found = []

    class P(HTMLParser):
        def handle_starttag(self, tag, attrs):
            for k, v in attrs:
                if k in ("href", "src") and v and not v.startswith(("data:", "http:", "https:", "mailto:", "#")):
                    found.append(v)

    P().feed(html)
    return found


def test_page_for_users(two_runs):
    """Issue 18: the advice comes first, every scene states its ranking with its rule, no development target,
    and every link of the page resolves."""
    out = two_runs[0]
    html = (out / "index.html").read_text()
    h2 = html.index("<h2")
    assert html[h2:].startswith("<h2 id=advice>Which model should I use?")
    assert "Speed target" not in html and "target ≤" not in html
    assert "tied within noise" in html and html.count("Ranking: <b>") == len(SCENES)
    # Issue 30 item 7: the first table, and the atlas' white cells explained.
    assert "<th class=l>accurate model</th>" in html and "White cells" in html
    links = local_links(html)
    assert "results.csv" in links and any(link.endswith(".png") for link in links)
    missing = [link for link in links if not (out / link.split("#")[0]).exists()]
    assert not missing, missing


def test_physics_checks_ran(two_runs):
    """The command checks its physics facts itself (bootstrap limits, 4σ) and exits non-zero if one fails;
    here: every scene's checks were run and reported."""
    run = two_runs[2]
    for scene in SCENES:
        for fact in ("heitz = invariance within noise", "single = built-in", "heitz variance ∝ 1/spp",
                     "invariance variance ∝ 1/spp", "reference noise ≤ 1/10"):
            assert f"[ok] {scene}: {fact}" in run.stdout, (scene, fact)


def test_same_command_same_numbers(two_runs):
    a, b, _, _ = two_runs
    for name in ("results.csv", "times.csv", "atlas.csv", "energy.csv"):
        ra, rb = rows(a / name), rows(b / name)
        assert len(ra) == len(rb)
        for x, y in zip(ra, rb):
            for k in x:
                if k in TIMING:
                    continue
                if x[k] != y[k]:
                    fx, fy = float(x[k]), float(y[k])
                    assert math.isclose(fx, fy, rel_tol=0, abs_tol=0) or (math.isnan(fx) and math.isnan(fy)), \
                        (name, k, x, y)


def test_times_say_measured_or_extrapolated(two_runs):
    """Issue 18 item 3: every row's time to each target says what it is (times.csv, and the page's cells):
    measured (the spp the fit needs ≤ the row's largest spp), extrapolated with f = needed ÷ largest > 1, or
    not reachable (the bias floor above the target by more than 3 standard errors); and the adaptive sweep
    stopped only where its rule says so (no row left extrapolated with its target predicted inside the cap
    and room to double)."""
    out = two_runs[0]
    times = rows(out / "times.csv")
    res = rows(out / "results.csv")
    largest = {}
    for r in res:
        key = (r["scene"], r["model"], r["estimator"])
        largest[key] = max(largest.get(key, 0), int(r["spp"]))
    assert {(r["scene"], r["model"], r["estimator"]) for r in times} == set(largest)
    seen = set()
    for t in times:
        key = (t["scene"], t["model"], t["estimator"])
        top, need, cap = int(t["largest_spp"]), float(t["spp_needed"]), int(t["cap_spp"])
        assert top == largest[key]
        seen.add(t["status"])
        if t["status"] == "measured":
            assert need <= top and float(t["factor"]) == 1.0
        elif t["status"] == "extrapolated":
            assert need > top and math.isclose(float(t["factor"]), need / top, rel_tol=1e-9)
            assert need > cap or 2 * top > cap, t  # the sweep would have gone on
        elif t["status"] == "not reachable":
            floor, se = float(t["bias_floor_pct"]), float(t["bias_floor_se_pct"])
            b2, b2_se = (floor / 100) ** 2, 2 * (floor / 100) * (se / 100)
            assert b2 - 3 * b2_se > (float(t["target_rms_pct"]) / 100) ** 2 * (1 - 1e-9), t
        else:
            assert t["status"] == "undecided", t
    assert "measured" in seen  # --quick measures some (its 10 % targets on the copper sphere)
    html = (out / "index.html").read_text()
    assert "(measured)" in html and "not reachable: bias floor" in html


def test_scene_targets_on_page_and_in_times(two_runs):
    """Issue 18 item 3: each scene's targets are the ones of the table (common.SWEEP_TARGETS): times.csv has
    every row at exactly those targets, and the page's scene section names them (its note and its columns)."""
    from msx.evaluation.common import SWEEP_TARGETS

    out = two_runs[0]
    times = rows(out / "times.csv")
    html = (out / "index.html").read_text()
    for scene in SCENES:
        targets = SWEEP_TARGETS[scene].targets_rms
        by_row = {}
        for t in times:
            if t["scene"] == scene:
                by_row.setdefault((t["model"], t["estimator"]), []).append(float(t["target_rms_pct"]))
        assert by_row and all(v == list(targets) for v in by_row.values()), (scene, by_row)
        section = html[html.index(f"<h3 id='{scene}'>"):]
        section = section[:section.index("<h3", 4)] if "<h3" in section[4:] else section
        assert "This scene's targets: <b>" + ", ".join(f"{x:g} %" for x in targets) + "</b>" in section
        header = section[section.index("<h4>Every row</h4>"):section.index("</tr>", section.index("<h4>Every row</h4>"))]
        assert [float(x) for x in re.findall(r"time to ([0-9.]+) % RMS", header)] == list(targets)
    assert "--quick is a first look" in html
