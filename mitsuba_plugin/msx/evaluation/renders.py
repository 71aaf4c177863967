"""Renders of the evaluation: the sweep scenes, their Smith reference, the spp
sweep of every model × estimator, object masks and the side-by-side scenes.

All renders of a run happen in this process, in the variant of the route the
report names: in ``llvm_*`` msx_posfree is the Dr.Jit engine (drjit's default
symbolic mode, as the built-ins), and a configuration the engine does not run
(BDPT on dielectrics, ``invariance`` on the diffuse surface) is rendered in
``scalar_rgb`` with the native back end instead — ``Renderer.routes`` lists
them and the report says so; in scalar variants the native back end uses every
render thread, the Python back end one (the GIL). Seconds are the wall time of
``mi.render`` (scene loading and the first, compiling render excluded).
"""

from __future__ import annotations

import gc
import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .common import UNBIASED, rel_mse, row_label
from .uncertainty import bias2_terms, mean_se, mean_terms


# What the Dr.Jit engine's refusals end with (msx/jit/bsdf.py ``ALTERNATIVES``).
ENGINE_REFUSAL = "msx.register(backend='batched')"


@dataclass
class SweepScene:
    name: str           # scene file stem
    title: str
    surface: str        # conductor | dielectric
    builtin: str        # Mitsuba's twin BSDF
    rows: list          # (model, estimator) rows of the sweep
    lighting: str


@dataclass
class Image:
    """Renders of one row at one spp: one image per seed and the seconds each took."""
    images: list
    seconds: list


# ---------------------------------------------------------------- rendering


def _raise_if_stopped():
    """A Ctrl-C can be lost below msx during a render: its handler ran (msx/cli.py noted the signal) but the
    KeyboardInterrupt never reached this code, and ``msx compare --quick`` signalled 4.2–4.6 s in ran to its end
    with exit 0 (2026-11-28, after ``auto``'s walk went behind a per-packet ``dr.if_stmt``, so raised, most
    likely, inside the Dr.Jit engine's Python code while drjit recorded the kernel; the layer that swallows it
    was not traced). The noted signal stops the run at the end of the render it arrived in."""
    from ..cli import stop_received

    if stop_received():
        raise KeyboardInterrupt


class Renderer:
    """Loads the scenes of one variant and renders them, timing mi.render."""

    def __init__(self, variant: str, scenes_dir: Path):
        import drjit as dr
        import mitsuba as mi

        import msx

        mi.set_variant(variant)
        msx.register(backend="jit" if not variant.startswith("scalar") else None)
        if variant.startswith("scalar"):
            # Native back end: every core; the Python back end serialises on the GIL (one thread).
            dr.set_thread_count((os.cpu_count() or 1) if msx.backend() == "native" else 1)
        self.mi, self.dr, self.msx = mi, dr, msx
        self.variant = variant
        self.scenes_dir = Path(scenes_dir)
        self._loaded = None  # (key, scene)
        self._fallback = None  # the scalar_rgb renderer of what the Dr.Jit engine does not run
        self.routes = {}  # (scene, model, estimator) → the variant it was rendered in, where not `variant`

    def _use(self):
        """This renderer's variant (the fallback renderer may have switched it)."""
        if self.mi.variant() != self.variant:
            self.mi.set_variant(self.variant)

    def scene_path(self, name):
        return self.scenes_dir / f"{name}.xml"

    def params(self, scene: SweepScene | str, row, size=None, builtin=None):
        model, est = row
        p = {}
        if model == "builtin":
            p["bsdf"] = builtin or (scene.builtin if isinstance(scene, SweepScene) else "roughconductor")
        else:
            p.update(bsdf="msx_posfree", model=model, estimator=est if est != "-" else "pt")
        if size:
            p["width"], p["height"] = str(size[0]), str(size[1])
        return p

    def _scene(self, name, params):
        from .._render import load_scene, with_assets

        self._use()
        params = with_assets(str(self.scene_path(name)), params)
        key = (name, tuple(sorted(params.items())))
        if self._loaded is None or self._loaded[0] != key:
            self._loaded = None
            gc.collect()  # no live msx instance may remain when a built-in renders symbolically
            try:
                self._loaded = (key, load_scene(self.mi, str(self.scene_path(name)), **params))
            except Exception as e:  # Mitsuba's error, the plugin's message inside
                if self.variant.startswith("scalar") or ENGINE_REFUSAL not in str(e):
                    raise
                return None  # the Dr.Jit engine does not run it: the fallback renders it
        return self._loaded[1]

    def _fallback_for(self, name, params):
        """The scalar_rgb renderer (native back end) of a row the engine does not run, noted in ``routes``."""
        if self._fallback is None:
            self._fallback = Renderer("scalar_rgb", self.scenes_dir)
        self.routes[(name, params.get("model"), params.get("estimator", "pt"))] = self._fallback.variant
        return self._fallback

    def render(self, name, params, spp, seed):
        """(image as float64 [H, W, 3], seconds of mi.render)."""
        scene = self._scene(name, params)
        if scene is None:
            return self._fallback_for(name, params).render(name, params, spp, seed)
        msx_row = params.get("bsdf") == "msx_posfree"
        ctx = self.msx.evaluated_mode() if (msx_row and self.msx.backend() == "batched") else _Null()
        with ctx:
            t0 = time.perf_counter()
            img = self.mi.render(scene, seed=seed, spp=spp)
            arr = np.array(img, dtype=np.float64)
            seconds = time.perf_counter() - t0
        _raise_if_stopped()
        if not np.all(np.isfinite(arr)):
            raise RuntimeError(f"non-finite pixels in {name} {params}")
        return arr[..., :3], seconds

    def warm_up(self, name, params):
        """One tiny render: loads the scene and compiles its kernels outside the timed renders."""
        self.render(name, params, 1, 10**6)

    def release(self):
        self._loaded = None
        if self._fallback is not None:
            self._fallback.release()
        gc.collect()

    def object_mask(self, name, params, sub=3):
        """Pixels whose whole footprint (sub × sub rays) hits a surface with msx_posfree: the object's pixels."""
        scene = self._scene(name, dict(params, bsdf="msx_posfree", model="correlated", estimator="pt"))
        return self.shapes_mask(scene, _msx_shapes(scene), sub)

    def shapes_mask(self, scene, targets, sub=3):
        """Pixels of a loaded scene whose whole footprint (sub × sub rays) hits one of the shapes `targets`."""
        mi = self.mi
        sensor = scene.sensors()[0]
        film = sensor.film()
        w, h = film.crop_size()
        if self.variant.startswith("llvm"):
            ys, xs, sy, sx = np.meshgrid(np.arange(h), np.arange(w), np.arange(sub), np.arange(sub), indexing="ij")
            u = ((xs + (sx + 0.5) / sub) / w).ravel().astype(np.float32)
            v = ((ys + (sy + 0.5) / sub) / h).ravel().astype(np.float32)
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(mi.Float(u), mi.Float(v)), mi.Point2f(0.5, 0.5))
            si = scene.ray_intersect(ray)
            ours = mi.Bool(False)
            for shape in targets:
                ours = ours | (si.is_valid() & (si.shape == mi.ShapePtr(shape)))
            hit = np.array(ours.numpy(), dtype=bool)
            return hit.reshape(h, w, sub * sub).all(axis=2)
        return self._mask_scalar(scene, w, h, sub, targets)

    def _mask_scalar(self, scene, w, h, sub, targets):
        mi = self.mi
        sensor = scene.sensors()[0]
        mask = np.ones((h, w), dtype=bool)
        for y in range(h):
            for x in range(w):
                for j in range(sub * sub):
                    sx, sy = (j % sub + 0.5) / sub, (j // sub + 0.5) / sub
                    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((x + sx) / w, (y + sy) / h), mi.Point2f(0.5, 0.5))
                    si = scene.ray_intersect(ray)
                    if not (bool(si.is_valid()) and any(si.shape is t for t in targets)):
                        mask[y, x] = False
                        break
        return mask


def _msx_shapes(scene):
    """The shapes whose BSDF is msx_posfree, possibly wrapped (a normal map): both back ends describe
    themselves as MsxPosfree[...]."""
    return [s for s in scene.shapes() if "MsxPosfree" in str(s.bsdf())]


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


# ---------------------------------------------------------------- reference


def _scene_text(path: Path) -> str:
    """The scene file and every file it includes (the cache key depends on all of them)."""
    text = path.read_text()
    inc = path.parent / "include"
    if inc.is_dir():
        text += "".join(f.name + f.read_text() for f in sorted(inc.glob("*.xml")))
    return text


def reference_key(renderer: Renderer, name, params, spp, row):
    import msx

    blob = json.dumps({"scene": _scene_text(renderer.scene_path(name)), "params": params, "spp": spp,
                       "row": list(row), "variant": renderer.variant, "version": msx.__version__,
                       "native": msx.native_version()}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def _reference_chunk(spp):
    """spp per render of a reference of `spp` (each half in chunks; a chunk's seed is its offset in the half)."""
    return max(1, min(spp // 2, 256))


def continues(smaller, spp):
    """True if a reference of spp can start from ``smaller`` = (h1, h2, seconds, its spp): same chunks, so
    its halves' first chunks are the smaller one's renders (same seeds) and the result is bit-identical to
    rendering it whole (a half's sum is its mean × its spp, exact in float64 for a power of two)."""
    if smaller is None or not smaller[3] < spp:
        return False
    half = smaller[3] // 2
    return (half > 0 and half & (half - 1) == 0 and smaller[3] % 2 == 0
            and _reference_chunk(smaller[3]) == _reference_chunk(spp) and half % _reference_chunk(spp) == 0)


def reference(renderer: Renderer, scene: SweepScene, size, row, spp, cache: Path, progress=None, smaller=None):
    """The converged render of the Smith multiple-scattering BSDF (`row`, an unbiased estimator):
    (image, per-pixel-mean noise as relative MSE, seconds, from_cache). Two independent halves give the
    noise: var(mean) = MSE(h1, h2)/4 per pixel and channel. ``smaller`` = (h1, h2, seconds, spp) of a
    reference of this scene and row at fewer spp: where ``continues`` allows it, only the spp it lacks are
    rendered (seconds: the whole reference's render time)."""
    params = renderer.params(scene, row, size)
    key = reference_key(renderer, scene.name, params, spp, row)
    path = Path(cache) / f"reference-{scene.name}-{key}.npz"
    if path.exists():
        d = np.load(path)
        return d["h1"], d["h2"], float(d["seconds"]), True
    halves, seconds = [], 0.0
    chunk = _reference_chunk(spp)
    start = continues(smaller, spp)
    if start:
        seconds = float(smaller[2])
    for half in range(2):
        acc, done = None, 0
        if start:
            done = smaller[3] // 2
            acc = smaller[half] * done
            if progress:
                progress(half * (spp // 2) + done, spp)
        while done < spp // 2:
            n = min(chunk, spp // 2 - done)
            img, s = renderer.render(scene.name, params, n, seed=7_000_000 + half * 100_000 + done)
            acc = img * n if acc is None else acc + img * n
            done += n
            seconds += s
            if progress:
                progress(half * (spp // 2) + done, spp)
        halves.append(acc / done)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, h1=halves[0], h2=halves[1], seconds=seconds)
    return halves[0], halves[1], seconds, False


def reference_noise(h1, h2, ref, mask):
    """Relative MSE of the mean of two halves due to its own noise."""
    d = (h1 - h2)[mask]
    return float(np.mean(d * d)) / 4.0 / float(np.mean(ref[mask] ** 2))


# ---------------------------------------------------------------- sweep


def _seed_base(scene: SweepScene, row):
    """Independent renders per row (a shared seed correlates the noise of two models), except that `single`
    shares the built-in's seeds: with the same samples the two images must be equal."""
    return 0 if row[0] in ("builtin", "single") else 100_000 * scene.rows.index(row)


class _Counter:
    """Renders done and planned, for the progress lines (the adaptive part adds to `total` as it goes)."""

    def __init__(self, total, progress):
        self.done, self.total, self.progress = 0, total, progress


def _render_spp(renderer, scene, st, params, row, spp, out, counter):
    imgs, secs = [], []
    base = _seed_base(scene, row)
    for k in range(st.seeds):
        # spp a power of two (two powers differ by a multiple of 1000 = 2³·5³ never), k < 3 and
        # spp ≤ 65 536: base + 1000 k + spp repeats neither within a row nor across rows.
        img, s = renderer.render(scene.name, params, spp, seed=base + 1000 * k + spp)
        imgs.append(img)
        secs.append(s)
        counter.done += 1
        if counter.progress:
            counter.progress(counter.done, counter.total, f"renders ({row_label(row)}, {spp} spp)")
    out[row][spp] = Image(imgs, secs)


def _next_spps(scene, row, out, more, cap_spp):
    """Whether the row's sweep doubles once more: `single` follows the built-in's spps (same samples, same
    images: the check "single = built-in"); every other row by ``more`` (uncertainty.wants_more)."""
    spp = max(out[row])
    if row[0] == "single" and ("builtin", "-") in out:
        return spp * 2 in out[("builtin", "-")]
    return 2 * spp <= cap_spp and bool(more(row, out[row]))


def sweep(renderer: Renderer, scene: SweepScene, st, progress=None, more=None, cap_spp=None):
    """{row: {spp: Image}} over every row, spp and seed of the settings; then, adaptively, each row's spp
    doubled while ``more(row, {spp: Image})`` says a target is still to be measured (the rule:
    uncertainty.wants_more) and the doubling stays ≤ cap_spp. The seeds follow the same scheme at every spp
    (reproducible: a render at a given row, spp and seed is the same in every run), and the decision depends
    on the images only, not on measured times, so the same command renders the same spps."""
    size = (st.size, st.size)
    out = {}
    counter = _Counter(len(scene.rows) * len(st.spps) * st.seeds, progress)
    for row in scene.rows:
        params = renderer.params(scene, row, size)
        renderer.warm_up(scene.name, params)
        out[row] = {}
        for spp in st.spps:
            _render_spp(renderer, scene, st, params, row, spp, out, counter)
        while more is not None and cap_spp and _next_spps(scene, row, out, more, cap_spp):
            counter.total += st.seeds
            _render_spp(renderer, scene, st, params, row, 2 * max(out[row]), out, counter)
    renderer.release()
    return out


def extend(renderer: Renderer, scene: SweepScene, st, out, more, cap_spp, progress=None):
    """The adaptive part of ``sweep`` again on its result (after a better reference changed the fits): rows
    whose rule now asks for more are doubled further. Returns the renders added."""
    size = (st.size, st.size)
    counter = _Counter(0, progress)
    for row in scene.rows:
        params = None
        while _next_spps(scene, row, out, more, cap_spp):
            if params is None:
                params = renderer.params(scene, row, size)
                renderer.warm_up(scene.name, params)
            counter.total += st.seeds
            _render_spp(renderer, scene, st, params, row, 2 * max(out[row]), out, counter)
    renderer.release()
    return counter.done


def statistics(scene: SweepScene, data, ref, ref_noise, mask):
    """Per row and spp: rel MSE against the reference (mean over seeds) and its square root, the relative
    RMS error, seconds (mean), variance (spread over seeds, relative); per row, from its seed mean at the
    top spp: bias² (against the reference, both noises removed) with its standard error, and the signed
    error of the mean radiance over the object with its standard error (uncertainty.py). Returns (rows,
    {row: per-pixel bias² contributions}) — the contributions let two rows be compared on the same pixels."""
    rows, terms = [], {}
    for row, by_spp in data.items():
        spps = sorted(by_spp)
        top = by_spp[spps[-1]]
        terms[row] = bias2_terms(top.images, ref, mask, ref_noise)
        bias2, bias2_se = mean_se(terms[row])
        mean_err, mean_err_se = mean_se(mean_terms(top.images, ref, mask))
        for spp in spps:
            im = by_spp[spp]
            errs = [rel_mse(i, ref, mask) for i in im.images]
            rel = float(np.mean(errs))
            rows.append(dict(scene=scene.name, model=row[0], estimator=row[1], label=row_label(row), spp=spp,
                             seconds=float(np.mean(im.seconds)), rel_mse=rel,
                             rel_mse_se=float(np.std(errs, ddof=1) / math.sqrt(len(errs))) if len(errs) > 1 else 0.0,
                             rel_rms_pct=100.0 * math.sqrt(max(rel, 0.0)),
                             variance=seed_variance(im.images, mask, ref), bias2=bias2, bias2_se=bias2_se,
                             mean_error_pct=100.0 * mean_err, mean_error_se_pct=100.0 * mean_err_se,
                             unbiased=row in UNBIASED))
    return rows, terms


def seed_variance(images, mask, reference=None):
    """Relative variance of one render (per pixel and channel), from the spread over seeds, normalised like
    rel_mse by mean(R²) of the reference (the seed mean's own square would carry its noise)."""
    n = len(images)
    if n < 2:
        return float("nan")
    m = sum(images) / n
    d = sum(((i - m)[mask]) ** 2 for i in images) / (n - 1)
    r = reference if reference is not None else m
    return float(np.mean(d)) / float(np.mean(r[mask] ** 2))


def write_exr(path, image):
    """A linear RGB image as EXR (Mitsuba's Bitmap)."""
    import mitsuba as mi

    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32), pixel_format=mi.Bitmap.PixelFormat.RGB).write(str(path))
