"""``msx compare``: the paper comparisons, side by side with Mitsuba's built-ins.

Each scene holds two spheres: the left one uses Mitsuba's `roughconductor`
(single scattering), the right one `msx_posfree`. For every model the report
gives the right/left energy ratio with its Monte Carlo standard error (from
the independent render chunks), images, difference images and a chart.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

MODELS = ("single", "uncorrelated", "correlated")
SCENES = {
    "fig09_copper_sphere": "Wang 2022 Fig. 9: copper, GGX α = 1, directional light",
    "furnace_spheres": "White furnace: F = 1, GGX α = 1.5, uniform white environment",
}


def _halves_stats(chunks):
    """Mean of (right half − left half) and of right/left over chunks, with standard errors."""
    import numpy as np

    lefts, rights = [], []
    for spp, img in chunks:
        w = img.shape[1] // 2
        lefts.append(float(np.mean(img[:, :w])))
        rights.append(float(np.mean(img[:, w:])))
    lefts, rights = np.array(lefts), np.array(rights)
    n = len(lefts)
    diff = rights - lefts
    se = float(np.std(diff, ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    return float(lefts.mean()), float(rights.mean()), float(diff.mean()), se


def run(args):
    import numpy as np

    from .cli import render_scene, write_image

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    montage = {}
    t_start = time.perf_counter()
    for scene, title in SCENES.items():
        path = Path(args.scenes) / f"{scene}.xml"
        if not path.exists():
            raise SystemExit(f"scene not found: {path} (run from the repository root or pass --scenes)")
        for model in MODELS:
            label = f"{scene} [{model}]"
            img, chunks, wall = render_scene(str(path), variant=args.variant, spp=args.spp, params={"model": model},
                                             workers=args.workers, seed=args.seed, label=label)
            write_image(out / f"{scene}_{model}", img, args.variant)
            left, right, diff, se = _halves_stats(chunks)
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
        "With `single`, both halves are the same BSDF: the difference must be 0 within ~3 standard errors.",
        "",
        "| scene | model | left (built-in) | right (msx) | right/left | right − left | ± s.e. | |Δ|/s.e. | wall s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for scene, model, left, right, diff, se, wall in rows:
        z = abs(diff) / se if se > 0 else float("nan")
        lines.append(f"| {scene} | {model} | {left:.5f} | {right:.5f} | {right / left:.4f} | {diff:+.5f} | {se:.5f} | {z:.1f} | {wall:.1f} |")
    lines += ["", "Images: `<scene>_<model>.png/.exr`, `<scene>_<model>_absdiff.png` (|right − left|, mirrored), "
              "`<scene>_montage.png` (rows: " + ", ".join(MODELS) + ")."]
    for scene, title in SCENES.items():
        lines += ["", f"## {scene}", "", title, "", f"![{scene}]({scene}_montage.png)"]
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3.2))
        for i, scene in enumerate(SCENES):
            sel = [r for r in rows if r[0] == scene]
            ratios = [r[3] / r[2] for r in sel]
            errs = [r[5] / r[2] for r in sel]
            ax.bar([k + 0.38 * i for k in range(len(sel))], ratios, width=0.36, yerr=errs, label=scene)
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xticks([k + 0.19 for k in range(len(MODELS))], MODELS)
        ax.set_ylabel("energy: msx / roughconductor")
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
    bad = [r for r in rows if r[1] == "single" and r[5] > 0 and abs(r[4]) > 4 * r[5]]
    if bad:
        raise SystemExit(f"model=single differs from roughconductor by more than 4 standard errors: {bad}")
