"""How ``auto``'s walking lanes fall into SIMD packets in a scene (deterministic; benches/README.md, "``auto`` at
single's price per frame").

    python3 benches/auto_packets.py [SCENE.xml] [--spp 32] [--res 320] [--width 16] [--set alpha=…]

(SCENE.xml by default the shipped ``matpreview_metal.xml``.)

Renders the scene once with ``model="auto"`` in ``llvm_ad_rgb`` on one drjit thread while jit/auto.py
``record_calls`` records every lane of every ``auto`` call in execution order (lane index, call site, whether
it walks). On one thread the kernel runs its packets (``--width`` consecutive lanes: drjit's LLVM vector
width, 16 with AVX-512, 8 with AVX2) one after the other, each through all its path vertices, and a packet's
call is one run of records of that packet's lanes (a new run starts where the site or the packet changes or a
lane repeats). Prints, per call site, the fraction of calls (lanes) that walk and the fraction of packet
calls with at least one walking lane — the packets that pay for a walk (``dr.if_stmt`` skips the walk only in
packets none of whose lanes walk) — and how many of their lanes walk.
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from scene_bench import _drop_duplicates, resize, resolve, start_engine, swap  # noqa: E402

SITES = ("eval_pdf", "sample", "eval_pdf's branch (ω_o below: closed form)")


def packet_runs(records, width):
    """(lanes, walking lanes) per packet call, from one traced call's records in execution order: a run ends
    where the packet changes or a lane repeats (two calls of one packet whose lanes do not overlap and
    come in increasing order would be merged; rare, and it undercounts the packet calls)."""
    import numpy as np

    lane, walks = records >> 1, records & 1
    packet = lane // width
    start = np.ones(len(records), dtype=bool)
    start[1:] = (packet[1:] != packet[:-1]) | (lane[1:] <= lane[:-1])
    run = np.cumsum(start) - 1
    return np.bincount(run), np.bincount(run, weights=walks).astype(np.int64)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", nargs="?", default="matpreview_metal.xml")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--res", type=int, default=320)
    ap.add_argument("--width", type=int, default=16, help="drjit's LLVM vector width (16: AVX-512)")
    ap.add_argument("--records", type=int, default=1 << 23)
    ap.add_argument("--set", action="append", default=[], help="name=value set on every swapped BSDF")
    args = ap.parse_args(argv)
    dr, mi = start_engine()
    import numpy as np
    from msx.jit import auto as jit_auto

    overrides = dict(kv.split("=", 1) for kv in args.set)
    path = resolve(args.scene)
    mi.file_resolver().prepend(str(path.parent))
    scene = mi.load_string(_drop_duplicates(swap(path.read_text(), "auto", overrides), overrides))
    film = scene.sensors()[0].film().size()
    resize(mi, scene, args.res, max(1, round(film[1] * args.res / film[0])))
    dr.set_thread_count(1)
    calls = jit_auto.record_calls(args.records)
    dr.eval(mi.render(scene, spp=args.spp, seed=0))
    dr.sync_thread()
    jit_auto.record_calls(0)
    print("%s, %d spp, width %d px, vector width %d"
          % (path.name, args.spp, args.res, args.width))
    print("| traced call | lane calls | that walk | packet calls | lanes per packet call | with ≥ 1 walking lane "
          "| walking lanes in those |")
    print("|---|---|---|---|---|---|---|")
    for site, records, counter in calls:
        n = int(counter.numpy()[0])
        if n == 0:  # a trace the render did not run
            continue
        if n > args.records:
            sys.exit("%d records, more than --records %d" % (n, args.records))
        lanes, walking = packet_runs(records.numpy()[:n].astype(np.int64), args.width)
        paying = walking > 0
        print("| %s | %d | %.1f %% | %d | %.2f | %.1f %% | %.2f of %.2f |"
              % (SITES[site], n, 100 * walking.sum() / max(n, 1), len(lanes), n / max(len(lanes), 1),
                 100 * paying.mean(), walking[paying].mean() if paying.any() else 0.0,
                 lanes[paying].mean() if paying.any() else 0.0))


if __name__ == "__main__":
    main()
