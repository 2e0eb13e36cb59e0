"""Is the front end's registration biased? (docs/slam.md, "A walk back down, and the building's heading"): frames
I and I + GAP of SEQ (true depth) registered by the tracker's ``Registration.align`` from their true relative pose,
within ``loop_max_corr_m``; per pair the error of the estimated step in the world, along and across the true
horizontal step (mm) and in yaw (degrees); then the means (along / across as mrad of the step).

    python scripts/slam_pair_bias.py SEQ 100,300,500 5
"""

from __future__ import annotations

import sys

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker
    from panovocc_cli.slam.tracker import erp_points

    seq = Sequence(sys.argv[1])
    ids, gap = [int(a) for a in sys.argv[2].split(",")], int(sys.argv[3])
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams())
    p, P = tr.params, seq.poses
    out = []
    for i in ids:
        c = [tr.reg.prepare(erp_points(seq.depth(j), tr._rays, tr.stride, p.min_range_m, p.max_range_m))
             for j in (i, i + gap)]
        T = np.linalg.inv(P[i]) @ P[i + gap]
        Te = tr.reg.align(c[0], c[1], T, p.loop_max_corr_m).T_target_source
        t, d = P[i][:3, :3] @ T[:3, 3], P[i][:3, :3] @ (Te[:3, 3] - T[:3, 3])
        L = float(np.linalg.norm(t[:2]))
        across, along = (t[0] * d[1] - t[1] * d[0]) / L, (t[0] * d[0] + t[1] * d[1]) / L
        Rd = P[i][:3, :3] @ T[:3, :3].T @ Te[:3, :3] @ P[i][:3, :3].T  # the yaw error in the world
        yaw = float(np.degrees(np.arctan2(Rd[1, 0], Rd[0, 0])))
        out.append((L, along, across, yaw))
        print(f"{i}: step {L:.3f} m, along {1e3 * along:+.2f} mm, across {1e3 * across:+.2f} mm, yaw {yaw:+.4f} deg")
    o = np.array(out)
    print(f"mean: along {1e3 * np.mean(o[:, 1] / o[:, 0]):+.3f} mrad, across {1e3 * np.mean(o[:, 2] / o[:, 0]):+.3f} "
          f"mrad of the step, yaw {o[:, 3].mean():+.4f} deg ({len(o)} pairs)")


if __name__ == "__main__":
    main()
