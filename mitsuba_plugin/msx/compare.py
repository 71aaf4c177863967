"""``msx compare``: the paper comparisons, side by side with Mitsuba's built-ins.

Left: Mitsuba's `roughconductor` (single scattering); right: `msx_posfree`.
Fig. 9 holds both spheres in one scene (direct lighting only, so they do not
interact); the furnace renders one sphere per image (another object would
hide part of the environment) and the two renders are put side by side. For every model the report
gives the right/left energy ratio with its Monte Carlo standard error (from
the independent render chunks), images, difference images and a chart.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

MODELS = ("single", "uncorrelated", "correlated")
# scene -> (title, reference BSDF or None if both spheres are in one scene, models)
SCENES = {
    "fig09_copper_sphere": ("Wang 2022 Fig. 9: copper, GGX α = 1, directional light", None, MODELS + ("heitz", "invariance")),
    "furnace_sphere": ("White furnace: F = 1, GGX α = 1.5, uniform white environment", "roughconductor",
                       MODELS + ("heitz", "invariance", "fastmsx", "compensated")),
    "fig01_dielectric_sphere": ("Wang 2022 Fig. 1 (c, d): rough dielectric, GGX α = 1, bk7", "roughdielectric",
                                MODELS + ("heitz", "invariance")),
    "roughness_ramp": ("Copper, GGX α = 0.02, 0.05, 0.1, 0.3, 1 (top to bottom): where model='auto' drops the walk",
                       None, MODELS + ("auto",)),
}


def _stats(left_chunks, right_chunks):
    """Means of the left and right images, and of right − left over paired
    chunks with its standard error."""
    import numpy as np

    lefts = np.array([float(np.mean(img)) for _, img in left_chunks])
    rights = np.array([float(np.mean(img)) for _, img in right_chunks])
    n = len(lefts)
    diff = rights - lefts
    se = float(np.std(diff, ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    return float(lefts.mean()), float(rights.mean()), float(diff.mean()), se


def run(args):
    import numpy as np

    from ._render import RenderError, render_scene, scenes_dir, write_image

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    montage = {}
    t_start = time.perf_counter()
    opts = dict(variant=args.variant, spp=args.spp, workers=args.workers, seed=args.seed)
    for scene, (title, reference, models) in SCENES.items():
        in_one = reference is None
        path = Path(args.scenes or scenes_dir()) / f"{scene}.xml"
        if not path.exists():
            raise RenderError(f"scene not found: {path}")
        if not in_one:
            ref, ref_chunks, _ = render_scene(str(path), params={"bsdf": reference},
                                              label=f"{scene} [{reference}]", **opts)
        for model in models:
            label = f"{scene} [{model}]"
            img, chunks, wall = render_scene(str(path), params={"model": model}, label=label, **opts)
            if in_one:
                w = img.shape[1] // 2
                halves = lambda cs, side: [(n, c[:, :w] if side == 0 else c[:, w:2 * w]) for n, c in cs]
                left, right, diff, se = _stats(halves(chunks, 0), halves(chunks, 1))
            else:
                left, right, diff, se = _stats(ref_chunks, chunks)
                img = np.concatenate([ref, img], axis=1)
            write_image(out / f"{scene}_{model}", img, args.variant)
            w = img.shape[1] // 2
            d = np.abs(img[:, w:2 * w] - img[:, :w])
            write_image(out / f"{scene}_{model}_absdiff", np.concatenate([d, d], axis=1), args.variant)
            montage.setdefault(scene, []).append(img)
            rows.append((scene, model, left, right, diff, se, wall))

    for scene, imgs in montage.items():
        write_image(out / f"{scene}_montage", np.concatenate(imgs, axis=0), args.variant)

    lines = [
        "# msx compare",
        "",
        "Left sphere: Mitsuba `roughconductor`; right sphere: `msx_posfree` with the model in the row.",
        f"{args.spp} spp, variant `{args.variant}`, {args.workers} worker process(es). "
        "Energy = mean pixel value of each half; ± is one standard error over the independent render chunks.",
        "With `single`, both halves are the same BSDF: the difference must be 0 within ~3 standard errors "
        "(the furnace renders share their samples, so there it is float32 rounding only).",
        "",
        "| scene | model | left (built-in) | right (msx) | right/left | right − left | ± s.e. | |Δ|/s.e. | wall s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, model, left, right, diff, se, wall in rows:
        z = abs(diff) / se if se > 0 else float("nan")
        lines.append(f"| {scene} | {model} | {left:.5f} | {right:.5f} | {right / left:.4f} | {diff:+.5f} | {se:.5f} | {z:.1f} | {wall:.1f} |")
    lines += ["", "Images: `<scene>_<model>.png/.exr`, `<scene>_<model>_absdiff.png` (|right − left|, mirrored), "
              "`<scene>_montage.png` (one row per model, in the table's order)."]
    for scene, (title, _, models) in SCENES.items():
        lines += ["", f"## {scene}", "", title, "", f"![{scene}]({scene}_montage.png)"]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        all_models = []
        for r in rows:
            if r[1] not in all_models:
                all_models.append(r[1])
        fig, ax = plt.subplots(figsize=(8, 3.4))
        width = 0.8 / len(SCENES)
        for i, scene in enumerate(SCENES):
            sel = [r for r in rows if r[0] == scene]
            xs = [all_models.index(r[1]) + width * i for r in sel]
            ax.bar(xs, [r[3] / r[2] for r in sel], width=width * 0.95, yerr=[r[5] / r[2] for r in sel], label=scene)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xticks([k + 0.4 - width / 2 for k in range(len(all_models))], all_models)
        ax.set_ylabel("energy: msx / Mitsuba built-in")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "energy_ratio.png", dpi=120)
        lines += ["", "## Energy ratio", "", "![energy ratio](energy_ratio.png)"]
    except ImportError:
        lines += ["", "(matplotlib not installed: no chart)"]
    lines += ["", f"Total time: {time.perf_counter() - t_start:.0f} s"]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines[7:7 + len(rows) + 1]))
    print(f"\nreport: {out / 'report.md'}")
    # The furnace renders of `single` and roughconductor use the same seeds, hence
    # the same samples: their difference is float32 rounding, not noise (1e-4 relative allowance).
    bad = [r for r in rows if r[1] == "single" and abs(r[4]) > 4 * r[5] + 1e-4 * abs(r[2])]
    if bad:
        raise SystemExit(f"model=single differs from roughconductor by more than 4 standard errors: {bad}")
