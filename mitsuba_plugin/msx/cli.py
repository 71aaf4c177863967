"""Command line: ``msx render SCENE.xml``, ``msx compare`` and ``msx simulate``
(ray tracing on generated microgeometry, msx/microgeometry.py).

Errors end the run with one line on stderr naming the problem (exit code 1;
``--verbose`` adds the traceback); Ctrl-C stops every worker (exit code 130).
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
from pathlib import Path

from ._render import DEFAULT_VARIANT, RenderError, one_line, render_scene, write_image

__all__ = ["main", "render_scene", "write_image"]


class UsageError(Exception):
    """Bad command-line input; the message is one line."""


def _parse_defines(items):
    params = {}
    for item in items or []:
        if "=" not in item:
            raise UsageError(f"-D expects key=value, got {item!r}")
        k, v = item.split("=", 1)
        params[k] = v
    return params


def _positive(name):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer ≥ 1 (got {text!r})") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"{name} must be an integer ≥ 1 (got {value})")
        return value

    return parse


def cmd_render(args):
    params = _parse_defines(args.define)
    out = Path(args.output or Path(args.scene).with_suffix("").name + ".exr")
    img, _, wall = render_scene(args.scene, variant=args.variant, spp=args.spp, params=params,
                                workers=args.workers, seed=args.seed)
    write_image(out, img, args.variant)
    print(f"wrote {out.with_suffix('.exr')} and {out.with_suffix('.png')} ({wall:.1f} s)")


def cmd_compare(args):
    from . import compare

    compare.run(args)


def cmd_assets(args):
    from . import assets

    folder = assets.ensure(args.folder)
    print(f"assets in {folder}: {', '.join(assets.FILES)}")


def build_parser():
    workers = os.cpu_count() or 1
    common = argparse.ArgumentParser(add_help=False)
    # Subcommands accept -v too; SUPPRESS keeps a top-level `msx -v render …` from being reset.
    common.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    p = argparse.ArgumentParser(prog="msx", description="Multiple-scattering microfacet BSDFs for Mitsuba 3")
    p.add_argument("-v", "--verbose", action="store_true", help="show tracebacks on errors")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render one scene", parents=[common])
    r.add_argument("scene")
    r.add_argument("-o", "--output", help="output path (.exr; a .png is written beside it)")
    r.add_argument("--spp", type=_positive("--spp"), default=None, help="samples per pixel (default: the scene's)")
    r.add_argument("--variant", default=DEFAULT_VARIANT)
    r.add_argument("--workers", type=_positive("--workers"), default=workers, help="worker processes")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("-D", "--define", action="append", help="scene parameter key=value (XML <default>)")
    r.set_defaults(func=cmd_render)

    c = sub.add_parser("compare", help="render the paper comparisons side by side with Mitsuba's built-ins",
                       parents=[common])
    c.add_argument("--quick", action="store_true", help="small settings: a first look in a few minutes (CI)")
    c.add_argument("--scenes", default=None, help="folder with the scene XMLs (default: the installed scenes)")
    c.add_argument("--out", default="out", help="report folder (index.html, CSVs, PNGs)")
    c.add_argument("--variant", default=None,
                   help="Mitsuba variant (default: the fastest available, llvm_ad_rgb if it works here)")
    c.add_argument("--cache", default=None, help="folder of cached reference renders (default ~/.cache/msx)")
    c.set_defaults(func=cmd_compare)

    a = sub.add_parser("assets", help="write the generated scene assets (sky, sculpted mesh, normal map)",
                       parents=[common])
    a.add_argument("folder", nargs="?", default=str(Path(__file__).resolve().parent / "scenes" / "assets"))
    a.set_defaults(func=cmd_assets)

    from .microgeometry import add_simulate_parser

    add_simulate_parser(sub, parents=[common])
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    verbose = getattr(args, "verbose", False)
    try:
        args.func(args)
    except KeyboardInterrupt:
        print("\nmsx: interrupted", file=sys.stderr)
        return 130
    except (RenderError, UsageError) as e:
        if verbose:
            traceback.print_exc()
        print(f"msx: error: {e}", file=sys.stderr)
        return 1
    except Exception as e:  # unexpected: still one line unless --verbose
        if verbose:
            traceback.print_exc()
        print(f"msx: error: {one_line(e)} (run with --verbose for the traceback)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
