"""Is the front end's registration biased? (docs/slam.md, "A walk back down, and the building's heading", "The
corridors' stretch"): frames I and I + GAP of SEQ (true depth) registered by the tracker's ``Registration.align``
from their true relative pose, within ``--corr`` metres (``loop_max_corr_m`` by default); per pair the error of
the estimated step in the world, along and across the true horizontal step (mm) and in yaw (degrees); then the
means (along / across as mrad of the step). ``--params``: :class:`panovocc_cli.slam.SlamParams` fields other than
the defaults (``'{"max_range_m": 30}'``); GAP may be a comma-separated list (one mean line each).

    python scripts/slam_pair_bias.py SEQ 100,300,500 5 [--corr 0.5] [--params JSON]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("ids", help="first frames of the pairs, comma-separated")
    ap.add_argument("gap", help="frames between a pair's two frames (a comma-separated list: one run each)")
    ap.add_argument("--corr", type=float, default=None, help="correspondence distance, metres (loop_max_corr_m)")
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON")
    ap.add_argument("--quiet", action="store_true", help="the mean lines only")
    a = ap.parse_args()
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker
    from panovocc_cli.slam.tracker import erp_points

    seq = Sequence(a.seq)
    ids = [int(s) for s in a.ids.split(",")]
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**json.loads(a.params)))
    p, P = tr.params, seq.poses
    corr = p.loop_max_corr_m if a.corr is None else a.corr
    clouds: dict = {}

    def cloud(j):
        if j not in clouds:
            clouds[j] = tr.reg.prepare(erp_points(seq.depth(j), tr._rays, tr.stride, p.min_range_m, p.max_range_m))
        return clouds[j]

    for gap in (int(g) for g in a.gap.split(",")):
        out = []
        for i in ids:
            T = np.linalg.inv(P[i]) @ P[i + gap]
            Te = tr.reg.align(cloud(i), cloud(i + gap), T, corr).T_target_source
            t, d = P[i][:3, :3] @ T[:3, 3], P[i][:3, :3] @ (Te[:3, 3] - T[:3, 3])
            L = float(np.linalg.norm(t[:2]))
            across, along = (t[0] * d[1] - t[1] * d[0]) / L, (t[0] * d[0] + t[1] * d[1]) / L
            Rd = P[i][:3, :3] @ T[:3, :3].T @ Te[:3, :3] @ P[i][:3, :3].T  # the yaw error in the world
            yaw = float(np.degrees(np.arctan2(Rd[1, 0], Rd[0, 0])))
            out.append((L, along, across, yaw))
            if not a.quiet:
                print(f"{i}: step {L:.3f} m, along {1e3 * along:+.2f} mm, across {1e3 * across:+.2f} mm, "
                      f"yaw {yaw:+.4f} deg")
        o = np.array(out)
        print(f"gap {gap}: mean along {1e3 * np.mean(o[:, 1] / o[:, 0]):+.3f} mrad, across "
              f"{1e3 * np.mean(o[:, 2] / o[:, 0]):+.3f} mrad of the step, yaw {o[:, 3].mean():+.4f} deg "
              f"({len(o)} pairs, mean step {o[:, 0].mean():.2f} m)")


if __name__ == "__main__":
    main()
