"""CPU of the per-frame geometric update, an older ``psvf/update.py`` against this one, in one process (issue 21,
docs/mapping.md "Memory layout": the frame box a slab at a time). Both compute ``geometry_parts`` of the same
frames (every ``--every``-th of MAP's sequence, in the map's local frame) in interleaved rounds; the deltas
are checked equal first. Prints the process CPU ms per frame of each and their ratio after every round.

    git show 2bba930:panovocc_cli/mapping/psvf/update.py > W/old_update.py
    python scripts/slab_ab.py MAP W/old_update.py [--rounds 4] [--every 20]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map")
    ap.add_argument("old_update")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--every", type=int, default=20)
    args = ap.parse_args()

    from panovocc_cli.runtime import setup

    setup()
    # the older module as a sibling of psvf.update: its relative imports resolve to this package's modules
    spec = importlib.util.spec_from_file_location("panovocc_cli.mapping.psvf._ab_old_update", args.old_update)
    old = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = old
    spec.loader.exec_module(old)
    from panovocc_cli.mapping.mapper import Mapper
    from panovocc_cli.mapping.pipeline import _open_sequence, load_config
    from panovocc_cli.mapping.psvf import update as new

    cfg = load_config(args.map)
    seq = _open_sequence(cfg)
    g = cfg.mapper_config().geometry
    m = Mapper(cfg.mapper_config())
    frames = [m._local(seq.frame(i)) for i in range(0, len(seq), args.every)]
    for f in frames:
        for a, b in zip(old.geometry_parts(f.depth, f.T_world_cam, g), new.geometry_parts(f.depth, f.T_world_cam, g)):
            if not (np.array_equal(a.keys, b.keys) and all(np.array_equal(a.channels[k], b.channels[k])
                                                           for k in a.channels)):
                raise SystemExit(f"frame {f.index}: the two give different deltas")
    total = {"old": 0.0, "new": 0.0}
    arms = [("old", old), ("new", new)]
    for r in range(args.rounds):
        for name, mod in (arms if r % 2 == 0 else arms[::-1]):
            c0 = time.process_time()
            for f in frames:
                mod.geometry_parts(f.depth, f.T_world_cam, g)
            total[name] += time.process_time() - c0
        ms = {k: round(1e3 * t / ((r + 1) * len(frames)), 2) for k, t in total.items()}
        print(f"round {r + 1}: CPU ms per frame {ms}, new / old {total['new'] / total['old']:.3f}", flush=True)


if __name__ == "__main__":
    main()
