"""Where the SLAM front end's time goes over a long walk (docs/slam.md, "The building run"): runs the tracker
alone (no map) over the first N frames of SEQ, starting at the sequence's first pose, and prints one JSON line
every 100 frames: wall ms a frame, and for those 100 frames the seconds and calls of loop verification
(``_close_loops``, ``_loop_candidates``), registration (``align``, ``restore``, ``information``), the pose
graph's update a keyframe (``_sync``: iSAM2) and its optimisation (``_optimise``), loop candidates and loops found, and the map frames the tracker hands out to be
revised (``revised``: what ``map --poses slam`` then re-integrates; ``revise_events``: the frames that hand any).

    python scripts/slam_tracker_profile.py SEQ N [--params JSON]

``--params``: :class:`panovocc_cli.slam.SlamParams` fields other than the defaults (``'{"loop_linked": 3}'``), as
``scripts/slam_optimiser_ab.py`` and ``scripts/slam_front_end_run.py`` take them.
"""

from __future__ import annotations

import argparse
import collections
import json
import time

from panovocc_cli.runtime import setup


def main() -> None:
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("frames", type=int)
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON (default: the defaults)")
    a = ap.parse_args()
    seq = Sequence(a.seq)
    n = a.frames
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**json.loads(a.params)), T_world_first=seq.poses[0])
    stats = collections.defaultdict(float)

    def timed(obj, name, key, count=None):
        f = getattr(obj, name)

        def wrapper(*a, **k):
            t = time.perf_counter()
            r = f(*a, **k)
            stats[key] += time.perf_counter() - t
            stats[key + "_n"] += 1
            if count is not None:
                count(r)
            return r
        setattr(obj, name, wrapper)

    timed(tr.reg, "restore", "restore")
    timed(tr.reg, "align", "align")
    timed(tr.reg, "information", "info")
    timed(tr, "_sync", "isam_update")
    timed(tr, "_optimise", "optimise")
    timed(tr, "_loop_candidates", "candidates", lambda r: stats.__setitem__("candidate_total", stats["candidate_total"] + len(r)))
    timed(tr, "_close_loops", "close_loops", lambda r: stats.__setitem__("loops_found", stats["loops_found"] + len(r[0])))
    last, t_last = dict(stats), time.perf_counter()
    for i in range(n):
        step = tr.track(i, seq.depth(i))
        stats["revised"] += len(step.revisions)
        stats["revise_events"] += 1 if step.revisions else 0
        if (i + 1) % 100 == 0:
            now = time.perf_counter()
            d = {k: round(stats[k] - last.get(k, 0.0), 3) for k in sorted(stats)}
            print(json.dumps({"frames": i + 1, "ms_per_frame": round(10 * (now - t_last), 1),
                              "keyframes": len(tr.keyframes), **d}), flush=True)
            last, t_last = dict(stats), now


if __name__ == "__main__":
    main()
