"""``msx compare SCENE.xml``: per material of a user's scene, does multiple scattering change the image, and
which is the cheapest model that looks right there (docs/evaluation.md, "Your own scene").

Every BSDF msx can stand in for (scene_xml.py) is evaluated on its own, the others left as they are: the scene
is rendered with the material set to each candidate — Mitsuba's built-in, ``single``, ``compensated``,
``correlated``, ``auto`` and the unbiased walk ``heitz`` — at a few spp with independent seeds, against a
converged reference of the Smith model (``invariance`` PT, two halves, cached in msx's cache folder keyed by the
scene's files, the material, the -D values and the settings: msx/_references.py). The numbers and the rules are
the evaluation's (renders.statistics, uncertainty.py, report._verdict): errors over the pixels where the
material is seen first (its mask: rays of the pixel's whole footprint hit a shape using it), bias² with its
standard error, "looks right" within 2 % mean radiance and 5 % RMS by 3 standard errors, ties within noise.
"""

from __future__ import annotations

import hashlib
import html
import json
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import _cache, _references
from .._render import RenderError, one_line, output_folder
from . import common, renders, scene_xml, uncertainty

# The mask's render marks the material with this seed: its BSDF's description (that of msx_posfree, inside any
# wrapper that holds it, by <ref id> or not) names it, so the shapes that use it are found.
MARK_SEED = 918_273_645
# The candidates, in the order of their cost per sample (the a priori order that breaks ties of measured time:
# benches/README.md): Mitsuba's built-in, then msx's models; `heitz` is the unbiased walk.
CANDIDATES = {"conductor": ["builtin", "single", "compensated", "auto", "correlated", "heitz"],
              "dielectric": ["builtin", "single", "compensated", "auto", "correlated", "heitz"],
              "diffuse": ["auto", "correlated", "uncorrelated", "heitz"]}
UNBIASED_MODELS = ("heitz", "invariance")
TIME_TIE = 0.10    # measured times per sample within 10 % of each other: the cheaper model by the order above
NOISY_RENDER = 0.05  # seconds: time ratios from shorter renders are flagged as noise on the page
TILE = 16          # px: the "worst region" of the change multiple scattering makes


@dataclass
class AdviceSettings:
    quick: bool
    max_size: int        # the image's longer side is capped to this
    spps: list           # the sweep of every candidate
    seeds: int           # independent renders per spp
    ref_spp: int         # the reference (two halves)


def settings(quick: bool) -> AdviceSettings:
    if quick:
        return AdviceSettings(True, 256, [1, 4, 16], 3, 256)
    return AdviceSettings(False, 512, [4, 16, 64], 3, 2048)


@dataclass
class MaterialRun:
    """What renders.statistics and msx/_references.py need of a scene: one material."""
    name: str
    material: scene_xml.Material
    rows: list


class SceneRenderer(renders.Renderer):
    """Renders a user's scene with one material set to a candidate model (text edits of its BSDF element,
    scene_xml.set_model) at a capped resolution, the -D values written into its <default>s."""

    def __init__(self, variant, scene: scene_xml.Scene, defines: dict, max_size: int, workdir: Path):
        super().__init__(variant, scene.path.parent)
        self.scene, self.defines, self.workdir = scene, dict(defines), Path(workdir)
        self.size = self._size(max_size)
        blob = b"".join(str(p).encode() + d for p, d in sorted(scene.files.items()))
        self.digest = hashlib.sha256(blob).hexdigest()[:24]
        self.mi.Thread.thread().file_resolver().prepend(str(scene.path.parent))

    def _size(self, max_size):
        film = self._film()
        w = h = None
        if film is not None:
            for name in ("width", "height"):
                p = film.param(name)
                if p is not None:
                    v = scene_xml.resolve(p.attrib.get("value", ""), self.scene.values)
                    try:
                        if name == "width":
                            w = int(v)
                        else:
                            h = int(v)
                    except ValueError:
                        pass
        w, h = w or 768, h or 576  # Mitsuba's hdrfilm defaults
        scale = min(1.0, max_size / max(w, h))
        return max(8, round(w * scale)), max(8, round(h * scale))

    def _film(self):
        return self.scene.film

    def scene_path(self, name):
        return self.scene.path

    def params(self, scene, row, size=None, builtin=None):
        return dict(material=scene.material.key, model=row[0], estimator=row[1], width=str(self.size[0]),
                    height=str(self.size[1]), scene_files=self.digest,
                    defines=json.dumps(self.defines, sort_keys=True))

    def text(self, material, model, mark=False):
        """The scene's text with `material` set to `model` (mark: an msx model, with the seed MARK_SEED), the
        film at the capped size and the -D values in its <default>s; edited included files are written to the
        work folder and the includes point there."""
        sc = self.scene
        edits = scene_xml.Edits()
        scene_xml.set_model(edits, sc, material, model)
        if mark:
            scene_xml.set_params(edits, sc.files[material.node.file], material.node,
                                 [("integer", "seed", str(MARK_SEED))])
        main = sc.files[sc.path]
        film = self._film()
        if film is not None:
            scene_xml.set_params(edits, sc.files[film.file], film, [("integer", "width", str(self.size[0])),
                                                                    ("integer", "height", str(self.size[1]))])
        new = []
        for k, v in self.defines.items():
            if k in sc.defaults:
                scene_xml.set_attr(edits, main, sc.defaults[k], "value", v)
            else:
                new.append(f'<default name="{k}" value="{v}"/>'.encode())
        if new:
            edits.replace(sc.path, sc.root.head_end, sc.root.head_end, b"".join(b"\n    " + n for n in new))
        for other in self.scene.materials:  # one msx refuses as written: its built-in twin (said on the page)
            if other is not material and not other.loads and other.builtin:
                scene_xml.set_model(edits, sc, other, "builtin")
        return scene_xml.apply_with_includes(edits, sc, self._copy)

    def _copy(self, file, data: bytes) -> str:
        """An edited included file, in the work folder (named by its content)."""
        copy = self.workdir / (hashlib.sha256(data).hexdigest()[:16] + ".xml")
        copy.write_bytes(data)
        return str(copy)

    def _scene(self, name, params):
        """The loaded scene of these parameters; the candidates of one material stay loaded together (the
        interleaved sweep switches between them at every render: ``sweep``)."""
        import drjit as dr

        self._use()
        key = (name, tuple(sorted(params.items())))
        if not hasattr(self, "_scenes"):
            self._scenes = {}
        if key not in self._scenes:
            material = self.materials[params["material"]]
            text = self.text(material, params["model"], mark=params.get("mark") == "1")
            threads = dr.thread_count()  # as _render.load_scene: Mitsuba 3.9 deadlocks reading an EXR on 1 thread
            if threads < 2:
                dr.set_thread_count(2)
            try:
                self._scenes[key] = self.mi.load_string(text.decode(), parallel=False)  # docs/mitsuba.md
            finally:
                if threads < 2:
                    dr.set_thread_count(threads)
        return self._scenes[key]

    def release(self):
        self._scenes = {}
        super().release()

    def mask(self, run: MaterialRun):
        """The material's pixels: the whole footprint of the pixel hits a shape that uses the material (its BSDF,
        or a BSDF holding it, describes the marked msx_posfree)."""
        row = next(r for r in run.rows if r[0] != "builtin")
        scene = self._scene(run.name, dict(self.params(run, row), mark="1"))
        mark = f"seed={MARK_SEED}"
        targets = [s for s in scene.shapes() if s.bsdf() is not None and mark in str(s.bsdf())]
        return self.shapes_mask(scene, targets)


# ---------------------------------------------------------------- one material


def _rows(material):
    rows = []
    for m in CANDIDATES[material.surface]:
        if m in material.refused:
            continue
        if m == "builtin":
            if material.builtin:
                rows.append(("builtin", "-"))
        else:
            rows.append((m, "pt"))
    return rows


def _label(row):
    return common.row_label(row)


def worst_tile(image, reference, mask, tile=TILE, min_pixels=32):
    """(largest |relative change of the mean| over a tile × tile block of the mask in %, its (y, x)): the
    "worst region" where `image` and `reference` differ."""
    h, w = mask.shape
    best = (float("nan"), None)
    for y in range(0, h, tile):
        for x in range(0, w, tile):
            m = mask[y:y + tile, x:x + tile]
            if m.sum() < min_pixels:
                continue
            r = float(reference[y:y + tile, x:x + tile][m].mean())
            if r <= 0:
                continue
            d = 100.0 * (float(image[y:y + tile, x:x + tile][m].mean()) - r) / r
            if not (abs(d) <= abs(best[0])):
                best = (d, (y, x))
    return best


def _verdict(entry):
    from .report import _verdict as verdict

    return verdict(entry["bias2"], entry["bias2_se"], entry["mean_error_pct"], entry["mean_error_se_pct"])


def choose(entries, order):
    """The cheapest of `entries` (dicts with 'model', 'cost': time per sample, optionally 'cost_se' its standard
    error over the seeds and 'noisy_time': renders too short to time): a candidate ties with the lowest cost
    unless it costs more by over TIME_TIE and 3 standard errors of the difference; renders too short to time
    tie with everything. Ties go to the first in `order` (the a priori cost order)."""
    if not entries:
        return None
    finite = [e for e in entries if math.isfinite(e["cost"])]
    low = min(finite, key=lambda e: e["cost"]) if finite else None

    def tied(e):
        if low is None or not math.isfinite(e["cost"]) or e.get("noisy_time") or low.get("noisy_time"):
            return True
        margin = max(TIME_TIE * low["cost"], uncertainty.Z * math.hypot(e.get("cost_se", 0.0), low.get("cost_se", 0.0)))
        return e["cost"] <= low["cost"] + margin

    return min([e for e in entries if tied(e)], key=lambda e: order.index(e["model"]) if e["model"] in order
               else len(order))


def sweep(renderer, run: MaterialRun, st: AdviceSettings, progress=None):
    """{row: {spp: renders.Image}}: every candidate at every spp and seed, with the seeds of renders.sweep
    (the same images), but interleaved — for each spp and seed, one render of each candidate in turn — so that
    a change of the machine's load during the sweep falls on every candidate alike: their times per sample,
    which choose the cheapest model, are compared under the same load."""
    data = {row: {spp: renders.Image([], []) for spp in st.spps} for row in run.rows}
    params = {row: renderer.params(run, row) for row in run.rows}
    for row in run.rows:
        renderer.warm_up(run.name, params[row])  # loads it and compiles its kernels, untimed
    total, done = len(run.rows) * len(st.spps) * st.seeds, 0
    for spp in st.spps:
        for k in range(st.seeds):
            for row in run.rows:
                img, seconds = renderer.render(run.name, params[row], spp,
                                               seed=renders._seed_base(run, row) + 1000 * k + spp)
                data[row][spp].images.append(img)
                data[row][spp].seconds.append(seconds)
                done += 1
                if progress:
                    progress(done, total, f"renders ({_label(row)}, {spp} spp)")
    renderer.release()
    return data


def evaluate(renderer, run: MaterialRun, st: AdviceSettings, cache: Path, progress=None):
    """Renders one material's candidates and reference; returns its verdict (dict)."""
    m = run.material
    ref_row = ("invariance", "pt") if m.surface != "diffuse" else ("heitz", "pt")
    mask = renderer.mask(run)
    renderer.release()  # one scene loaded at a time, but for the candidates of the sweep
    if not mask.any():
        return dict(material=m, problem="not seen from the camera (no pixel of the image shows it first)")
    h1, h2, ref_seconds, cached = _references.reference(
        renderer, run, renderer.size, ref_row, st.ref_spp, cache,
        progress=(lambda d, t: progress(d, t, f"reference ({_label(ref_row)}, {st.ref_spp} spp)")) if progress else None)
    ref = 0.5 * (h1 + h2)
    renderer.release()
    noise = renders.reference_noise(h1, h2, ref, mask)
    data = sweep(renderer, run, st, progress=progress)
    stats, terms = renders.statistics(run, data, ref, noise, mask)
    top = max(st.spps)
    base_row = ("builtin", "-") if ("builtin", "-") in data else run.rows[0]
    base_t = float(np.mean(data[base_row][top].seconds)) / top
    entries = []
    for row in run.rows:
        r = next(x for x in stats if (x["model"], x["estimator"]) == row and x["spp"] == top)
        secs = float(np.mean(data[row][top].seconds))
        spread = np.std(data[row][top].seconds, ddof=1) / math.sqrt(len(data[row][top].seconds)) / top \
            if len(data[row][top].seconds) > 1 else 0.0
        e = dict(r, row=row, terms=terms[row], se=r["bias2_se"], cost=secs / top, cost_se=float(spread), seconds_top=secs,
                 time_ratio=(secs / top) / base_t if base_t > 0 else float("nan"), noisy_time=secs < NOISY_RENDER,
                 unbiased=row[0] in UNBIASED_MODELS)
        e["verdict"] = _verdict(e)
        entries.append(e)
    groups = uncertainty.rank([dict(e, label=e["label"]) for e in entries])
    group_of = {e["label"]: k for k, g in enumerate(groups) for e in g}
    smith_groups = {group_of[e["label"]] for e in entries if e["unbiased"]}
    for e in entries:
        e["group"] = group_of[e["label"]]
        e["matches_smith"] = (e["unbiased"] or (e["group"] in smith_groups and
                                                abs(e["mean_error_pct"]) <= uncertainty.Z * e["mean_error_se_pct"]))
    order = CANDIDATES[m.surface]
    right = [e for e in entries if e["verdict"] == "right"]
    fast = choose(right, order)
    # The accurate model: the cheapest that matches the Smith model and is not visibly off; the unbiased walk
    # is the Smith model itself (in expectation), so it is there whatever this run's noise.
    accurate = choose([e for e in entries if e["matches_smith"] and (e["verdict"] != "off" or e["unbiased"])
                       and (e["verdict"] == "right" or e["unbiased"])], order)
    means = {row: sum(data[row][top].images) / len(data[row][top].images) for row in run.rows}
    single_row = base_row if base_row[0] in ("builtin", "single") else None
    effect = None
    if single_row:
        s = next(e for e in entries if e["row"] == single_row)
        tile, where = worst_tile(means[single_row], ref, mask)
        # What multiple scattering changes: single scattering's error against the reference (the Smith model).
        effect = dict(mean=s["mean_error_pct"], mean_se=s["mean_error_se_pct"], bias2=s["bias2"], se=s["bias2_se"],
                      verdict=s["verdict"], tile=tile, where=where)
    return dict(material=m, entries=entries, groups=groups, fast=fast, accurate=accurate, effect=effect,
                stats=stats, means=means, ref=ref, mask=mask, ref_row=ref_row, ref_spp=st.ref_spp,
                ref_noise=noise, ref_cached=cached, ref_seconds=ref_seconds,
                recommended=_recommended(fast, accurate, effect))


def _model_name(e):
    """A candidate as a model name: the built-in renders what `single` does (identical by construction)."""
    return None if e is None else ("single" if e["model"] == "builtin" else e["model"])


def _recommended(fast, accurate, effect):
    """What --write-scene writes: the cheapest model that looks right; where none does at this run's noise, the
    accurate model if single scattering is visibly off (or there is no single-scattering candidate), else
    nothing (the material is left as it is: this run cannot tell)."""
    if fast is not None:
        return _model_name(fast)
    if effect is None or effect["verdict"] == "off":
        return _model_name(accurate)
    return None


# ---------------------------------------------------------------- the command


def _preflight(variant, scene, materials):
    """Loads each material's BSDF alone, as written and as each candidate (scene_xml.standalone): a material
    that does not load as written renders as its built-in twin in the others' renders (``loads``); a candidate
    msx refuses is left out (``refused``); a material with no msx candidate left is not evaluated (``problem``)."""
    import mitsuba as mi

    import msx

    mi.set_variant(variant)
    msx.register(backend="jit" if not variant.startswith("scalar") else None)

    def refusal(model):
        try:
            mi.load_string(scene_xml.standalone(scene, m, model), parallel=False)
            return None
        except Exception as e:  # noqa: BLE001 - Mitsuba's or msx's message, in one line
            _stopped(e)
            return one_line(e)

    for m in scene.materials:
        if m.problem:
            continue
        m.loads = refusal(None) is None
        if m not in materials:
            continue
        for row in _rows(m):
            why = refusal(row[0])
            if why:
                m.refused[row[0]] = why
        left = [row for row in _rows(m) if row[0] not in m.refused]
        if not any(row[0] != "builtin" for row in left) or "heitz" in m.refused:
            m.problem = "msx refuses it: " + (m.refused.get("heitz") or next(iter(m.refused.values()), "?"))


def run(args):
    """``msx compare SCENE.xml [-D k=v …] [--quick] [--out DIR] [--write-scene OUT.xml] [--material KEY …]``."""
    from .._render import resolve_scene, shipped_scene, with_assets

    t_start = time.perf_counter()
    defines = {}
    for item in args.define or []:
        if "=" not in item:
            raise RenderError(f"-D expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        defines[k] = v
    path = resolve_scene(args.scene)
    try:
        if not os.path.exists(args.scene):  # a shipped scene by name: with its generated assets
            import msx

            path = msx.scene_path(shipped_scene(args.scene).name)
    except (RenderError, FileNotFoundError):
        pass
    try:
        scene = scene_xml.discover(path, defines)
    except scene_xml.SceneXmlError as e:
        raise RenderError(str(e)) from None
    defines = with_assets(str(path), defines)
    scene = scene_xml.discover(path, defines)
    for note in scene.notes:
        _say(f"msx: {note}")
    materials = scene.materials
    if args.material:
        keys = {m.key for m in materials}
        for k in args.material:
            if k not in keys:
                _say(f"msx: --material {k}: no such material in {Path(path).name} (its materials: "
                     f"{', '.join(sorted(keys)) or 'none'})")
        materials = [m for m in materials if m.key in args.material]
    if not scene.materials:
        raise RenderError(f"{Path(path).name}: no BSDF msx can stand in for ({', '.join(scene_xml.STANDINS)}, also "
                          f"inside {', '.join(scene_xml.WRAPPERS)})")
    if not materials:
        raise RenderError(f"{Path(path).name}: none of the materials asked for (--material) is in the scene")
    out = output_folder(args.out, f"--out {args.out}")
    if args.write_scene:
        output_folder(Path(args.write_scene).resolve().parent, f"--write-scene {args.write_scene}")
    variant = args.variant or "llvm_ad_rgb"
    if variant == "llvm_ad_rgb":
        from .._variants import llvm_problem

        why = llvm_problem()
        if why:
            raise RenderError(f"msx compare SCENE renders in llvm_ad_rgb, which does not work here: {why}")
    _preflight(variant, scene, materials)
    for m in materials:
        if m.problem:
            _say(f"msx: material {m.key}: {m.problem}; not evaluated")
        elif m.refused:
            _say(f"msx: material {m.key}: " + "; ".join(f"{k} not evaluated ({v})" for k, v in m.refused.items()))
    st = settings(args.quick)
    cache = Path(args.cache) if args.cache else _cache.folder("references")
    output_folder(cache, f"--cache {cache}" if args.cache else f"the cache folder {cache} (--cache to choose one)")
    todo = [m for m in materials if not m.problem]
    print(f"msx compare {Path(path).name}{' --quick' if st.quick else ''}: {len(todo)} material(s) "
          f"({', '.join(m.key for m in todo)}); variant {variant}; report in {out}", flush=True)
    work = Path(tempfile.mkdtemp(prefix="msx-scene-"))
    stage = Path(tempfile.mkdtemp(prefix=".msx-partial-", dir=out))
    try:
        renderer = SceneRenderer(variant, scene, defines, st.max_size, work)
        renderer.materials = {m.key: m for m in todo}
        prog = common.Progress([m.key for m in todo])
        results = [dict(material=m, problem=m.problem) for m in materials if m.problem]
        for m in todo:
            prog.stage(m.key)
            run_m = MaterialRun(f"{Path(path).stem}-{m.key}", m, _rows(m))
            try:
                results.append(evaluate(renderer, run_m, st, cache, progress=prog.update))
            except RenderError:
                raise
            except Exception as e:  # noqa: BLE001 - a material msx refuses: one line, the others evaluated
                _stopped(e)
                _say(f"msx: material {m.key}: not evaluated: {one_line(e)}")
                results.append(dict(material=m, problem=one_line(e)))
            renderer.release()
        written, written_files = None, []
        try:
            if args.write_scene:
                written = write_scene(scene, results, args.write_scene, renderer, written_files)
            total = time.perf_counter() - t_start
            notes = list(scene.notes) + [
                f"material {m.key}: {'; '.join(f'{k} left out ({v})' for k, v in m.refused.items())}"
                for m in materials if m.refused and not m.problem]
            notes += [f"material {m.key} does not load as written: the other materials' renders use its built-in "
                      "twin" for m in scene.materials if not m.loads]
            _write_outputs(stage, out, scene, results, st, variant, total, written, notes)
        except BaseException:
            # Stopped (Ctrl-C) or failed after the scene was written but before the report was: the scene
            # goes too, so that a run leaves all of its outputs or none.
            for f in written_files:
                Path(f).unlink(missing_ok=True)
            raise
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        shutil.rmtree(work, ignore_errors=True)
    print(f"\nreport: {out / 'index.html'} ({time.perf_counter() - t_start:.0f} s)")
    for r in results:
        print("  " + summary_line(r))
    if written:
        print(f"wrote {written}")


def _stopped(error):
    """A Ctrl-C that arrived while Mitsuba loaded or rendered (msx's plugin constructor, a render's custom op)
    comes back wrapped in Mitsuba's or Dr.Jit's error: it stops the run (msx/cli.py), it is not a material msx
    refuses."""
    from ..cli import stop_received

    chain, e = [], error
    while e is not None and len(chain) < 10:
        chain.append(e)
        e = e.__cause__ or e.__context__
    if stop_received() or any(isinstance(x, KeyboardInterrupt) or "KeyboardInterrupt" in str(x) for x in chain):
        raise KeyboardInterrupt from error


def _say(line):
    try:
        sys.stderr.write(line + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def summary_line(r):
    m = r["material"]
    if r.get("problem"):
        return f"{m.key}: not evaluated ({r['problem']})"
    eff = r["effect"]
    ms = (f"single scattering {common.pct(eff['mean'], eff['mean_se'])} in mean radiance "
          f"({uncertainty.sign_word(eff['mean'], eff['mean_se'])}), {VERDICT_WORDS[eff['verdict']]}"
          if eff else "no single-scattering candidate")
    fast = _model_name(r["fast"])
    if fast == "single":
        advice = "`single` suffices"
    elif fast:
        advice = f"cheapest that looks right: {fast}"
    else:
        advice = "cannot tell which model looks right at this run's noise"
    acc = _model_name(r["accurate"])
    return (f"{m.key}: {ms}; {advice}; accurate: {acc or '—'}; "
            f"--write-scene: {r['recommended'] or 'left as it is'}")


# ---------------------------------------------------------------- --write-scene


def write_scene(scene, results, target, renderer=None, written_files=None):
    """The scene file with each evaluated material set to its recommended model (scene_xml.set_model: only
    that BSDF element's type and parameters change), written atomically; checked by loading it. A material in
    an included file is written into a copy of that file beside the target, ``<target stem>.<its name>``,
    which the target's <include> names instead. ``written_files`` (a list), if given, receives every file
    written under its final name, as it is written."""
    written_files = [] if written_files is None else written_files
    edits = scene_xml.Edits()
    for r in results:
        m, model = r["material"], r.get("recommended")
        if r.get("problem") or not model:
            continue
        if model == "single" and m.kind != "msx_posfree":
            continue  # the built-in is single scattering itself: nothing to change
        scene_xml.set_model(edits, scene, m, model)
    target = Path(target)
    copies = {}  # {final path: bytes} of the included files with a change

    def copy_beside(file, data):
        path = target.with_name(f"{target.stem}.{Path(file).name}")
        copies[path] = data
        return path.name

    data = scene_xml.apply_with_includes(edits, scene, copy_beside)
    tmps = {path: path.with_name(f".{path.name}.{os.getpid()}.tmp") for path in [*copies, target]}
    try:
        for path, tmp in tmps.items():
            tmp.write_bytes(copies.get(path, data))
        if renderer is not None:  # it must load (the original's folder on the resolver path for its files)
            renderer._use()
            if copies:
                renderer.mi.Thread.thread().file_resolver().prepend(str(target.resolve().parent))
            for path, tmp in tmps.items():  # loaded under their final names
                if path != target:
                    written_files.append(path)
                    os.replace(tmp, path)
            used = set().union(*(scene_xml._REF.findall(d.decode(errors="replace")) for d in scene.files.values()))
            try:
                renderer.mi.load_string(data.decode(), parallel=False,
                                         **{k: v for k, v in renderer.defines.items() if k in used})
            except Exception as e:  # noqa: BLE001
                unloadable = [m.key for m in scene.materials if not m.loads]
                if not unloadable:
                    raise
                # The original does not load either: the materials at fault are left as written.
                _say(f"msx: --write-scene {target}: does not load, as the original does not (material "
                     f"{', '.join(unloadable)} left as written): {one_line(e)}")
        for path, tmp in tmps.items():
            if tmp.exists():
                written_files.append(path)
                os.replace(tmp, path)
    except BaseException as e:
        for path, tmp in tmps.items():
            tmp.unlink(missing_ok=True)
            if path != target and path in copies:
                path.unlink(missing_ok=True)
        if isinstance(e, Exception):
            raise RenderError(f"--write-scene {target}: {one_line(e)}") from None
        raise
    if target.resolve().parent != scene.path.resolve().parent:
        _say(f"msx: {target} refers to files relative to {scene.path.parent} (render it from there, or copy it "
             "beside the original)")
    for path in copies:
        _say(f"msx: --write-scene: wrote {path} (an included file with a material changed; {target.name} "
             "includes it instead)")
    return target


# ---------------------------------------------------------------- outputs


def _write_outputs(stage, out, scene, results, st, variant, seconds, written, notes):
    from . import charts

    pngs = {}
    for r in results:
        if r.get("problem"):
            continue
        m = r["material"]
        key = _file_key(m.key)
        ys, xs = np.nonzero(r["mask"])
        pad = 4
        crop = ((max(ys.min() - pad, 0), min(ys.max() + 1 + pad, r["mask"].shape[0])),
                (max(xs.min() - pad, 0), min(xs.max() + 1 + pad, r["mask"].shape[1])))
        rows = [e["row"] for e in r["entries"]]
        imgs = [r["means"][row] for row in rows] + [r["ref"]]
        labels = [f"{_label(row)}\n{_verdict_word(e)}" for row, e in zip(rows, r["entries"])] + \
                 [f"reference ({_label(r['ref_row'])}, {r['ref_spp']} spp)"]
        grid = charts.image_grid(stage / f"{key}_models.png", imgs, labels, cols=len(imgs), crop=crop,
                                 title=f"{m.key}: converged candidates ({max(st.spps)} spp × {st.seeds} seeds)")
        (y0, y1), (x0, x1) = crop
        cut = lambda im: im[y0:y1, x0:x1]  # noqa: E731 - the material's bounding box, as the grid above
        diff = charts.difference_grid(stage / f"{key}_diff.png", cut(r["ref"]), [cut(r["means"][row]) for row in rows],
                                      [_label(row) for row in rows], cut(r["mask"]),
                                      f"{m.key}: candidate − reference (the material's pixels)")
        evt = charts.error_vs_time(stage / f"{key}_error_vs_time.png", f"{m.key}: error against time",
                                   r["stats"])
        pngs[m.key] = dict(models=grid, diff=diff, evt=evt)
    common.write_csv(stage / "results.csv", [dict(s, material=r["material"].key) for r in results if not r.get("problem")
                                 for s in r["stats"]],
         ["material", "model", "estimator", "spp", "seconds", "rel_mse", "rel_mse_se", "rel_rms_pct", "bias2",
          "bias2_se", "mean_error_pct", "mean_error_se_pct", "variance", "unbiased"])
    common.write_csv(stage / "materials.csv", [_material_row(r) for r in results], MATERIAL_COLUMNS)
    common.write_csv(stage / "candidates.csv", [dict(e, material=r["material"].key, rank=e["group"] + 1)
                                    for r in results if not r.get("problem") for e in r["entries"]],
         CANDIDATE_COLUMNS)
    page = _page(scene, results, pngs, st, variant, seconds, written, notes)
    (stage / "index.html").write_text(page)
    for f in sorted(stage.iterdir(), key=lambda p: p.name == "index.html"):  # the page last
        os.replace(f, out / f.name)


MATERIAL_COLUMNS = ["material", "kind", "surface", "status", "ms_mean_pct", "ms_mean_se_pct", "ms_rms_pct",
                    "ms_worst_tile_pct", "single_verdict", "fast_model", "accurate_model", "recommended",
                    "candidates"]


CANDIDATE_COLUMNS = ["material", "model", "estimator", "spp", "bias2", "bias2_se", "mean_error_pct",
                     "mean_error_se_pct", "verdict", "rank", "matches_smith", "unbiased", "seconds_top", "time_ratio"]


def _material_row(r):
    m = r["material"]
    row = dict(material=m.key, kind=m.kind, surface=m.surface)
    if r.get("problem"):
        return dict(row, status=f"not evaluated: {r['problem']}")
    eff = r["effect"] or {}
    row.update(status="evaluated", ms_mean_pct=eff.get("mean"), ms_mean_se_pct=eff.get("mean_se"),
               ms_rms_pct=100 * math.sqrt(max(eff["bias2"], 0.0)) if eff else None,
               ms_worst_tile_pct=eff.get("tile"), single_verdict=eff.get("verdict"),
               fast_model=_model_name(r["fast"]) or "", accurate_model=_model_name(r["accurate"]) or "",
               recommended=r["recommended"] or "",
               candidates="; ".join(f"{e['label']}={e['verdict']}" for e in r["entries"]))
    return row


def _file_key(key):
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in key)


VERDICT_WORDS = {"right": "looks right", "off": "visibly off", "undecided": "cannot tell at this noise"}


def _verdict_word(e):
    return VERDICT_WORDS[e["verdict"]]


def _page(scene, results, pngs, st, variant, seconds, written, notes):
    from .report import CSS, LOOK_MEAN, LOOK_RMS, _img, _rms_bias

    esc = html.escape
    out = [f"<!doctype html><html><head><meta charset=utf-8><title>msx compare {esc(scene.path.name)}</title>"
           f"<style>{CSS}</style></head><body>",
           f"<h1>Which model does {esc(scene.path.name)} need?</h1>",
           f"<p class=note>{esc(str(scene.path))}; variant {esc(variant)}; {'--quick: ' if st.quick else ''}"
           f"images capped to {st.max_size} px, {', '.join(map(str, st.spps))} spp × {st.seeds} seeds per "
           f"candidate, reference {st.ref_spp} spp; {seconds:.0f} s.</p>",
           "<h2 id=advice>Per material</h2>",
           "<table><tr><th class=l>material</th><th>single scattering: mean radiance vs the reference</th>"
           f"<th>its RMS</th><th>its worst {TILE}-px region</th><th class=l>accurate model</th><th class=l>fast model</th>"
           f"<th class=l>written by --write-scene</th></tr>"]
    for r in results:
        m = r["material"]
        if r.get("problem"):
            out.append(f"<tr><td class=l>{esc(m.label)}</td><td class=l colspan=6>not evaluated: "
                       f"{esc(r['problem'])}</td></tr>")
            continue
        eff = r["effect"]
        fast = _model_name(r["fast"])
        fast_txt = ("<b>single suffices</b>" if fast == "single" else f"<b>{esc(fast)}</b>" if fast else
                    "<span class=warn>cannot tell at this run's noise</span>")
        out.append(f"<tr><td class=l>{esc(m.label)}</td>"
                   f"<td>{common.pct(eff['mean'], eff['mean_se']) if eff else '—'}"
                   f"{' (' + uncertainty.sign_word(eff['mean'], eff['mean_se']) + ')' if eff else ''}</td>"
                   f"<td>{_rms_bias(eff['bias2'], eff['se']) if eff else '—'}</td>"
                   f"<td>{common.pct(eff['tile']) if eff else '—'}</td>"
                   f"<td class=l>{esc(_model_name(r['accurate']) or '—')}</td><td class=l>{fast_txt}</td>"
                   f"<td class=l>{esc(r['recommended'] or 'left as it is')}</td></tr>")
    out.append("</table>")
    out.append(f"<p class=note><b>Looks right</b>: the converged render within {LOOK_MEAN:g} % of the reference in "
               f"mean radiance over the material's pixels and {LOOK_RMS:g} % RMS per pixel, each bound "
               f"{uncertainty.Z:g} standard errors on the pessimistic side; <b>visibly off</b>: beyond a threshold "
               "by more than 3 standard errors; else <b>cannot tell</b>. <b>Fast model</b>: the cheapest candidate "
               f"that looks right (measured time per sample; within {TIME_TIE:.0%} or 3 standard errors of each "
               f"other, or from renders shorter than {NOISY_RENDER * 1000:.0f} ms, the simpler model). "
               "<b>Accurate model</b>: the cheapest that looks right, whose bias² is tied with the unbiased walk's "
               "and whose mean radiance is within noise of the reference; else the unbiased walk. What multiple "
               "scattering changes: single scattering (the built-in) against the reference (the Smith model with "
               "every bounce, unbiased), over the material's pixels (the pixels that see it first; the worst region: "
               f"the {TILE} × {TILE}-pixel block whose mean differs most). <b>--write-scene</b> writes the fast "
               "model; where none looks right at this run's noise, the accurate one if single scattering is "
               "visibly off, else it leaves the material as it is. " + (f"Scene written with the recommendations: {esc(str(written))}."
                                                 if written else "") + "</p>")
    if notes:
        out.append("<p class=warn>" + "<br>".join(esc(n) for n in notes) + "</p>")
    for r in results:
        if r.get("problem"):
            continue
        m = r["material"]
        out.append(f"<h2>{esc(m.label)}</h2>")
        out.append(f"<p class=note>{int(r['mask'].sum())} pixels; used by {m.users} shape(s); reference "
                   f"{esc(_label(r['ref_row']))} {r['ref_spp']} spp, noise {r['ref_noise']:.2e} (relative MSE)"
                   f"{', from the cache' if r['ref_cached'] else ''}.</p>")
        out.append("<table><tr><th class=l>candidate</th><th>mean radiance vs reference</th><th>RMS of the converged "
                   "render</th><th>bias² ± s.e.</th><th class=l>verdict</th><th>rank</th><th>time per sample ÷ "
                   "built-in</th></tr>")
        for e in r["entries"]:
            tr = f"×{e['time_ratio']:.2f}" + (" <span class=warn>(renders of a few ms: noise)</span>"
                                               if e["noisy_time"] else "")
            out.append(f"<tr><td class=l>{esc(e['label'])}</td><td>{common.pct(e['mean_error_pct'], e['mean_error_se_pct'])}"
                       f" ({uncertainty.sign_word(e['mean_error_pct'], e['mean_error_se_pct'])})</td>"
                       f"<td>{_rms_bias(e['bias2'], e['bias2_se'])}</td><td>{e['bias2']:.2e} ± {e['bias2_se']:.1e}</td>"
                       f"<td class=l>{_verdict_word(e)}</td><td>{e['group'] + 1}</td><td>{tr}</td></tr>")
        out.append("</table>")
        out.append(f"<p>Ranking by bias²: <b>{esc(uncertainty.ranking_text(r['groups']))}</b> (“=”: tied within "
                   "noise).</p>")
        p = pngs[m.key]
        out.append(_img(p["models"], f"{m.key}: the candidates side by side with the reference"))
        out.append(_img(p["diff"], f"{m.key}: difference to the reference"))
        out.append(_img(p["evt"], f"{m.key}: relative MSE against render time"))
    out.append("</body></html>")
    return "\n".join(out)
