"""Where the SLAM front end's final refinement spends its time (docs/slam.md, "A store that lasts"): tracks SEQ with
the default ``SlamParams`` (or ``--params JSON``) from its first true pose, then runs ``Tracker.finish`` under
``cProfile`` and prints its CPU seconds, the keyframe structures it rebuilt, the keyframes and edges, and the
functions that took the most time; ``--save FILE.npy`` keeps the final poses of every frame ((n, 4, 4) float64, frame
order) to compare two versions' bit for bit (run each with its package on ``PYTHONPATH``).

    python scripts/slam_refine_profile.py SEQ [--params JSON] [--save POSES.npy] [--top 12]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import time

import numpy as np

from panovocc_cli.io.sequence import Sequence
from panovocc_cli.runtime import setup
from panovocc_cli.slam import SlamParams, Tracker


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON (default: the defaults)")
    ap.add_argument("--save", default=None, help="write the final poses here (.npy)")
    ap.add_argument("--top", type=int, default=12, help="functions listed (by their own time)")
    a = ap.parse_args()
    setup()
    seq = Sequence(a.seq)
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**json.loads(a.params)), T_world_first=seq.poses[0])
    for i in range(len(seq)):
        tr.track(i, seq.depth(i))
    rebuilds = tr.rebuilds
    prof = cProfile.Profile()
    t = time.process_time()
    prof.enable()
    tr.finish()
    prof.disable()
    print(f"finish CPU {time.process_time() - t:.2f} s, rebuilds {tr.rebuilds - rebuilds}, keyframes {len(tr.keyframes)}, "
          f"edges {len(tr._edges)}")
    pstats.Stats(prof).sort_stats("tottime").print_stats(a.top)
    if a.save:
        C = tr.committed()
        np.save(a.save, np.stack([C[i] for i in sorted(C)]))


if __name__ == "__main__":
    main()
