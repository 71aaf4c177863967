"""`msx simulate` (ray tracing on generated Beckmann surfaces) and the model
comparison of msx/microgeometry/: the CLI output contract, consistency of
the written numbers, progress output, parameter errors, and a small run of
the comparison. The physics is tested in tests/microgeometry.rs."""

import csv
import math
import subprocess
import sys

import numpy as np
import pytest

from msx import microgeometry as mg


def read_csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def run_cli(tmp_path, *args):
    out = tmp_path / "sim"
    cmd = [sys.executable, "-m", "msx", "simulate", "--distribution", "beckmann", "--out", str(out), *args]
    p = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return out, p


def test_cli_writes_energy_and_lobes_per_order(tmp_path):
    out, p = run_cli(tmp_path, "--surface", "dielectric", "--alpha", "0.6", "--alpha-v", "0.3", "--theta-i", "0.7",
                     "--rays", "40000", "--surfaces", "4", "--grid", "128")
    energy = read_csv(out / "energy.csv")
    assert [r["order"] for r in energy] == ["1", "2", "3", "4+", "total"]
    for col in ("E_r", "E_t", "stderr"):
        assert col in energy[0]
    e = {r["order"]: r for r in energy}
    # Lossless facets: every ray leaves (E_r + E_t = 1) and the orders add up to the total.
    assert float(e["total"]["E_r"]) + float(e["total"]["E_t"]) == pytest.approx(1.0, abs=1e-9)
    for part in ("E_r", "E_t"):
        assert sum(float(e[o][part]) for o in ("1", "2", "3", "4+")) == pytest.approx(float(e["total"][part]), abs=1e-9)
    assert 0.0 < float(e["total"]["E_r"]) < 0.2  # glass at 40°: mostly transmitted
    lobes = read_csv(out / "lobes.csv")
    for col in ("order", "theta_o", "phi_o", "value", "stderr"):
        assert col in lobes[0]
    assert len(lobes) == 5 * 36 * 36
    # The lobes integrate to the energies, per order and per hemisphere.
    for o in ("1", "2", "4+", "total"):
        rows = [r for r in lobes if r["order"] == o]
        up = sum(float(r["value"]) * float(r["solid_angle"]) for r in rows if float(r["theta_o"]) < math.pi / 2)
        down = sum(float(r["value"]) * float(r["solid_angle"]) for r in rows if float(r["theta_o"]) > math.pi / 2)
        assert up == pytest.approx(float(e[o]["E_r"]), rel=1e-6, abs=1e-12)
        assert down == pytest.approx(float(e[o]["E_t"]), rel=1e-6, abs=1e-12)
    # Not a terminal: progress as plain lines.
    assert "100.0 %" in p.stderr and "\r" not in p.stderr


def test_conductor_fresnel_and_perfect_mirror(tmp_path):
    res1 = mg.simulate("conductor", 0.5, theta_i=0.4, rays=20000, surfaces=4, grid=128, progress=False)
    e1 = res1.energy_estimates()
    assert e1["total"][0] == pytest.approx(1.0, abs=1e-12)  # F = 1 by default
    assert e1["total"][1] == 0.0
    res2 = mg.simulate("conductor", 0.5, theta_i=0.4, rays=20000, surfaces=4, grid=128, eta=0.2, k=3.9,
                       progress=False)
    # Copper-like IOR: F ≈ 0.95 at normal incidence, the same rays lose energy.
    assert 0.85 < res2.energy_estimates()["total"][0] < 0.99
    assert res2.rays == 20000 and res2.counts[:, 1:3].sum() == 0


def test_invalid_parameters_raise_with_the_parameter_named():
    with pytest.raises(ValueError, match="theta_i"):
        mg.simulate("conductor", 0.5, theta_i=1.6, rays=100, progress=False)
    with pytest.raises(ValueError, match="grid"):
        mg.simulate("conductor", 0.5, theta_i=0.1, rays=100, grid=100, progress=False)
    with pytest.raises(ValueError, match="alpha"):
        mg.simulate("diffuse", -0.5, theta_i=0.1, rays=100, progress=False)
    with pytest.raises(ValueError, match="surface"):
        mg.simulate("plastic", 0.5, theta_i=0.1, rays=100, progress=False)


def test_model_lobes_cover_the_simulated_bins():
    res = mg.simulate("diffuse", 0.5, theta_i=0.5, rays=20000, surfaces=4, grid=128, progress=False)
    value, se, groups = mg.model_lobes(res, "correlated", samples=40000, groups=4)
    assert value.shape == (5, 36, 36) and groups.shape == (4, 5, 36, 36)
    omega = res.solid_angles()
    # Diffuse microsurface of albedo 1: every sampled path leaves with weight
    # 1 (the model conserves energy), upward only, and the orders add up.
    total = (value[4] * omega).sum()
    assert total == pytest.approx(1.0, abs=1e-3)
    assert np.all(value[:, 18:] == 0.0)
    assert (value[:4] * omega).sum() == pytest.approx(total, rel=1e-9)
    # The sampled binning is the simulation's: a direction at a bin centre lands in that bin.
    te, pe = res.theta_edges(), res.phi_edges()
    for it, ip in ((0, 0), (7, 3), (20, 35), (35, 18)):
        t, ph = 0.5 * (te[it] + te[it + 1]), 0.5 * (pe[ip] + pe[ip + 1])
        w = np.array([[math.sin(t) * math.cos(ph), math.sin(t) * math.sin(ph), math.cos(t)]])
        assert mg.bin_index(res, w)[0] == it * 36 + ip


def test_comparison_writes_tables_and_charts(tmp_path, monkeypatch):
    monkeypatch.setenv("MSX_CACHE_DIR", str(tmp_path / "cache"))
    r = mg.compare(tmp_path, rays=16000, thetas=(0.5,), alphas=((0.5, 0.5), (0.6, 0.2)),
                   surfaces=("conductor", "dielectric"), model_samples=16000, grid=128, n_surfaces=4, progress=False)
    rows = read_csv(tmp_path / "errors.csv")
    models = {(row["surface"], row["alpha"], row["model"]) for row in rows}
    assert models == {(s, a, m) for s in ("conductor", "dielectric") for a in ("0.5", "(0.6, 0.2)") for m in mg.MODELS[s]}
    for row in rows:
        assert np.isfinite(float(row["L1"])) and float(row["E1_sim"]) > 0.5
    for name in ("errors.md", "errors.html", "summary.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert "| conductor | heitz |" in r["markdown"]
    if mg.report._plt() is not None:
        assert (tmp_path / "energy_conductor.png").exists()
        assert (tmp_path / "lobes_dielectric_a0.5-0.5_t0.5.png").exists()
    # Cached simulations are reused: a second run gives the same table.
    r2 = mg.compare(tmp_path, rays=16000, thetas=(0.5,), alphas=((0.5, 0.5),), surfaces=("conductor",),
                    model_samples=16000, grid=128, n_surfaces=4, progress=False)
    a = [x for x in r["rows"] if x["surface"] == "conductor" and x["model"] == "single"][0]
    b = [x for x in r2["rows"] if x["model"] == "single"][0]
    assert a["E1_sim"] == b["E1_sim"]
    # With the report's prefix (the folder sits one level below the page): the returned Markdown carries the
    # prefix, summary.md — which lies in the folder — resolves from its own folder.
    import re

    r3 = mg.compare(tmp_path, rays=16000, thetas=(0.5,), alphas=((0.5, 0.5),), surfaces=("conductor",),
                    model_samples=16000, grid=128, n_surfaces=4, progress=False, link_prefix="microgeometry/")
    links = re.findall(r"\]\(([^)]+)\)", (tmp_path / "summary.md").read_text())
    assert links and all((tmp_path / link).exists() for link in links), links
    assert all(link.startswith("microgeometry/") for link in re.findall(r"\]\(([^)]+)\)", r3["markdown"]))
