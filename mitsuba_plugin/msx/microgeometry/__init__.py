"""Ground truth from explicit microgeometry.

Rays are traced through all their bounces on generated random surfaces with
Beckmann statistics (Rust core, ``src/microgeometry/``, reached through the C
ABI ``msx_sim_*``), and every model of the plugin is compared with the result,
order by order (docs/microgeometry.md).

* :func:`simulate` runs one simulation and returns a :class:`SimResult`
  (energies and lobes per scattering order with their Monte Carlo errors);
  :meth:`SimResult.write` writes ``energy.csv`` and ``lobes.csv``.
* :func:`model_lobes` measures a model the same way: paths sampled from it
  (``msx_sample_orders_batch``) binned by scattering order and direction.
* :func:`compare` runs the grid of configurations, writes charts (PNG), the
  error table (CSV, Markdown, HTML) into a folder and returns the Markdown
  fragment for a report.

This package: the API here (simulation, model lobes, errors, :func:`compare`); the report's tables and
charts in ``report.py``; the command lines (``msx simulate``, ``python3 -m msx.microgeometry``) in ``cli.py``.

Errors: each surface realisation is one batch; the standard error of a
simulated quantity is the standard deviation of its per-surface means over
√(number of surfaces), which contains the finite-surface error as well as the
ray sampling error.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..plugin import parameters

SURFACES = tuple(parameters.SURFACES)
ORDER_LABELS = ("1", "2", "3", "4+", "total")
# Models compared per surface, from the core's table of names (src/config.rs): those defined for
# Beckmann (the simulated surfaces are Beckmann; fastmsx is GGX only), but the shortcuts of another
# model's walk (auto is correlated with a shortcut).
MODELS = {s: tuple(parameters.models(s, distribution="beckmann", shortcut=False)) for s in SURFACES}
# Closed forms have no orders beyond their whole value.
ANALYTIC = tuple(parameters.models(random_walk=False))
# Of these, single *is* order 1 (Walter 2007); the others are a whole lobe
# with no order decomposition: only their total is compared.
WHOLE = tuple(parameters.models(per_order=False))


def _has_order(model, lab):
    """Whether a model's value for order `lab` is meaningful."""
    if model in WHOLE:
        return lab == "total"
    return not (model in ANALYTIC and lab in ("2", "3", "4+"))
# The configurations of the comparison (issue 12).
THETAS = (0.0, 0.5, 1.0, 1.5)
ALPHAS = ((0.25, 0.25), (0.5, 0.5), (1.0, 1.0), (1.0, 0.1))
DIELECTRIC_IOR = 1.5
_ERR_LEN = 512
_MODEL_MAX_BOUNCES = 256


def _native():
    from .._native import ffi, lib

    return ffi, lib


# ------------------------------------------------------------------ progress


class Progress:
    """Progress on stderr: one rewritten line on a terminal, plain lines
    (every 10 %) otherwise."""

    def __init__(self, label, total, enabled=True, stream=None):
        self.label, self.total, self.enabled = label, max(1, total), enabled
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.t0 = time.perf_counter()
        self.last_decile = -1

    def update(self, done):
        if not self.enabled:
            return
        el = time.perf_counter() - self.t0
        frac = min(1.0, done / self.total)
        eta = el / frac * (1 - frac) if frac > 0 else float("nan")
        msg = f"{self.label}: {frac * 100:5.1f} % ({done}/{self.total}), {el:6.1f} s elapsed, ETA {eta:6.1f} s"
        if self.tty:
            self.stream.write("\r" + msg + " ")
            if frac >= 1.0:
                self.stream.write("\n")
        else:
            decile = int(frac * 10 + 1e-9)
            if decile == self.last_decile:
                return
            self.last_decile = decile
            self.stream.write(msg + "\n")
        self.stream.flush()


# ---------------------------------------------------------------- simulation


@dataclass
class SimResult:
    """Tallies of one simulation (sums per surface realisation) and its parameters."""

    params: dict
    lobes: np.ndarray  # [surface, order(4), theta, phi]: Σ weight
    energy: np.ndarray  # [surface, order(4), 2 (reflected, transmitted)]: Σ weight
    counts: np.ndarray  # [surface, 4]: rays, lost, capped, Σ bounces
    seconds: float = 0.0
    slopes: dict = field(default_factory=dict)  # realised slope statistics of the surfaces

    @property
    def theta_bins(self):
        return self.lobes.shape[2]

    @property
    def phi_bins(self):
        return self.lobes.shape[3]

    @property
    def rays(self):
        return int(self.counts[:, 0].sum())

    def theta_edges(self):
        return np.linspace(0.0, math.pi, self.theta_bins + 1)

    def phi_edges(self):
        """Absolute azimuths of the φ bin edges (bin 0 centred on φ_i)."""
        d = 2 * math.pi / self.phi_bins
        return self.params["phi_i"] + (np.arange(self.phi_bins + 1) - 0.5) * d

    def solid_angles(self):
        te = self.theta_edges()
        return np.outer(np.cos(te[:-1]) - np.cos(te[1:]), np.full(self.phi_bins, 2 * math.pi / self.phi_bins))

    def _per_surface(self, sums):
        """Per-surface fractions of the incident flux: sums / rays (surface axis first)."""
        rays = self.counts[:, 0].astype(float)
        return sums / rays.reshape((-1,) + (1,) * (sums.ndim - 1))

    @staticmethod
    def _mean_se(x):
        m = x.shape[0]
        return x.mean(axis=0), x.std(axis=0, ddof=1) / math.sqrt(m)

    def energy_estimates(self):
        """{order label: (E_r, E_t, se_r, se_t, E, se)} with 'total' = all orders."""
        e = self._per_surface(self.energy)  # [s, order, 2]
        out = {}
        for k, lab in enumerate(ORDER_LABELS):
            x = e[:, k, :] if k < 4 else e.sum(axis=1)
            m, se = self._mean_se(x)
            tm, tse = self._mean_se(x.sum(axis=1))
            out[lab] = (m[0], m[1], se[0], se[1], tm, tse)
        return out

    def lobe_estimates(self):
        """(value, se), each [order(5), theta, phi]: dE/dω (flux fraction per
        steradian) averaged over each bin, orders 1, 2, 3, 4+, total."""
        per = self._per_surface(self.lobes) / self.solid_angles()[None, None]
        per = np.concatenate([per, per.sum(axis=1, keepdims=True)], axis=1)
        return self._mean_se(per)

    def write(self, out_dir):
        """Writes energy.csv, lobes.csv and params.json into out_dir."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        lines = ["order,E_r,E_t,E,stderr_r,stderr_t,stderr"]
        for lab, (er, et, ser, set_, e, se) in self.energy_estimates().items():
            lines.append(f"{lab},{er:.8g},{et:.8g},{e:.8g},{ser:.4g},{set_:.4g},{se:.4g}")
        (out / "energy.csv").write_text("\n".join(lines) + "\n")
        val, se = self.lobe_estimates()
        te, pe = self.theta_edges(), self.phi_edges()
        omega = self.solid_angles()
        rows = ["order,theta_o,phi_o,value,stderr,theta_lo,theta_hi,phi_lo,phi_hi,solid_angle"]
        for k, lab in enumerate(ORDER_LABELS):
            for it in range(self.theta_bins):
                for ip in range(self.phi_bins):
                    rows.append(
                        f"{lab},{0.5 * (te[it] + te[it + 1]):.6f},{0.5 * (pe[ip] + pe[ip + 1]):.6f},"
                        f"{val[k, it, ip]:.9g},{se[k, it, ip]:.4g},{te[it]:.6f},{te[it + 1]:.6f},"
                        f"{pe[ip]:.6f},{pe[ip + 1]:.6f},{omega[it, ip]:.9g}"
                    )
        (out / "lobes.csv").write_text("\n".join(rows) + "\n")
        c = self.counts.sum(axis=0)
        info = dict(self.params)
        info.update(
            rays=int(c[0]), lost=int(c[1]), capped=int(c[2]), mean_bounces=float(c[3] / max(1, c[0] - c[1] - c[2])),
            seconds=self.seconds, rays_per_second=(c[0] / self.seconds if self.seconds > 0 else None), slopes=self.slopes,
        )
        (out / "params.json").write_text(json.dumps(info, indent=2) + "\n")

    def save_npz(self, path):
        np.savez_compressed(path, lobes=self.lobes, energy=self.energy, counts=self.counts,
                            meta=json.dumps({"params": self.params, "seconds": self.seconds, "slopes": self.slopes}))

    @staticmethod
    def load_npz(path):
        z = np.load(path)
        meta = json.loads(str(z["meta"]))
        return SimResult(meta["params"], z["lobes"], z["energy"], z["counts"], meta["seconds"], meta.get("slopes", {}))


def simulate(surface, alpha, alpha_v=None, theta_i=0.0, rays=1_000_000, *, phi_i=0.0, eta=0.0, k=1.0,
             ior=DIELECTRIC_IOR, albedo=1.0, grid=1024, corr_cells=16.0, surfaces=16, theta_bins=36, phi_bins=36,
             max_bounces=100_000, seed=0, threads=0, progress=True, label=None, chunks=40):
    """Traces `rays` rays (split evenly over `surfaces` independent surface
    realisations) arriving from (θ_i, φ_i) on Beckmann surfaces of roughness
    (alpha, alpha_v). Conductor facets use the complex IOR (eta, k) — (0, 1) is
    the perfect mirror, F = 1 —, dielectric facets the relative IOR `ior`,
    diffuse facets `albedo`. Returns a :class:`SimResult`."""
    ffi, lib = _native()
    if surface not in SURFACES:
        raise ValueError(f"surface must be one of {', '.join(SURFACES)}, got {surface!r}")
    alpha_v = alpha if alpha_v is None else alpha_v
    params = dict(surface=surface, distribution="beckmann", alpha_u=float(alpha), alpha_v=float(alpha_v),
                  theta_i=float(theta_i), phi_i=float(phi_i), eta=float(eta), k=float(k), ior=float(ior),
                  albedo=float(albedo), grid=int(grid), corr_cells=float(corr_cells), surfaces=int(surfaces),
                  theta_bins=int(theta_bins), phi_bins=int(phi_bins), max_bounces=int(max_bounces), seed=int(seed))
    p = ffi.new("MsxSimParams *")
    p.surface = {"conductor": lib.MSX_SURFACE_CONDUCTOR, "dielectric": lib.MSX_SURFACE_DIELECTRIC,
                 "diffuse": lib.MSX_SURFACE_DIFFUSE}[surface]
    for name in ("alpha_u", "alpha_v", "theta_i", "phi_i", "eta", "k", "ior", "albedo", "corr_cells"):
        setattr(p, name, params[name])
    for name in ("grid", "surfaces", "theta_bins", "phi_bins", "max_bounces", "seed"):
        setattr(p, name, params[name])
    out = ffi.new("MsxSim **")
    err = ffi.new("char[]", _ERR_LEN)
    if lib.msx_sim_new(p, out, err, _ERR_LEN) != lib.MSX_OK:
        raise ValueError(ffi.string(err).decode(errors="replace"))
    sim = ffi.gc(out[0], lib.msx_sim_free)
    per_surface = max(1, -(-int(rays) // surfaces))
    steps = max(1, min(chunks, per_surface // 1000))
    bar = Progress(label or f"simulate {surface} α=({alpha:g},{alpha_v:g}) θi={theta_i:g}", per_surface * surfaces,
                   enabled=progress)
    t0 = time.perf_counter()
    done = 0
    bar.update(0)
    for s in range(steps):
        n = per_surface * (s + 1) // steps - done
        if lib.msx_sim_run(sim, n, threads, err, _ERR_LEN) != lib.MSX_OK:
            raise RuntimeError(ffi.string(err).decode(errors="replace"))
        done += n
        bar.update(done * surfaces)
    seconds = time.perf_counter() - t0
    nb = theta_bins * phi_bins
    lobes = np.empty(surfaces * 4 * nb)
    energy = np.empty(surfaces * 4 * 2)
    counts = np.empty(surfaces * 4, dtype=np.uint64)
    rc = lib.msx_sim_read(sim, ffi.cast("double *", lobes.ctypes.data), lobes.size,
                          ffi.cast("double *", energy.ctypes.data), energy.size,
                          ffi.cast("uint64_t *", counts.ctypes.data), counts.size)
    if rc != lib.MSX_OK:
        raise RuntimeError(f"msx_sim_read failed ({rc})")
    res = SimResult(params, lobes.reshape(surfaces, 4, theta_bins, phi_bins), energy.reshape(surfaces, 4, 2),
                    counts.reshape(surfaces, 4).astype(np.int64), seconds)
    res.slopes = _slope_stats(sim, params)
    return res


def _slope_stats(sim, params):
    """Realised slope variances of the generated triangles, averaged over the
    surfaces, against Beckmann's α²/2 (a record of what was simulated)."""
    ffi, lib = _native()
    n = params["grid"]
    h = np.empty(n * n)
    dx, dy = ffi.new("double *"), ffi.new("double *")
    vx, vy = [], []
    for s in range(params["surfaces"]):
        if lib.msx_sim_surface(sim, s, ffi.cast("double *", h.ctypes.data), h.size, dx, dy) != lib.MSX_OK:
            return {}
        g = h.reshape(n, n)
        # Forward differences along x and y (every triangle's slopes are such differences).
        vx.append(np.mean(((np.roll(g, -1, axis=1) - g) / dx[0]) ** 2))
        vy.append(np.mean(((np.roll(g, -1, axis=0) - g) / dy[0]) ** 2))
    m = len(vx)
    return {
        "var_x": float(np.mean(vx)), "var_x_se": float(np.std(vx, ddof=1) / math.sqrt(m)),
        "var_y": float(np.mean(vy)), "var_y_se": float(np.std(vy, ddof=1) / math.sqrt(m)),
        "beckmann_var_x": params["alpha_u"] ** 2 / 2, "beckmann_var_y": params["alpha_v"] ** 2 / 2,
    }


# -------------------------------------------------------------------- models


def bin_index(res: SimResult, wo):
    """Direction bin of each row of `wo` (n, 3), as the simulation bins (θ_o
    uniform on [0, π], φ_o bins centred on φ_i + k·Δφ): θ index · phi_bins + φ index."""
    nt, npb = res.theta_bins, res.phi_bins
    theta = np.arccos(np.clip(wo[:, 2], -1.0, 1.0))
    it = np.minimum((theta / math.pi * nt).astype(np.int64), nt - 1)
    dphi = 2 * math.pi / npb
    phi = np.arctan2(wo[:, 1], wo[:, 0]) - res.params["phi_i"]
    ip = np.mod(np.floor(phi / dphi + 0.5).astype(np.int64), npb)
    return it * npb + ip


def model_lobes(res: SimResult, model, *, samples=2_000_000, groups=8, seed=1, max_bounces=_MODEL_MAX_BOUNCES):
    """The model's lobes per order in the direction bins of `res`, estimated
    the way the simulation measures them: `samples` directions sampled from
    the model (``msx_sample_orders_batch``: Importance mode, each sample's
    weight f·|cos θ_o|/pdf and its scattering order) binned by order and
    direction. Returns (value, se, per_group): value and se [order(5), theta,
    phi] in flux per steradian like :meth:`SimResult.lobe_estimates`,
    per_group [group, order, theta, phi]; the standard errors are the spread
    between `groups` independent groups. Analytic models put their whole value
    in order 1.

    Sampling rather than integrating `eval` over each bin: the random walks'
    per-order `eval` estimates are heavy-tailed at high orders (rare values
    10⁵ times the mean), so bin integrals of a few hundred thousand
    evaluations miss most of the order-4+ energy; sampled weights are bounded
    by 1 for lossless facets."""
    from ..core import CoreBsdf

    p = res.params
    b = CoreBsdf(p["surface"], "beckmann", model, channels=1, seed=seed, max_bounces=max_bounces,
                 alpha=p["alpha_u"], alpha_v=p["alpha_v"], eta=p["eta"], k=p["k"], ior=p["ior"],
                 reflectance=p["albedo"], radiance=False)
    st, ct = math.sin(p["theta_i"]), math.cos(p["theta_i"])
    wi = np.array([[st * math.cos(p["phi_i"]), st * math.sin(p["phi_i"]), ct]])
    nt, npb = res.theta_bins, res.phi_bins
    nb = nt * npb
    omega = res.solid_angles()
    rng = np.random.default_rng(seed)
    per_group = np.zeros((groups, 5, nt, npb))
    n = max(1, samples // groups)
    chunk = 1 << 18
    for g in range(groups):
        sums = np.zeros(4 * nb)
        done = 0
        while done < n:
            m = min(chunk, n - done)
            wo, weight, pdf, orders = b.sample_orders(wi, rng.random((3, m)))
            ok = orders > 0
            idx = (np.minimum(orders[ok], 4).astype(np.int64) - 1) * nb + bin_index(res, wo[ok])
            sums += np.bincount(idx, weights=weight[0][ok], minlength=4 * nb)
            done += m
        lob = sums.reshape(4, nt, npb) / n / omega[None]
        per_group[g, :4] = lob
        per_group[g, 4] = lob.sum(axis=0)
    value = per_group.mean(axis=0)
    se = per_group.std(axis=0, ddof=1) / math.sqrt(groups) if groups > 1 else np.zeros_like(value)
    return value, se, per_group


# ---------------------------------------------------------------- comparison


def simulation_path(params) -> Path:
    """The cache entry of one simulation (msx/_cache.py, ``simulations/``): its parameters, msx's version and
    the simulator's digest in the name."""
    from .. import __version__, _cache

    # The simulator is part of the compiled core.
    return _cache.folder("simulations") / (_cache.key_of(params, __version__, _cache.core_digest()) + ".npz")


def cached_simulation(params, *, cache=True, progress=True, label=None):
    """(SimResult, computed now?) for `params` (the keywords of :func:`simulate`): from the cache when an intact
    entry is there, else simulated and written to it atomically. A damaged entry is reported in one line and
    simulated again."""
    from .. import _cache

    path = simulation_path(params)
    if cache and _cache.check_file(path):
        try:
            return SimResult.load_npz(path), False
        except Exception as e:  # noqa: BLE001 - intact bytes that still do not load: recompute
            _cache.report(path, f"unreadable ({type(e).__name__}: {e})")
            _cache.remove(path)
    res = simulate(progress=progress, label=label, **params)
    _cache.write_file(path, res.save_npz)
    return res, True


def _alpha_label(a):
    return f"{a[0]:g}" if a[0] == a[1] else f"({a[0]:g}, {a[1]:g})"


def errors_for(res: SimResult, model, lobes):
    """Errors of one model against one simulation: relative energy error per
    order (with its standard error), of the reflected and transmitted totals,
    and the L1 distance of the total lobe ∫|f_model − f_sim||cos θ_o| dω with
    the value expected from the Monte Carlo noise alone."""
    sim_v, sim_se = res.lobe_estimates()
    mv, mse, groups = lobes
    omega = res.solid_angles()
    e_sim = res.energy_estimates()
    e_groups = (groups * omega).sum(axis=(2, 3))  # [group, order]
    row = {}
    for k, lab in enumerate(ORDER_LABELS):
        es, ess = e_sim[lab][4], e_sim[lab][5]
        em = float(e_groups[:, k].mean())
        ems = float(e_groups[:, k].std(ddof=1) / math.sqrt(len(e_groups))) if len(e_groups) > 1 else 0.0
        if not _has_order(model, lab):
            em = ems = float("nan")  # no such order in this model (CSV: nan, tables: —)
        rel = (em - es) / es if es > 0 else float("nan")
        rel_se = abs(em / es) * math.hypot(ems / em if em > 0 else 0.0, ess / es) if es > 0 else float("nan")
        row[f"E{lab}_sim"], row[f"E{lab}_sim_se"], row[f"E{lab}_model"], row[f"E{lab}_model_se"] = es, ess, em, ems
        row[f"rel{lab}"], row[f"rel{lab}_se"] = rel, rel_se
    up = np.zeros(res.theta_bins, dtype=bool)
    up[: res.theta_bins // 2] = True
    for part, mask in (("R", up), ("T", ~up)):
        es = float((sim_v[4][mask] * omega[mask]).sum())
        em = float((mv[4][mask] * omega[mask]).sum())
        row[f"E{part}_sim"], row[f"E{part}_model"] = es, em
        row[f"rel{part}"] = (em - es) / es if es > 1e-9 else float("nan")
    diff = np.abs(mv[4] - sim_v[4]) * omega
    sigma = np.hypot(mse[4], sim_se[4]) * omega
    row["L1"] = float(diff.sum())
    row["L1_noise"] = float(sigma.sum() * math.sqrt(2 / math.pi))
    return row


def compare(out_dir, *, rays=4_000_000, quick=False, thetas=THETAS, alphas=ALPHAS, surfaces=SURFACES,
            model_samples=2_000_000, grid=1024, corr_cells=16.0, n_surfaces=16, theta_bins=36, phi_bins=36, seed=0,
            progress=True, cache=True, link_prefix=""):
    """Runs every configuration (surfaces × α × θ_i), compares every applicable
    model with the simulation and writes into `out_dir`: one lobe chart per
    configuration (``lobes_<surface>_a<α>_t<θ>.png``), an energy chart per
    surface, ``errors.csv`` (every number), ``errors.md`` / ``errors.html``
    (tables) and ``summary.md``. `quick` runs a reduced grid with fewer rays
    (for smoke tests). Simulations are cached in msx's cache folder
    (``simulations/``, msx/_cache.py) by their parameters and the simulator. Returns a dict with the Markdown fragment ('markdown'; its links
    are relative to out_dir, prefixed with `link_prefix`, e.g. "microgeometry/"
    when the fragment goes into a report one folder up), the HTML table
    ('html'), the rows and the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        rays = min(rays, 200_000)
        model_samples = min(model_samples, 200_000)
        thetas, alphas, grid, corr_cells = (0.0, 1.0), ((0.5, 0.5),), 256, 8.0
    t_start = time.perf_counter()
    configs = [(s, a, t) for s in surfaces for a in alphas for t in thetas]
    rows, charts = [], []
    total_rays, total_seconds = 0, 0.0
    for i, (surface, alpha, theta) in enumerate(configs):
        kw = dict(surface=surface, alpha=alpha[0], alpha_v=alpha[1], theta_i=theta, rays=rays, grid=grid,
                  corr_cells=corr_cells, surfaces=n_surfaces, theta_bins=theta_bins, phi_bins=phi_bins, seed=seed,
                  ior=DIELECTRIC_IOR, albedo=1.0)
        label = f"[{i + 1}/{len(configs)}] {surface} α={_alpha_label(alpha)} θi={theta:g}"
        res, fresh = cached_simulation(kw, cache=cache, progress=progress, label=label)
        if fresh:
            total_rays += res.rays
            total_seconds += res.seconds
        model_data = {}
        for model in MODELS[surface]:
            lob = model_lobes(res, model, samples=model_samples, seed=seed + 1)
            model_data[model] = lob[:2]
            r = errors_for(res, model, lob)
            r.update(surface=surface, alpha=_alpha_label(alpha), alpha_u=alpha[0], alpha_v=alpha[1], theta_i=theta,
                     model=model)
            rows.append(r)
        if progress:
            sys.stderr.write(f"{label}: models compared ({time.perf_counter() - t_start:.0f} s so far)\n")
        charts.append(report.lobe_chart(out, res, model_data, surface, alpha, theta))
    energy_charts = [report.energy_chart(out, rows, s, alphas, thetas) for s in surfaces]
    surf_chart = surface_chart(out, alphas[-1], grid=grid, corr_cells=corr_cells, n_surfaces=n_surfaces, seed=seed)
    fragment, html = report.write_tables(out, rows, surfaces, link_prefix)
    local_fragment, _ = report.write_tables(out, rows, surfaces, "")
    elapsed = time.perf_counter() - t_start
    speed = f"{total_rays / total_seconds:,.0f} rays/s" if total_seconds > 0 else "cached simulations"
    def summary(prefix, frag):
        md = [
            "## Ground truth from explicit microgeometry",
            "",
            f"Rays traced through all their bounces on generated Beckmann surfaces ({n_surfaces} realisations of "
            f"{grid}² vertices, correlation length {corr_cells:g} cells, {rays:,} rays per configuration; "
            f"{speed}; {elapsed:.0f} s in all). Errors of the simulation: spread between surface realisations. "
            f"Models: {model_samples:,} Importance-mode samples each, binned by order and direction like the rays. "
            "How it works and what it shows: docs/microgeometry.md.",
            "",
            frag,
            "",
        ]
        if surf_chart:
            md += ["Generated surfaces against Beckmann (slope histograms; tested in tests/microgeometry.rs):", "",
                   f"![surfaces]({prefix}surfaces.png)", ""]
        md += ["Energy per order against θ_i:", ""]
        md += [f"![{Path(c).stem}]({prefix}{Path(c).name})" for c in energy_charts if c]
        md += ["", "Lobes per order in the plane of incidence (one chart per configuration): "
               + ", ".join(f"[{Path(c).stem}]({prefix}{Path(c).name})" for c in charts if c)]
        return "\n".join(md) + "\n"

    markdown = summary(link_prefix, fragment)
    # summary.md lies in out_dir: its links are relative to out_dir, without the report's prefix.
    (out / "summary.md").write_text(summary("", local_fragment))
    return {"markdown": markdown, "html": html, "rows": rows, "charts": charts + energy_charts,
            "energy_charts": [c for c in energy_charts if c], "surface_chart": surf_chart,
            "csv": str(out / "errors.csv"), "seconds": elapsed}


# The report's parts (charts and tables; report.py) and the surface chart, as before the split.
from . import report  # noqa: E402  (report.py reads this module's names)
from .report import surface_chart  # noqa: E402,F401
