"""The SLAM front end's pose-graph optimisers side by side (docs/slam.md, "Optimiser"): each sequence's
preloaded depth frames tracked once per arm, in one process, arm after arm (the same load for both), with
``SlamParams(optimiser=ARM, **JSON)``. Prints one JSON line per sequence and arm.

    python scripts/slam_optimiser_ab.py SEQ [SEQ ...] [--arms isam2,open3d] [--params JSON] [--no-refine] [--solves]

Per line: ATE RMSE and max (SE(3)-aligned, ``evaluation/trajectory.py``) of the poses handed out after the
last frame (``before``) and after the final refinement (``after``), keyframes, loop closures, optimisations,
lost frames; CPU (``time.process_time``): tracking per frame and the final refinement (and the keyframe structures
it rebuilt, ``refine_rebuilds``); and early vs late,
over frames 10-20 % and the last 10 %: tracking CPU per frame (``track_ms``) and the optimiser's CPU per
keyframe created there (``opt_ms_per_kf``: iSAM2's update per keyframe and its read-backs, or Open3D's whole
solves) and per online solve ending there (``opt_ms_per_solve``: a read-back after a disagreeing loop edge, or
one of Open3D's solves), with the ratios late / early; ``last_solves``: the last three online solves (frame,
keyframes, CPU ms). ``--solves`` prints each online solve on stderr as it ends.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from panovocc_cli.evaluation.trajectory import evaluate_trajectory
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.slam import SlamParams, Tracker


class TimedTracker(Tracker):
    """The tracker with the CPU of its optimiser calls (``_sync``: iSAM2's update; ``_optimise``) summed."""

    opt_s = 0.0
    solves: list = []  # (frame index, keyframes, CPU s) of each read-back or whole solve
    frame = -1
    log = None

    def _sync(self):
        t = time.process_time()
        super()._sync()
        self.opt_s += time.process_time() - t

    def _optimise(self, batch=False):
        if batch:
            return super()._optimise(batch)
        t, o = time.process_time(), self.opt_s
        super()._optimise(batch)
        dt = time.process_time() - t
        self.opt_s = o + dt  # its _sync counted once
        self.solves.append((self.frame, len(self.keyframes), dt))
        if self.log:
            print(json.dumps({"solve": self.solves[-1], "optimiser": self.params.optimiser}), file=self.log, flush=True)


def _ate(tr, seq):
    C = tr.committed()
    ids = sorted(C)
    return evaluate_trajectory(np.stack([C[i] for i in ids]), seq.poses[ids], "se3").ate


def run(path: str, arm: str, kw: dict, refine: bool, log=None) -> dict:
    seq = Sequence(path)
    depths = [seq.depth(i) for i in range(len(seq))]
    tr = TimedTracker(seq.meta.width, seq.meta.height, SlamParams(optimiser=arm, refine=refine, **kw))
    tr.solves, tr.log = [], log
    n = len(depths)
    track, opt, kfs = np.zeros(n), np.zeros(n), np.zeros(n)
    for i, d in enumerate(depths):
        o, k, tr.frame = tr.opt_s, len(tr.keyframes), i
        t = time.process_time()
        tr.track(i, d)
        track[i] = time.process_time() - t
        opt[i], kfs[i] = tr.opt_s - o, len(tr.keyframes) - k
    before = _ate(tr, seq)
    rebuilds = tr.rebuilds
    t = time.process_time()
    tr.finish()
    fin = time.process_time() - t
    after = _ate(tr, seq)

    def window(a, b):
        s = slice(int(a * n), int(b * n))
        sol = [c for f, _, c in tr.solves if s.start <= f < s.stop]
        return {"opt_ms_per_solve": 1e3 * float(np.mean(sol)) if sol else None, "solves": len(sol),
                "track_ms": 1e3 * float(track[s].mean()), "opt_ms_per_kf": 1e3 * float(opt[s].sum() / max(kfs[s].sum(), 1)),
                "keyframes": int(kfs[s].sum())}

    early, late = window(0.1, 0.2), window(0.9, 1.0)
    return {"seq": path, "optimiser": arm, "frames": n, "ate_before_mm": 1e3 * before["rmse"], "ate_after_mm": 1e3 * after["rmse"],
            "max_before_mm": 1e3 * before["max"], "max_after_mm": 1e3 * after["max"], "keyframes": len(tr.keyframes),
            "loops": len(tr.loops), "optimisations": tr.optimisations, "lost": len(tr.lost),
            "track_ms_per_frame": 1e3 * float(track.mean()), "opt_s": float(opt.sum()), "refine_s": fin,
            "refine_rebuilds": tr.rebuilds - rebuilds,
            "last_solves": [[f, k, round(1e3 * c, 2)] for f, k, c in tr.solves if f >= 0][-3:],
            "early": early, "late": late, "late_over_early_track": late["track_ms"] / early["track_ms"],
            "late_over_early_opt": late["opt_ms_per_kf"] / max(early["opt_ms_per_kf"], 1e-9)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seqs", nargs="+")
    ap.add_argument("--arms", default="isam2,open3d")
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON")
    ap.add_argument("--no-refine", action="store_true", help="skip the final refinement")
    ap.add_argument("--solves", action="store_true", help="each online solve on stderr as it ends (frame, keyframes, CPU s)")
    a = ap.parse_args()
    for path in a.seqs:
        for arm in a.arms.split(","):
            print(json.dumps(run(path, arm, json.loads(a.params), not a.no_refine, sys.stderr if a.solves else None)), flush=True)


if __name__ == "__main__":
    main()
