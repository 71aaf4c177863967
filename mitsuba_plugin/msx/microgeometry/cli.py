"""Ground truth from explicit microgeometry: the command lines — ``msx simulate`` (one simulation; its
parser is added to msx's CLI, msx/cli.py) and ``python3 -m msx.microgeometry OUT_DIR`` (the full comparison
on its own)."""

from __future__ import annotations

import os

from . import DIELECTRIC_IOR, SURFACES, compare, simulate


def add_simulate_parser(sub, parents=()):
    """Adds the `simulate` subcommand to an argparse subparsers object."""
    s = sub.add_parser("simulate", help="ray-trace generated Beckmann surfaces; energy and lobes per scattering order",
                       parents=list(parents))
    s.add_argument("--surface", required=True, choices=SURFACES)
    s.add_argument("--distribution", default="beckmann", choices=("beckmann",),
                   help="slope distribution of the generated surfaces (Gaussian processes: Beckmann only)")
    s.add_argument("--alpha", type=float, required=True, help="roughness (along x if --alpha-v is given)")
    s.add_argument("--alpha-v", type=float, default=None, help="roughness along y (anisotropic)")
    s.add_argument("--theta-i", type=float, required=True, help="incident polar angle (rad, < π/2)")
    s.add_argument("--phi-i", type=float, default=0.0, help="incident azimuth (rad; x is the α direction)")
    s.add_argument("--rays", type=int, required=True)
    s.add_argument("--out", required=True, help="output folder (energy.csv, lobes.csv, params.json)")
    s.add_argument("--eta", type=float, default=0.0, help="conductor: real part of the IOR (with --k; default F = 1)")
    s.add_argument("--k", type=float, default=1.0, help="conductor: imaginary part of the IOR")
    s.add_argument("--ior", type=float, default=DIELECTRIC_IOR, help="dielectric: relative IOR η_int/η_ext")
    s.add_argument("--albedo", type=float, default=1.0, help="diffuse: facet albedo")
    s.add_argument("--grid", type=int, default=1024, help="vertices per side of each surface (power of two)")
    s.add_argument("--corr-cells", type=float, default=16.0, help="correlation length in grid cells")
    s.add_argument("--surfaces", type=int, default=16, help="independent surface realisations (error batches)")
    s.add_argument("--theta-bins", type=int, default=36)
    s.add_argument("--phi-bins", type=int, default=36)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--threads", type=int, default=0, help="0 = all cores")
    s.set_defaults(func=cmd_simulate)
    return s


def cmd_simulate(args):
    from .._render import RenderError, output_folder

    for option, value, low in (("--rays", args.rays, 1), ("--surfaces", args.surfaces, 1),
                               ("--theta-bins", args.theta_bins, 1), ("--phi-bins", args.phi_bins, 1),
                               ("--threads", args.threads, 0), ("--seed", args.seed, 0)):
        if value < low:
            raise RenderError(f"{option} must be an integer ≥ {low} (got {value})")
    output_folder(args.out, f"--out {args.out}")  # before the simulation, not after it
    try:
        res = simulate(args.surface, args.alpha, args.alpha_v, args.theta_i, args.rays, phi_i=args.phi_i,
                       eta=args.eta, k=args.k, ior=args.ior, albedo=args.albedo, grid=args.grid,
                       corr_cells=args.corr_cells, surfaces=args.surfaces, theta_bins=args.theta_bins,
                       phi_bins=args.phi_bins, seed=args.seed, threads=args.threads)
    except ValueError as e:  # the core's parameter check: one line naming the parameter
        raise RenderError(str(e)) from None
    res.write(args.out)
    c = res.counts.sum(axis=0)
    print(f"{res.rays:,} rays in {res.seconds:.1f} s ({res.rays / max(res.seconds, 1e-9):,.0f} rays/s); "
          f"lost {int(c[1])}, capped {int(c[2])}")
    for lab, (er, et, ser, set_, e, se) in res.energy_estimates().items():
        print(f"  order {lab:>5}: E_r = {er:.5f} ± {ser:.5f}   E_t = {et:.5f} ± {set_:.5f}")
    print(f"wrote {os.path.join(args.out, 'energy.csv')} and {os.path.join(args.out, 'lobes.csv')}")


def main(argv=None):
    """``python3 -m msx.microgeometry OUT_DIR``: the full comparison on its own."""
    import argparse

    p = argparse.ArgumentParser(prog="python3 -m msx.microgeometry",
                                description="compare every model with ray tracing on generated Beckmann surfaces")
    p.add_argument("out", help="output folder (charts, errors.csv/.md/.html, summary.md)")
    p.add_argument("--rays", type=int, default=4_000_000, help="rays per configuration")
    p.add_argument("--model-samples", type=int, default=2_000_000, help="samples per model and configuration")
    p.add_argument("--quick", action="store_true", help="reduced grid and rays (smoke test)")
    p.add_argument("--no-cache", action="store_true", help="rerun simulations even if cached (msx cache shows where)")
    a = p.parse_args(argv)
    r = compare(a.out, rays=a.rays, model_samples=a.model_samples, quick=a.quick, cache=not a.no_cache)
    print(r["markdown"])
