"""The SLAM front end's revision budget (docs/slam.md, "The building run"): ``map --poses slam --first-pose
reference`` of SEQ once per budget k (``SlamParams(revise_per_frame=k)``, 0 = every revision at once), one run
after another in this process, each into WORK/kK with its ``--frame-times``. Prints one JSON line per run: wall
s; ms a frame (tracking, mapping and the revisions it handed out, from the frame times) as the median over
frames 10-20 % and over the last 10 % and their ratio, the mean and the largest; frames revised; loop closures;
and, with ``--gt``, the map's IoU / mIoU against it (``panovocc eval --classes eval12``, as ``make bench-scale``).

    python scripts/slam_budget_ab.py SEQ WORK [--budgets 0,4] [--frames A:B] [--gt GT.npz]
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from panovocc_cli.benchmark.scale import early_late
from panovocc_cli.mapping.config import MapConfig, parse_frames
from panovocc_cli.slam import SlamParams
from panovocc_cli.slam.run import run_map_slam


def frame_ms(path: Path) -> np.ndarray:
    t = np.array([float(r["t_s"]) for r in csv.DictReader(open(path))])
    return 1e3 * np.diff(np.concatenate([[0.0], t]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq", type=Path)
    ap.add_argument("work", type=Path)
    ap.add_argument("--budgets", default="0,4")
    ap.add_argument("--frames", default=None)
    ap.add_argument("--gt", type=Path, default=None)
    a = ap.parse_args()
    a.work.mkdir(parents=True, exist_ok=True)
    for k in (int(x) for x in a.budgets.split(",")):
        out, times = a.work / f"k{k}", a.work / f"k{k}-frames.csv"
        cfg = MapConfig(seq=str(a.seq), out=str(out), poses="slam", first_pose="reference", frame_times=str(times),
                        frames=None if a.frames is None else parse_frames(a.frames))
        t0 = time.perf_counter()
        s = run_map_slam(cfg, overwrite=True, progress=False, params=SlamParams(revise_per_frame=k))
        wall = time.perf_counter() - t0
        ms = frame_ms(times)
        n = len(ms)
        early, late = (float(np.median(ms[w])) for w in early_late(n))
        row = {"budget": k, "wall_s": round(wall, 1), "frames": n, "ms_early": round(early, 1),
               "ms_late": round(late, 1), "late_over_early": round(late / early, 3), "ms_mean": round(float(ms.mean()), 1),
               "ms_max": round(float(ms.max()), 1), "revisions": s["slam"]["revisions"],
               "loops": len(s["slam"]["loop_closures"])}
        if a.gt is not None:
            r = subprocess.run([sys.executable, "-m", "panovocc_cli", "eval", str(out / "prediction.npz"), str(a.gt),
                                "--classes", "eval12", "--json"], capture_output=True, text=True, check=True)
            e = json.loads(r.stdout)
            row["iou"], row["miou"] = round(e["iou"], 2), round(e["miou"], 2)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
