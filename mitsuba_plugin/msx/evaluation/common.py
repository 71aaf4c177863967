"""Settings, progress and small numerical helpers shared by the evaluation."""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..plugin.parameters import models

# A model row of the evaluation: (model, estimator); model "builtin" is Mitsuba's own BSDF.
Row = tuple


def model_rows(surface):
    """Every model of the core's table (src/config.rs) on a surface with estimator 'pt', each followed by its
    'bdpt' row where the table gives it one — except for a model that shortcuts another's walk (``auto``), whose
    BDPT is that model's."""
    bdpt = set(models(surface, estimator="bdpt", shortcut=False))
    return [row for m in models(surface) for row in [(m, "pt")] + ([(m, "bdpt")] if m in bdpt else [])]


CONDUCTOR_ROWS = [("builtin", "-")] + model_rows("conductor")
DIELECTRIC_ROWS = [("builtin", "-")] + model_rows("dielectric")
# Estimators of the Smith multiple-scattering BSDF itself (unbiased against the reference): the table's exact models.
UNBIASED = {row for row in CONDUCTOR_ROWS + DIELECTRIC_ROWS if row[0] in models(exact=True)}


@dataclass(frozen=True)
class SweepTargets:
    """What one sweep scene measures: its targets of the time-to-error columns, as relative RMS error in %
    (rel MSE = (x / 100)², largest first), and the cap of its adaptive sweep (renders.sweep) that measures
    them, as a factor of the top fixed spp, in the full run and in --quick; `why` is stated on the page."""
    targets_rms: tuple
    extend: int
    extend_quick: int
    why: str


# The one table of the sweep scenes' targets and caps (the driver, the report, times.csv and the tests read
# it). Each scene names the targets its cap can measure for the rows that converge, from the fit
# rel_mse(n) = bias² + k/n of the full run in docs/evaluation.md ("Times to a target"): the spp a target needs
# scales as 1 / target². --quick (CI, a first look: 40 × 40 pixels, top fixed spp 8) keeps the same targets;
# most of its times are extrapolated, and the dielectric sphere is not extended there (its renders are slow).
SWEEP_TARGETS = {
    "fig09_copper_sphere": SweepTargets(
        (10.0, 3.0), 16, 16,
        "10 % is a visibly noisy render, 3 % a clean one; the unbiased rows reach 3 % within the cap"),
    "fig01_dielectric_slab": SweepTargets(
        (10.0, 5.0), 8, 16,
        "5 % rather than 3 %: 3 % needs (5 / 3)² ≈ 2.8 × the spp of 5 % (1 / target²), beyond this cap; 5 % "
        "lies within it for the rows that converge"),
    "fig01_dielectric_sphere": SweepTargets(
        (20.0,), 2, 1,
        "20 % only: this scene (environment light, 16 bounces) renders slowly; 10 % needs 4 × the spp of "
        "20 % (1 / target²), beyond this cap"),
}


def targets_rms(scene_name):
    """The scene's targets, relative RMS error in %, largest first (SWEEP_TARGETS)."""
    return SWEEP_TARGETS[scene_name].targets_rms


def row_label(row) -> str:
    model, est = row
    if model == "builtin":
        return "built-in"
    return model if est in ("pt", "-") else f"{model} {est}"


def pct(x, se=None, digits=1):
    """A percentage with its sign and, if given, its standard error ("+1.2 ± 0.3 %"); "—" if not finite. The
    evaluation's report and the microgeometry's tables write them so."""
    if x is None or not math.isfinite(x):
        return "—"
    out = f"{x:+.{digits}f}"
    if se is not None and math.isfinite(se):
        out += f" ± {se:.{digits}f}"
    return out + " %"


@dataclass
class Settings:
    """What one run computes. `quick` is the CI / first-look size; the full run is the report's."""
    quick: bool
    size: int            # image width and height of the sweep scenes
    spps: list           # the spp sweep
    seeds: int           # independent renders per spp
    ref_factor: int      # reference spp = ref_factor × max(spps), doubled until its noise is small enough
    ref_max_factor: int  # ... up to ref_max_factor × the largest spp the (adaptive) sweep rendered
    atlas_alphas: list
    atlas_thetas: list   # degrees
    atlas_calls: int     # furnace estimate per cell
    atlas_repeat: tuple  # (fixed ω_o per cell, calls at each) for the noise per call
    lobe_points: int     # θ_o samples per side
    lobe_calls: int      # eval calls averaged per θ_o and order
    lobe_alphas: list
    energy_alphas: list
    energy_calls: int
    compare_spp: int     # side-by-side scenes (furnace, ramp)
    compare_scale: float
    variant: str = "scalar_rgb"
    notes: list = field(default_factory=list)
    # The adaptive sweep (renders.sweep): a row's spp doubles up to extend × max(spps) while a target is
    # predicted within that cap; per scene (a factor of 1: no extension), a budget of render time fixed in
    # spp so that the same command renders the same spps (python_tests/test_compare.py).
    extend: dict = field(default_factory=dict)
    extend_default: int = 16

    def cap_spp(self, scene_name):
        return max(self.spps) * self.extend.get(scene_name, self.extend_default)


def _extend(quick):
    """Each scene's cap of the adaptive sweep (× the top fixed spp), from SWEEP_TARGETS."""
    return {name: (t.extend_quick if quick else t.extend) for name, t in SWEEP_TARGETS.items()}


def settings(quick: bool, variant: str) -> Settings:
    if quick:
        return Settings(True, 40, [1, 2, 4, 8], 3, 16, 64, list(np.geomspace(1e-3, 4.0, 6)),
                        [0.0, 30.0, 60.0, 75.0, 85.0, 89.9], 3000, (3, 300), 19, 150, [1.0],
                        list(np.geomspace(0.02, 2.0, 6)), 3000, 8, 0.25, variant, extend=_extend(True))
    return Settings(False, 128, [1, 2, 4, 8, 16, 32, 64], 3, 16, 128, list(np.geomspace(1e-3, 4.0, 12)),
                    [0.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0, 85.0, 88.0, 89.9], 20000, (6, 2000), 61, 1500,
                    [0.5, 1.0], list(np.geomspace(0.02, 2.0, 12)), 20000, 64, 1.0, variant,
                    extend=_extend(False))


def default_variant() -> tuple[str, str]:
    """The fastest route here and why: llvm_ad_rgb with the Dr.Jit engine where Mitsuba's LLVM variant works
    (what the engine does not run falls back to scalar_rgb, row by row), else scalar_rgb with the native back
    end (every render thread), else scalar_rgb with the Python back end (one thread)."""
    from ..plugin.native import NativeUnavailable, build
    from .._variants import llvm_problem

    llvm_why = llvm_problem()
    if llvm_why is None:
        return "llvm_ad_rgb", (f"llvm_ad_rgb with the Dr.Jit engine (traced into Mitsuba's kernels, "
                               f"{os.cpu_count()} threads)")
    try:
        build()
        return "scalar_rgb", (f"scalar_rgb with the native back end (C++ plugin on the Rust core, "
                              f"{os.cpu_count()} render threads; {llvm_why})")
    except NativeUnavailable as e:
        native_why = str(e).splitlines()[0]
    return "scalar_rgb", f"scalar variant, Python back end, one thread (native: {native_why}; {llvm_why})"


class Progress:
    """Stage i of N and, inside a stage, done/total with the stage's ETA and the run's (from each stage's
    share of a run's time, `weights`); plain lines off a terminal."""

    def __init__(self, stages, weights=None, stream=None):
        self.stages = list(stages)
        self.weights = list(weights or [1.0] * len(self.stages))
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()
        self.index = 0
        self.last_line = 0.0

    def stage(self, name):
        self.index = self.stages.index(name) + 1 if name in self.stages else self.index + 1
        self.name = name
        self.stage_t0 = time.perf_counter()
        self._write(f"[{self.index}/{len(self.stages)}] {name} (elapsed {self.elapsed():.0f} s)", final=True)

    def elapsed(self):
        return time.perf_counter() - self.t0

    def update(self, done, total, what=""):
        now = time.perf_counter()
        if not self.tty and done < total and now - self.last_line < 10.0:
            return  # off a terminal: a line every 10 s at most
        self.last_line = now
        el = now - self.stage_t0
        eta = ""
        if 0 < done < total:
            left = el / done * (total - done)
            i = self.index - 1
            done_w = sum(self.weights[:i]) + self.weights[i] * done / total
            rest_w = sum(self.weights) - done_w
            run_left = self.elapsed() / done_w * rest_w if done_w > 0 else float("nan")
            eta = f", stage ETA {left:.0f} s, run ETA {run_left:.0f} s"
        self._write(f"    {self.name}: {done}/{total} {what}{eta}", final=done >= total)

    def _write(self, line, final):
        if self.tty:
            self.stream.write("\r" + line + " " * 10 + ("\n" if final else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def rel_mse(image, reference, mask):
    """Relative MSE over the object's pixels: mean((I − R)²) / mean(R²), all channels."""
    d = (image - reference)[mask]
    r = reference[mask]
    den = float(np.mean(r * r))
    return float(np.mean(d * d)) / den if den > 0 else float("nan")


def fit_variance_constant(times, variances):
    """c of variance ≈ c / t (least squares in relative terms: c = mean(v·t))."""
    vt = [v * t for v, t in zip(variances, times) if v > 0 and t > 0 and math.isfinite(v)]
    return float(np.median(vt)) if vt else float("nan")


def time_to_reach(target, bias2, c):
    """Render seconds for rel MSE = target under rel_mse(t) = bias² + c/t (inf below the bias floor)."""
    if not (math.isfinite(c) and c > 0):
        return float("nan")
    room = target - max(bias2, 0.0)
    return c / room if room > 0 else float("inf")


def write_csv(path, rows, columns):
    """Writes ``rows`` (dicts) as a CSV with ``columns`` in that order (keys outside them are left out)."""
    import csv

    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)
