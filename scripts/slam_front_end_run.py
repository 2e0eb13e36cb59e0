"""The SLAM front end alone over a long walk (docs/slam.md, "The building run"): ``slam.run.run_slam_poses`` of
SEQ in the reference trajectory's world (``--first-pose reference``) into WORK/slam, with its frame times in
WORK/track.csv (skipped when both exist), then one JSON object of the front end's figures:

* wall ms a frame of the tracker (the last frame's final refinement apart): medians by tenth of the walk, the
  median over frames 10-20 % and over the last 10 % and their ratio (issue 22's goal: at most 1.2);
* the final refinement's wall time (the last frame's time);
* the keyframe store (``Tracker.memory``: downsampled points, and the registration structures of the held
  keyframes) at each tenth and at the end, bytes; the process's resident memory at the end and its largest;
* loop closures, those joining frames on different floors (``--floor-height``: floors by the reference
  camera height, rounded from the first frame's), and those joining two frames of one floor between which the
  walk went to another floor and came back (``loops_around_other_floors``: ``synth --building --descend``);
* ATE RMSE / max of the poses handed out (every frame's, WORK/slam/poses.txt) against SEQ/poses.txt,
  without alignment (the SLAM world is the reference's) and SE(3)-aligned (evo's protocol).

    python scripts/slam_front_end_run.py SEQ WORK [--floor-height 3.2] [--params JSON]

``--params``: :class:`panovocc_cli.slam.SlamParams` fields other than the defaults (``'{"loop_linked": 3}'``).

Then the map from those poses, scored against the true-pose map (the commands docs/slam.md lists).
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--floor-height", type=float, default=3.2, help="metres between floors (the building's)")
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON (default: the defaults)")
    a = ap.parse_args()
    setup()
    from panovocc_cli.benchmark.scale import early_late
    from panovocc_cli.evaluation.trajectory import evaluate_trajectory
    from panovocc_cli.io.poses import read_poses
    from panovocc_cli.slam import SlamParams
    from panovocc_cli.slam.run import run_slam_poses

    out, times = a.work / "slam", a.work / "track.csv"
    wall = None
    if not ((out / "slam.json").is_file() and times.is_file()):
        t0 = time.perf_counter()
        run_slam_poses(a.seq, out, SlamParams(**json.loads(a.params)), first_pose="reference", frame_times=times)
        wall = time.perf_counter() - t0
    info = json.loads((out / "slam.json").read_text())
    rows = list(csv.DictReader(open(times)))
    ms = np.array([float(r["track_ms"]) for r in rows])
    n = len(ms)
    online = ms[:-1]  # the last frame holds the final refinement
    tenth = [float(np.median(online[k * n // 10:(k + 1) * n // 10])) for k in range(10)]
    early, late = (float(np.median(online[w])) for w in early_late(n))  # the map's windows, over the n frames
    at = [rows[min((k + 1) * n // 10, n) - 1] for k in range(10)]
    ref = read_poses(a.seq / "poses.txt")
    est = read_poses(out / "poses.txt")
    floor = np.round((ref[:, 2, 3] - ref[0, 2, 3]) / a.floor_height).astype(int)
    loops = info["loop_closures"]
    across = sum(1 for i, j in loops if floor[i] != floor[j])
    # loops whose two frames are on one floor but whose walk between them went to another floor and came back
    # (synth --building --descend): the loop closes around the floors above
    lo_hi = [(min(i, j), max(i, j)) for i, j in loops]
    around = [(a_, b_) for a_, b_ in lo_hi if floor[a_] == floor[b_] and np.any(floor[a_:b_ + 1] != floor[a_])]
    res = {"frames": n, "wall_s": wall, "ms_by_tenth": [round(x, 1) for x in tenth],
           "ms_early": round(early, 1), "ms_late": round(late, 1), "late_over_early": round(late / early, 3),
           "mean_ms": round(float(online.mean()), 1), "refinement_s": round(float(ms[-1]) / 1e3, 1),
           "points_bytes_by_tenth": [int(r["points_bytes"]) for r in at],
           "held_bytes_by_tenth": [int(r["held_bytes"]) for r in at],
           "rss_mb_end": float(rows[-1]["rss_mb"]), "rss_mb_max": max(float(r["rss_mb"]) for r in rows),
           "keyframes": info["keyframes"], "store": info["keyframe_store"], "loops": len(loops),
           "loops_across_floors": across, "floors": sorted(set(floor.tolist())),
           "loops_around_other_floors": len(around),
           "around_frames_apart_max": max((b_ - a_ for a_, b_ in around), default=0),
           "unplaced": len(info["unplaced_frames"]), "optimisations": info["optimisations"]}
    for align in ("none", "se3"):
        e = evaluate_trajectory(est, ref, align).ate
        res[f"ate_{align}_mm"] = [round(1e3 * e["rmse"], 2), round(1e3 * e["max"], 2)]
    print(json.dumps(res))


if __name__ == "__main__":
    main()
