"""Every registration that verifies a loop candidate, over a stretch of a walk (docs/slam.md, "Loop candidates a
storey away"): the tracker over SEQ's frames 0 to B (started at the sequence's first pose, ``SlamParams`` defaults
or the ``--params`` JSON fields), and for the keyframes of frames A to B each of ``Tracker._close_loops``'
registrations as one JSON object: frame, new keyframe, candidate keyframe and their gap, the candidate's
horizontal and vertical offset from the new keyframe (metres, estimated poses), the correspondence distance, the
fitness and the wall ms. Then a summary line per correspondence distance: registrations, ms in all, and how many
stayed below ``min_fitness``.

    python scripts/slam_loop_candidates_log.py SEQ A B [--params JSON]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("first", type=int)
    ap.add_argument("last", type=int)
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON (default: the defaults)")
    args = ap.parse_args()
    seq, a, b = Sequence(args.seq), args.first, args.last
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**json.loads(args.params)), T_world_first=seq.poses[0])
    log, state = [], {"new": None, "frame": -1}
    close, align = tr._close_loops, tr.reg.align

    def close_logged(new):
        state["new"] = new
        try:
            return close(new)
        finally:
            state["new"] = None

    def align_logged(target, source, init, max_corr):
        t = time.perf_counter()
        r = align(target, source, init, max_corr)
        ms = 1e3 * (time.perf_counter() - t)
        new = state["new"]
        if new is not None and state["frame"] >= a:
            j = next(k for k, kf in enumerate(tr.keyframes) if kf.cloud is target)
            d = tr.keyframes[j].T_world[:3, 3] - tr.keyframes[new].T_world[:3, 3]
            log.append({"frame": state["frame"], "new": new, "candidate": j, "gap": new - j,
                        "dxy_m": round(float(np.hypot(d[0], d[1])), 3), "dz_m": round(float(d[2]), 3),
                        "max_corr_m": max_corr, "fitness": round(r.fitness, 3), "ms": round(ms, 1)})
            print(json.dumps(log[-1]), flush=True)
        return r

    tr._close_loops, tr.reg.align = close_logged, align_logged
    for fid in range(b):
        state["frame"] = fid
        tr.track(fid, seq.depth(fid))
    for mc in sorted({r["max_corr_m"] for r in log}):
        rows = [r for r in log if r["max_corr_m"] == mc]
        print(json.dumps({"max_corr_m": mc, "registrations": len(rows), "ms": round(sum(r["ms"] for r in rows)),
                          "below_min_fitness": sum(r["fitness"] < tr.params.min_fitness for r in rows)}))


if __name__ == "__main__":
    main()
