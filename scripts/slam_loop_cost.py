"""What one loop verification of the SLAM front end costs (docs/slam.md, "The building run"): prepares the
clouds of frame REF and of the frames OTHER... of MAP's sequence as ``Tracker.track`` does, then times, per
pair, the rebuild of a compacted keyframe's registration structures (``Registration.restore``), the two
alignments of ``Tracker._close_loops`` (at ``max_corr_m``, then ``loop_max_corr_m``) and the edge's
information matrix; prints one line a pair with the final fitness (means of ``--repeat`` runs, one thread).

    python scripts/slam_loop_cost.py MAP REF OTHER... [--repeat 5]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config
from panovocc_cli.slam.registration import erp_points
from panovocc_cli.slam.tracker import Tracker


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("ref", type=int)
    ap.add_argument("other", type=int, nargs="+")
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    read = SequenceFrames(_open_sequence(load_config(a.map))).read
    first = read(a.ref)
    tr = Tracker(first.depth.shape[1], first.depth.shape[0])
    p = tr.params

    def cloud(frame):
        return tr.reg.prepare(erp_points(frame.depth, tr._rays, tr.stride, p.min_range_m, p.max_range_m))

    target = cloud(first)
    tr.reg.information(target, target, np.eye(4), p.loop_max_corr_m)  # Open3D loaded before timing
    for j in a.other:
        fr = read(j)
        source = cloud(fr)
        init = np.linalg.inv(first.T_world_cam) @ fr.T_world_cam
        t = time.perf_counter()
        for _ in range(a.repeat):
            target.compact()
            tr.reg.restore(target)
        t_restore = (time.perf_counter() - t) / a.repeat
        t = time.perf_counter()
        for _ in range(a.repeat):
            r = tr.reg.align(target, source, init, p.max_corr_m)
            r = tr.reg.align(target, source, r.T_target_source, p.loop_max_corr_m)
        t_align = (time.perf_counter() - t) / a.repeat
        t = time.perf_counter()
        for _ in range(a.repeat):
            tr.reg.information(target, source, r.T_target_source, p.loop_max_corr_m)
        t_info = (time.perf_counter() - t) / a.repeat
        print(f"{a.ref} <- {j}: {len(target)} / {len(source)} points, restore {1e3 * t_restore:.1f} ms, two alignments "
              f"{1e3 * t_align:.1f} ms, information {1e3 * t_info:.1f} ms, fitness {r.fitness:.2f}")


if __name__ == "__main__":
    main()
