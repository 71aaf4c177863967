"""``msx compare``: the evaluation's driver — speed against accuracy (the stages; the parts are this package's
other modules).

Renders the paper scenes with every model × estimator and Mitsuba's built-ins,
measures error against time against a converged Smith reference, maps where
each model fails, draws the lobes and the energy curves, and writes
``DIR/index.html`` (self-contained), ``results.csv``, ``atlas.csv``,
``energy.csv`` and the PNGs. ``--quick`` is the small version (CI, a first
look); the full run is the report's.
"""

from __future__ import annotations

import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from .. import _cache, _references
from .._render import RenderError, output_folder, scenes_dir
from . import atlas as atlas_mod
from . import charts, common
from . import energy as energy_mod
from . import lobes as lobes_mod
from . import renders, scene_advice, two_references
from . import uncertainty
from ..plugin.parameters import models
from .common import CONDUCTOR_ROWS, DIELECTRIC_ROWS, UNBIASED, row_label

SWEEP_SCENES = [
    renders.SweepScene("fig09_copper_sphere", "Wang 2022 Fig. 9: copper sphere, GGX α = 1, directional light (direct only)",
                       "conductor", "roughconductor", CONDUCTOR_ROWS, "direct"),
    renders.SweepScene("fig01_dielectric_slab", "Wang 2022 Fig. 1 (c, d): rough dielectric slab, GGX α = 1, directional lights (direct only)",
                       "dielectric", "roughdielectric", DIELECTRIC_ROWS, "direct"),
    renders.SweepScene("fig01_dielectric_sphere", "Rough dielectric sphere, GGX α = 1, environment + directional light, 16 bounces",
                       "dielectric", "roughdielectric", DIELECTRIC_ROWS, "environment"),
]
# Side-by-side only (no sweep): (key, scene file, title, built-in twin, models, scene parameters)
SIDE_SCENES = [
    ("furnace_sphere", "furnace_sphere", "White furnace: F = 1, GGX α = 1.5 — an energy-conserving BSDF vanishes (value 1)",
     "roughconductor", models("conductor"), {}),  # every conductor model of the core's table
    ("roughness_ramp", "roughness_ramp", "Copper, GGX α = 0.02, 0.05, 0.1, 0.3, 1 (top to bottom): where model='auto' drops the walk",
     "roughconductor", ["single", "correlated", "auto", "invariance"], {}),
    ("fig01_metals", "fig01_metals", "Wang 2022 Fig. 1 (a, b): copper α 0.1, aluminium α 0.6, gold α 0.5 on aluminium α 0.1",
     "roughconductor", ["single", "correlated", "heitz", "invariance", "auto", "compensated"], {}),
    ("fig07_normalmap", "fig07_normalmap", "Wang 2022 Fig. 7: copper α 0.3 under a normal map — black where single scattering "
     "sees ω_i below the shading plane", "roughconductor", ["single", "correlated", "uncorrelated", "auto"], {}),
    ("fig08_diffuse", "fig08_diffuse", "Wang 2022 Fig. 8: rough diffuse microsurface, GGX α 1 (built-in: Lambertian diffuse)",
     "diffuse", ["correlated", "uncorrelated", "heitz", "invariance", "auto"], {}),
    ("fig12_kulla_conty", "fig12_kulla_conty", "Wang 2022 Fig. 12: gold GGX α 1 — multiple scattering vs Kulla-Conty "
     "compensation (average-Fresnel colour)", "roughconductor", ["single", "heitz", "invariance", "correlated", "compensated",
                                                                 "fastmsx"], {}),
    ("fig14_dielectric_series", "fig14_dielectric_series", "Wang 2022 Fig. 14: rough glass, GGX α 0.1, 0.6, 1.0",
     "roughdielectric", ["single", "correlated", "uncorrelated", "heitz", "invariance", "compensated"], {}),
    ("furnace_dielectric_a0.1", "furnace_dielectric", "Dielectric white furnace, GGX α 0.1", "roughdielectric",
     ["single", "correlated", "heitz", "invariance", "compensated"], {"alpha": "0.1"}),
    ("furnace_dielectric_a1", "furnace_dielectric", "Dielectric white furnace, GGX α 1.0", "roughdielectric",
     ["single", "correlated", "heitz", "invariance", "compensated"], {"alpha": "1.0"}),
]


def run(args):
    t_start = time.perf_counter()
    if args.variant:
        import mitsuba as mi

        if args.variant not in mi.variants():
            raise RenderError(f"--variant {args.variant}: not a Mitsuba variant of this install; available: "
                              f"{', '.join(mi.variants())}")
    out = output_folder(args.out, f"--out {args.out}")
    variant, route = (args.variant, f"variant {args.variant} (chosen with --variant)") if args.variant else \
        common.default_variant()
    st = common.settings(args.quick, variant)
    sdir = Path(args.scenes) if args.scenes else scenes_dir()
    if not sdir.is_dir():
        raise RenderError(f"--scenes {args.scenes}: not a folder")
    for s in SWEEP_SCENES:
        if not (sdir / f"{s.name}.xml").exists():
            raise RenderError(f"scene not found: {sdir / (s.name + '.xml')}")
    cache = Path(args.cache) if args.cache else _cache.folder("references")
    output_folder(cache, f"--cache {cache}" if args.cache else f"the cache folder {cache} (--cache to choose one)")
    stages = [f"sweep {s.name}" for s in SWEEP_SCENES] + ["side-by-side scenes", "stability atlas", "lobes",
                                                          "energy curves"]
    stages += ([] if st.quick else ["microgeometry"]) + ["report"]
    # Shares of a run's time per stage, for the run's ETA: the full run of 25 November in docs/evaluation.md (adaptive sweep,
    # default route) spent 102, 146, 310, 229, 234, 49 and 18 s in its first stages; the microgeometry took
    # 1377 s there with other work on the cores, about 600 s without (README), the share used here.
    weights = [0.06, 0.09, 0.18, 0.13, 0.14, 0.03, 0.01] + ([] if st.quick else [0.35]) + [0.002]
    prog = common.Progress(stages, weights)
    print(f"msx compare{' --quick' if st.quick else ''}: route {route}; report in {out}", flush=True)

    renderer = renders.Renderer(variant, sdir)
    results, scene_reports, times_rows = [], [], []
    for scene in SWEEP_SCENES:
        prog.stage(f"sweep {scene.name}")
        scene_reports.append(_sweep_scene(renderer, scene, st, cache, out, prog, results, times_rows))

    prog.stage("side-by-side scenes")
    side_reports = [_side_scene(renderer, key, name, title, builtin, models, extra, st, out, prog)
                    for key, name, title, builtin, models, extra in SIDE_SCENES]
    renderer.release()
    if renderer.routes:
        route += ("; rendered in scalar_rgb with the native back end instead, which the Dr.Jit engine does not "
                  "run: " + "; ".join(f"{name}: {row_label((model, est))}" for name, model, est in sorted(renderer.routes)))

    prog.stage("stability atlas")
    atlas_rows = atlas_mod.compute(st, progress=prog.update)
    pexit = atlas_mod.pexit_map(st)
    fails = atlas_mod.failures(atlas_rows)
    stability_pngs = [charts.stability(out / f"stability_{s}.png", atlas_rows, s, st.atlas_alphas, st.atlas_thetas,
                                       failing=atlas_mod.is_failing)
                      for s in atlas_mod.SURFACES]
    fast = [r for r in atlas_rows if r["model"] == "fastmsx"]
    extras_png = charts.extras(out / "stability_extras.png", pexit, fast, st.atlas_alphas, st.atlas_thetas)
    common.write_csv(out / "atlas.csv", atlas_rows, ["model", "estimator", "surface", "alpha", "theta_i", "furnace_error",
                                               "furnace_se", "rel_std", "nonfinite", "max_weight", "ns_per_call",
                                               "energy"])

    prog.stage("lobes")
    lobe_data = lobes_mod.compute(st, progress=prog.update)
    lobe_pngs = [charts.lobes(out / f"lobes_{s}.png", s, lobe_data, lobes_mod.ORDERS) for s in lobes_mod.MODELS]
    cusp = {m: lobes_mod.normal_cusp(model=m) for m in ("correlated", "heitz")}

    prog.stage("energy curves")
    import mitsuba as mi

    energy_rows = energy_mod.compute(st, energy_mod.copper_rgb(mi), progress=prog.update)
    energy_png = charts.energy(out / "energy.png", energy_rows, energy_mod.THETAS)
    common.write_csv(out / "energy.csv", energy_rows, ["surface", "material", "model", "theta_i", "alpha", "part", "value", "se"])

    micro = None
    if not st.quick:
        # Every model against ray-traced explicit microgeometry (docs/microgeometry.md); simulations cached.
        prog.stage("microgeometry")
        from .. import microgeometry

        micro = microgeometry.compare(out / "microgeometry", link_prefix="microgeometry/")

    prog.stage("report")
    common.write_csv(out / "results.csv", results, ["scene", "model", "estimator", "spp", "seconds", "rel_mse",
                                              "rel_mse_se", "rel_rms_pct", "bias2", "bias2_se", "mean_error_pct",
                                              "mean_error_se_pct", "variance", "unbiased", "route"])
    # Per row and target: the time to it and whether it is measured, extrapolated (×factor) or not reachable.
    common.write_csv(out / "times.csv", times_rows, TIMES_COLUMNS)
    from . import report

    checks = _physics_checks(scene_reports)
    micro_summary = None
    if micro:
        micro_summary = two_references.summary(scene_reports, micro["rows"])
        micro_summary["chart"] = charts.two_references(out / "two_references.png", *micro_summary["chart_data"])
    total = time.perf_counter() - t_start
    html = report.page(dict(route=route, settings=st, scenes=scene_reports, side=side_reports, fails=fails,
                            stability=stability_pngs, extras=extras_png, lobes=lobe_pngs, cusp=cusp, energy=energy_png,
                            checks=checks, seconds=total, micro=micro, micro_summary=micro_summary, atlas=atlas_rows, machine=_machine(),
                            out=out))
    (out / "index.html").write_text(html)
    print(f"\nreport: {out / 'index.html'} ({total:.0f} s)")
    for c in checks:
        state = "FAILED" if not c["ok"] else "warning" if c.get("warning") else "ok"
        print(f"  [{state}] {c['name']}: {c['detail']}" + (f" — {c['warning']}" if c.get("warning") else ""))
    bad = [c for c in checks if not c["ok"]]
    if bad:
        raise RenderError(f"{len(bad)} physics check(s) failed: " + "; ".join(c["name"] for c in bad))


TIMES_COLUMNS = ["scene", "model", "estimator", "target_rms_pct", "seconds", "status", "factor", "spp_needed",
                 "largest_spp", "cap_spp", "bias_floor_pct", "bias_floor_se_pct"]


def _machine():
    """CPU model (Linux: /proc/cpuinfo), architecture and cores, for the page."""
    name = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            name = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), name)
    except OSError:
        pass
    return f"{name + ', ' if name else ''}{platform.machine()}, {os.cpu_count()} cores, {platform.system()}"


# ---------------------------------------------------------------- sweep scenes


def _statuses(rs, targets):
    """Each target's status (uncertainty.target_status) for one row's statistics rows (sorted by spp): its
    fit rel_mse(n) = bias² + k/n, k = the median of variance × spp over its spps. targets: relative RMS
    errors in % (the scene's, common.SWEEP_TARGETS)."""
    k = common.fit_variance_constant([r["spp"] for r in rs], [r["variance"] for r in rs])
    return [uncertainty.target_status(rms, rs[-1]["bias2"], rs[-1]["bias2_se"], k, rs[-1]["spp"])
            for rms in targets]


def _time_ratio(rs, builtin_top, top):
    """Render time per sample ÷ the built-in's, both at the top fixed spp."""
    mine = next(r["seconds"] for r in rs if r["spp"] == top)
    return mine / builtin_top["seconds"] if builtin_top["seconds"] > 0 else float("nan")


def _noisy_time(rs, builtin_top, top):
    """True when the row's render or the built-in's at the top fixed spp took less than
    scene_advice.NOISY_RENDER (the rule of `msx compare SCENE.xml`): their time ratio is then noise."""
    mine = next(r["seconds"] for r in rs if r["spp"] == top)
    return min(mine, builtin_top["seconds"]) < scene_advice.NOISY_RENDER


def _sweep_scene(renderer, scene, st, cache, out, prog, results, times_rows):
    size = (st.size, st.size)
    base = renderer.params(scene, ("single", "pt"), size)
    mask = renderer.object_mask(scene.name, base)
    top = max(st.spps)

    # The reference: invariance PT (Cui 2023: Heitz's BSDF with the heights integrated out; the most
    # efficient unbiased estimator in the benchmarks, and measured again below) at ref_factor × the top fixed
    # spp, rendered first: the adaptive sweep decides with it. After the sweep it is doubled until its own
    # noise is ≤ 1/10 of the smallest error the sweep measured (or the cap, ref_max_factor × the largest spp
    # rendered, is reached): where a row's time to a target is measured, its error at its largest spp is at
    # most the target, so the reference's noise is ≤ 1/10 of the target's rel MSE there. A fixed choice keeps
    # the numbers reproducible; a choice by measured time would depend on the machine's load.
    ref_row = ("invariance", "pt")
    ref_spp = st.ref_factor * top

    last = [None]  # the reference rendered last, (h1, h2, seconds, spp): a doubling renders only the spp it lacks

    def render_reference(spp):
        prog.update(0, spp, f"reference ({row_label(ref_row)}, {spp} spp)")
        h1, h2, seconds, cached = _references.reference(renderer, scene, size, ref_row, spp, cache,
                                                        progress=lambda d, t: prog.update(d, t, "reference spp"),
                                                        smaller=last[0])
        last[0] = (h1, h2, seconds, spp)
        ref = 0.5 * (h1 + h2)
        return ref, renders.reference_noise(h1, h2, ref, mask), seconds, cached

    ref, noise, ref_seconds, cached = render_reference(ref_spp)
    cap = st.cap_spp(scene.name)
    targets = common.targets_rms(scene.name)

    def more(row, by_spp):
        """The adaptive sweep's rule (uncertainty.wants_more) on this row's fit so far."""
        rs, _ = renders.statistics(scene, {row: by_spp}, ref, noise, mask)
        return uncertainty.wants_more(_statuses(rs, targets), max(by_spp), cap)

    data = renders.sweep(renderer, scene, st, progress=prog.update, more=more, cap_spp=cap)
    largest = max(max(by) for by in data.values())

    def efficiency(row):
        im = data[row][top]
        return 1.0 / (renders.seed_variance(im.images, mask) * float(np.mean(im.seconds)))

    eff_ratio = efficiency(("invariance", "pt")) / efficiency(("heitz", "pt"))
    # The reference refined, then the rows' decisions again with it (its noise moves their bias²), until no
    # row asks for more (at most 3 passes; the reference is refined after the last one).
    for passes in range(4):
        while True:
            stats, terms = renders.statistics(scene, data, ref, noise, mask)
            smallest = min(r["rel_mse"] for r in stats)
            if noise <= smallest / 10 or ref_spp >= st.ref_max_factor * largest:
                break
            ref_spp *= 2
            ref, noise, ref_seconds, cached = render_reference(ref_spp)
        if passes == 3 or not renders.extend(renderer, scene, st, data, more, cap, progress=prog.update):
            break
        largest = max(max(by) for by in data.values())
    for r in stats:  # the variant each row was rendered in (the engine's refusals: scalar_rgb)
        r["route"] = renderer.routes.get((scene.name, r["model"], r["estimator"]), renderer.variant)
    results.extend(stats)

    # Time to reach each target relative RMS error: rel_mse(t) = bias² + c/t, c from the measured variances
    # and times. Whether it is measured (the target's spp inside the row's sweep) or extrapolated (with the
    # factor: the spp needed ÷ the largest spp) or not reachable (the bias floor above it) comes from the
    # same fit in spp, rel_mse(n) = bias² + k/n (uncertainty.target_status), which does not depend on the
    # machine's load.
    builtin_top = next(r for r in stats if (r["model"], r["estimator"]) == ("builtin", "-") and r["spp"] == top)
    table = []
    for row in scene.rows:
        rs = [r for r in stats if (r["model"], r["estimator"]) == row]
        secs = [r["seconds"] for r in rs]
        c = common.fit_variance_constant(secs, [r["variance"] for r in rs])
        b2 = rs[-1]["bias2"]
        t = dict(label=row_label(row), row=row, bias2=b2, bias2_se=rs[-1]["bias2_se"], c=c, top=rs[-1],
                 mean_error=rs[-1]["mean_error_pct"], mean_error_se=rs[-1]["mean_error_se_pct"],
                 unbiased=row in UNBIASED, terms=terms[row], seconds_range=(min(secs), max(secs)),
                 time_ratio=_time_ratio(rs, builtin_top, top),
                 noisy_time=_noisy_time(rs, builtin_top, top),
                 slope=_slope([r["spp"] for r in rs], [r["variance"] for r in rs]), times={},
                 status={s["target"]: s for s in _statuses(rs, targets)}, spp_max=rs[-1]["spp"], cap=cap)
        for rms in targets:
            s = t["status"][rms]
            t["times"][rms] = (common.time_to_reach((rms / 100.0) ** 2, b2, c), s["factor"])
            times_rows.append(dict(scene=scene.name, model=row[0], estimator=row[1], target_rms_pct=rms,
                                   seconds=t["times"][rms][0], status=s["status"], factor=s["factor"],
                                   spp_needed=s["spp"], largest_spp=rs[-1]["spp"], cap_spp=cap,
                                   bias_floor_pct=s["floor_pct"], bias_floor_se_pct=s["floor_se_pct"]))
        table.append(t)
    groups = _model_groups(scene, table, sdir=renderer.scenes_dir)
    ranking = uncertainty.rank(groups)

    # Images: converged (seed mean at the top spp) per row, side by side, and differences to the built-in.
    means = {row: sum(data[row][top].images) / len(data[row][top].images) for row in scene.rows}
    labels = [f"{row_label(r)}\n{_energy(means[r], mask):.4f}" for r in scene.rows]
    grid_png = charts.image_grid(out / f"{scene.name}_models.png", [means[r] for r in scene.rows] + [ref], labels +
                                 [f"reference ({row_label(ref_row)}, {ref_spp} spp)"], cols=6,
                                 title=f"{scene.title}: {top} spp × {st.seeds} seeds per model (label: mean over the object)")
    builtin = means[("builtin", "-")]
    diff_png = charts.difference_grid(out / f"{scene.name}_diff.png", builtin,
                                      [means[r] for r in scene.rows[1:]] + [ref],
                                      [row_label(r) for r in scene.rows[1:]] + ["reference"], mask,
                                      f"{scene.name}: model − built-in {scene.builtin} (same pixels)")
    # Equal time: the budget of heitz at a middle spp; each row at the spp whose time is closest.
    mid = st.spps[len(st.spps) // 2]
    budget = float(np.mean(data[("heitz", "pt")][mid].seconds))
    crops, crop_labels = [], []
    for row in scene.rows:
        spp = min(data[row], key=lambda s: abs(math.log(max(np.mean(data[row][s].seconds), 1e-9) / budget)))
        img = data[row][spp].images[0]
        crops.append(img)
        crop_labels.append(f"{row_label(row)}: {spp} spp, {np.mean(data[row][spp].seconds):.2f} s\n"
                           f"RMS error {100 * math.sqrt(max(renders.rel_mse(img, ref, mask), 0.0)):.1f} %")
    ys, xs = np.nonzero(mask)
    crop = ((ys.min(), ys.max() + 1), (xs.min(), xs.max() + 1)) if ys.size else None
    crops_png = charts.image_grid(out / f"crops_{scene.name}.png", crops, crop_labels, cols=6, crop=crop,
                                  title=f"Equal time ≈ {budget:.2f} s (heitz at {mid} spp), seed 0")
    evt_png = charts.error_vs_time(out / f"error_vs_time_{scene.name}.png", scene.title, stats)
    renders.write_exr(out / f"{scene.name}_reference.exr", ref)
    return dict(scene=scene, stats=stats, table=table, cap=cap, fixed_spps=list(st.spps), targets=targets,
                targets_why=common.SWEEP_TARGETS[scene.name].why, ref=dict(row=ref_row, spp=ref_spp, noise=noise,
                seconds=ref_seconds, cached=cached, smallest=smallest, efficiency_vs_heitz=eff_ratio),
                mask_pixels=int(mask.sum()),
                groups=groups, ranking=ranking,
                pngs=dict(evt=evt_png, models=grid_png, diff=diff_png, crops=crops_png),
                means=means, data_top={r: data[r][top] for r in scene.rows}, data=data, mask=mask, reference=ref,
                energy={row_label(r): _energy(means[r], mask) for r in scene.rows})


def _same_model_here(scene, sdir, a, b, n=4000):
    """True if models a and b give bit-identical values at the scene's material (its α, distribution and
    surface; bk7 for glass) on n random direction pairs with the same random stream: e.g. `auto`, whose rule
    keeps the whole `correlated` walk wherever multiple scattering is not negligible."""
    import xml.etree.ElementTree as ET

    from ..core import CoreBsdf

    root = ET.parse(Path(sdir) / f"{scene.name}.xml").getroot()
    d = {e.get("name"): e.get("value") for e in root.iter("default")}
    kw = dict(distribution=d.get("distribution", "ggx"), alpha=float(d.get("alpha", 0.1)), seed=17)
    if scene.surface == "dielectric":
        kw.update(surface="dielectric", ior=1.5046)  # bk7, the scenes' default interior
    rng = np.random.default_rng(99)
    wi, wo = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi[:, 2] = np.abs(wi[:, 2])
    if scene.surface != "dielectric":
        wo[:, 2] = np.abs(wo[:, 2])
    fa = CoreBsdf(model=a, **kw).eval(wi, wo)
    fb = CoreBsdf(model=b, **kw).eval(wi, wo)
    return bool(np.array_equal(fa, fb))


def _model_groups(scene, table, sdir):
    """The entries the bias² ranking compares: rows that are one model at this scene are one entry.
    Estimators of one model (pt, bdpt) have the same expectation; `single` is the built-in (the physics check
    "single = built-in" verifies it on every run); heitz and invariance are the Smith model the reference
    renders (checked too); `auto` joins `correlated` where both give identical values at the scene's
    material. Each entry takes its bias² from its member with the smallest standard error; `members_differ`
    lists members whose bias² differ beyond noise (it should stay empty)."""
    by = {t["row"]: t for t in table}
    sets = [(["single", "built-in"], [("single", "pt"), ("builtin", "-")], "identical by construction"),
            (["Smith model (the reference)"], sorted(UNBIASED), "heitz and invariance: the model the reference renders")]
    same_auto = ("auto", "pt") in by and _same_model_here(scene, sdir, "auto", "correlated")
    for m in ("uncorrelated", "correlated", "compensated", "fastmsx", "auto"):
        if m == "auto" and same_auto:
            continue
        rows = [r for r in by if r[0] == m]
        if m == "correlated" and same_auto:
            rows.append(("auto", "pt"))
        why = ("auto keeps the whole correlated walk at this scene's roughness (identical values)"
               if m == "correlated" and same_auto else "estimators of one model")
        sets.append(([m] if not (m == "correlated" and same_auto) else ["correlated", "auto"], rows, why))
    groups = []
    for names, rows, why in sets:
        members = [by[r] for r in rows if r in by]
        if not members:
            continue
        best = min(members, key=lambda t: t["bias2_se"])
        entry = lambda t: dict(bias2=t["bias2"], se=t["bias2_se"], terms=t["terms"])  # noqa: E731
        differ = [f"{x['label']} vs {y['label']}" for i, x in enumerate(members) for y in members[i + 1:]
                  if uncertainty.differ(entry(x), entry(y))]
        label = " = ".join(names)
        groups.append(dict(label=label, members=[m["label"] for m in members], bias2=best["bias2"], se=best["bias2_se"],
                           terms=best["terms"], why=why, unbiased=all(m["unbiased"] for m in members),
                           members_differ=differ, rows=[m["row"] for m in members]))
    return groups


def _slope(spps, variances):
    x = np.log([s for s, v in zip(spps, variances) if v > 0])
    y = np.log([v for v in variances if v > 0])
    return float(np.polyfit(x, y, 1)[0]) if len(x) >= 2 else float("nan")


def _energy(img, mask):
    return float(img[mask].mean()) if mask.any() else float("nan")


# ---------------------------------------------------------------- side-by-side scenes


def _side_scene(renderer, key, name, title, builtin, models, extra, st, out, prog):
    spp = max(1, st.compare_spp)
    path = renderer.scene_path(name)
    import xml.etree.ElementTree as ET

    root = ET.parse(path).getroot()
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    w, h = int(defaults.get("width", 128)), int(defaults.get("height", 128))
    size = (max(8, int(w * st.compare_scale)), max(8, int(h * st.compare_scale)))
    sizes = {"width": str(size[0]), "height": str(size[1]), **extra}
    mask = renderer.object_mask(name, dict(sizes, bsdf="msx_posfree"))
    rows = [("builtin", "-")] + [(m, "pt") for m in models]
    images, seeds = {}, 4
    for i, row in enumerate(rows):
        params = renderer.params(name, row, builtin=builtin)
        params.update(sizes)
        renderer.warm_up(name, params)
        imgs = [renderer.render(name, params, max(1, spp // seeds), seed=500 + k)[0] for k in range(seeds)]
        images[row] = imgs
        prog.update(i + 1, len(rows), f"{key} renders")
    means = {r: sum(v) / len(v) for r, v in images.items()}
    b = images[("builtin", "-")]
    energy = []
    for row in rows:
        e = [float(im[mask].mean()) for im in images[row]]
        eb = [float(im[mask].mean()) for im in b]
        d = np.array(e) - np.array(eb)
        energy.append(dict(label=row_label(row), value=float(np.mean(e)), builtin=float(np.mean(eb)),
                           ratio=float(np.mean(e) / np.mean(eb)), se=float(d.std(ddof=1) / math.sqrt(len(d))), seeds=e))
    grid_png = charts.image_grid(out / f"{key}_models.png", [means[r] for r in rows],
                                 [f"{row_label(r)}\n{e['value']:.4f}" for r, e in zip(rows, energy)], cols=min(len(rows), 5),
                                 title=f"{title} ({spp} spp; label: mean over the object)")
    diff_png = charts.difference_grid(out / f"{key}_diff.png", means[("builtin", "-")], [means[r] for r in rows[1:]],
                                      [row_label(r) for r in rows[1:]], mask, f"{key}: model − built-in {builtin}")
    renderer.release()
    return dict(name=key, title=title, builtin=builtin, energy=energy, pngs=dict(models=grid_png, diff=diff_png),
                spp=spp)


# ---------------------------------------------------------------- physics checks


BOOTSTRAP = 300  # resamplings of the object's pixels behind each check's standard error


def _pixel_variance(images, mask):
    """Per pixel (summed over channels, which share their noise): the unbiased variance of one render over
    the seeds, and the seed mean per pixel and channel."""
    n = len(images)
    m = sum(images) / n
    return (sum(((i - m)[mask]) ** 2 for i in images) / (n - 1)).sum(axis=1), m[mask]


def _bootstrap_se(stat, size, seed):
    """Standard error of stat(indices) over resamplings of the object's pixel values."""
    rng = np.random.default_rng(seed)
    vals = [stat(rng.integers(0, size, size)) for _ in range(BOOTSTRAP)]
    return float(np.std(vals, ddof=1))


def _same_within_noise(a, b, mask, seed):
    """Two sets of renders of the same expectation: ratio of the squared difference of their seed means to
    the variance that difference should have, its bootstrap standard error, and the 4σ limit."""
    va, ma = _pixel_variance(a, mask)
    vb, mb = _pixel_variance(b, mask)
    d2 = ((ma - mb) ** 2).sum(axis=1)
    e = va / len(a) + vb / len(b)
    if not np.any(e > 0):  # deterministic on both sides: they must agree to rounding
        return float(d2.sum()), 0.0, 0.0
    ratio = lambda idx: float(d2[idx].sum() / max(e[idx].sum(), 1e-300))  # noqa: E731
    r = ratio(np.arange(len(d2)))
    se = _bootstrap_se(ratio, len(d2), seed)
    return r, se, 1.0 + 4.0 * se


def _variance_slope(by_spp, mask, seed):
    """Log-log slope of the variance of one render against spp, and its bootstrap standard error."""
    spps = sorted(by_spp)
    per = [_pixel_variance(by_spp[s].images, mask)[0] for s in spps]
    x = np.log(spps)
    fit = lambda idx: float(np.polyfit(x, np.log([max(v[idx].mean(), 1e-300) for v in per]), 1)[0])  # noqa: E731
    return fit(np.arange(len(per[0]))), _bootstrap_se(fit, len(per[0]), seed)


def _slope_check(name, t, by_spp, mask, seed):
    """Variance of an unbiased model against spp. Independent samples cannot make it fall faster than 1/spp:
    a slope below −1 beyond 4σ is a defect (the check fails). A slope above −1 beyond 4σ is reported as a
    warning, not a failure: the expectation of each spp's variance estimate is σ²/spp, but for a heavy-tailed
    estimator (rare, large samples) the estimate from few samples usually misses the tail, so the variance
    measured at low spp comes out low and σ²·spp seems to grow with spp (docs/estimators.md)."""
    slope, se = _variance_slope(by_spp, mask, seed)
    spps = sorted(by_spp)
    vs = {s: float(_pixel_variance(by_spp[s].images, mask)[0].mean()) * s for s in (spps[0], spps[-1])}
    detail = (f"log-log slope of the variance against spp {slope:.3f} ± {se:.3f} (expected −1; limit 4σ); "
              f"variance × spp {vs[spps[0]]:.3g} at {spps[0]} spp, {vs[spps[-1]]:.3g} at {spps[-1]} spp")
    check = dict(name=f"{name}: {t['label']} variance ∝ 1/spp", ok=slope + 1.0 >= -4.0 * se, detail=detail)
    if slope + 1.0 > 4.0 * se:
        check["warning"] = "falls slower than 1/spp: a heavy-tailed estimator here (its tail is missed at low spp)"
    return check


def _physics_checks(scene_reports):
    """Facts every run must show, each with a limit from its own standard error (bootstrap over the object's
    pixels; 4σ)."""
    checks = []
    for k, rep in enumerate(scene_reports):
        name = rep["scene"].name
        top = rep["data_top"]
        mask = rep["mask"]
        r, se, lim = _same_within_noise(top[("heitz", "pt")].images, top[("invariance", "pt")].images, mask, 10 + k)
        checks.append(dict(name=f"{name}: heitz = invariance within noise", ok=r <= lim,
                           detail=f"squared difference of their converged images / its expected variance = {r:.2f} "
                                  f"± {se:.2f} (limit {lim:.2f}; 1 = noise only)"))
        r, se, lim = _same_within_noise(top[("single", "pt")].images, top[("builtin", "-")].images, mask, 20 + k)
        if lim == 0.0:
            ok, detail = r <= 1e-10, f"both deterministic here; summed squared difference {r:.2e}"
        else:
            ok, detail = r <= lim, f"squared difference / expected variance = {r:.2e} ± {se:.2e} (limit {lim:.2f})"
        checks.append(dict(name=f"{name}: single = built-in {rep['scene'].builtin}", ok=ok, detail=detail))
        for t in rep["table"]:
            if t["unbiased"]:
                checks.append(_slope_check(name, t, rep["data"][t["row"]], mask, 30 + k))
        ref = rep["ref"]
        checks.append(dict(name=f"{name}: reference noise ≤ 1/10 of the smallest plotted error",
                           ok=ref["noise"] <= ref["smallest"] / 10,
                           detail=f"reference ({row_label(ref['row'])}, {ref['spp']} spp) noise {ref['noise']:.2e}, "
                                  f"smallest plotted rel MSE {ref['smallest']:.2e}"))
    return checks


