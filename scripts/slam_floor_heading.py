"""Where a long walk's SLAM error sits, floor by floor (docs/slam.md, "The building's heading"): for the
estimated poses EST (NICE-SLAM form, in the reference's world: ``--first-pose reference``) against SEQ/poses.txt,
per floor (the reference camera height, rounded to ``--floor-height``): the median world rotation error about
+z (yaw), +x and +y (tilt; degrees), and the position error fitted as a + b x + c y per axis (its slopes in mm a
metre and what is left, RMS mm): a floor turned as a whole about the stairs reads as a yaw error equal to the
slopes of x and y, a floor tilted as a rotation about x or y equal to the slopes of z; and the median z error of
each tenth of the floor's frames, in walking order. With ``--scatter STEP``:
also the wall heading (:func:`panovocc_cli.slam.heading.wall_heading`) and the vertical
(:func:`~panovocc_cli.slam.heading.floor_vertical`) of every STEP-th frame of SEQ under its true pose, their
spread (degrees) -- what the heading and level priors can read.

    python scripts/slam_floor_heading.py SEQ EST [--floor-height 3.2] [--scatter 40]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("est")
    ap.add_argument("--floor-height", type=float, default=3.2)
    ap.add_argument("--scatter", type=int, default=0, help="every this many frames: the wall heading's spread")
    a = ap.parse_args()
    setup()
    from panovocc_cli.io.poses import read_poses
    from panovocc_cli.io.sequence import Sequence

    seq = Sequence(a.seq)
    ref, est = seq.poses, read_poses(a.est)
    floor = np.round((ref[:, 2, 3] - ref[0, 2, 3]) / a.floor_height).astype(int)
    Rw = np.einsum("nij,nkj->nik", est[:, :3, :3], ref[:, :3, :3])  # est R ref R^T: the world-frame error
    yaw = np.degrees(np.arctan2(Rw[:, 1, 0], Rw[:, 0, 0]))
    tilt = np.degrees(np.stack([Rw[:, 2, 1] - Rw[:, 1, 2], Rw[:, 0, 2] - Rw[:, 2, 0]], 1) / 2)  # small angles
    e = est[:, :3, 3] - ref[:, :3, 3]
    x, y = ref[:, 0, 3], ref[:, 1, 3]
    out = {"floors": []}
    for f in sorted(set(floor.tolist())):
        m = floor == f
        A = np.column_stack([np.ones(m.sum()), x[m], y[m]])
        row = {"floor": f, "frames": int(m.sum()), "yaw_deg_median": round(float(np.median(yaw[m])), 4),
               "tilt_deg_median_x_y": [round(float(np.median(tilt[m, k])), 4) for k in (0, 1)],
               "ez_mm_median_by_tenth": [round(1e3 * float(np.median(t)), 1)
                                         for t in np.array_split(e[m, 2], 10) if len(t)]}
        for k, name in ((0, "x"), (1, "y"), (2, "z")):
            c = np.linalg.lstsq(A, e[m, k], rcond=None)[0]
            r = e[m, k] - A @ c
            row[f"e{name}_mm_per_m_x_y"] = [round(1e3 * c[1], 2), round(1e3 * c[2], 2)]
            row[f"e{name}_rms_mm_raw_left"] = [round(1e3 * float(np.sqrt((e[m, k] ** 2).mean())), 1),
                                               round(1e3 * float(np.sqrt((r ** 2).mean())), 1)]
        out["floors"].append(row)
    if a.scatter:
        from panovocc_cli.slam import SlamParams, Tracker
        from panovocc_cli.slam.heading import cloud_normals, floor_vertical, wall_heading
        from panovocc_cli.slam.tracker import erp_points

        tr = Tracker(seq.meta.width, seq.meta.height, SlamParams())
        p = tr.params
        phi, vert = [], []
        for i in range(0, len(seq), a.scatter):
            c = tr.reg.prepare(erp_points(seq.depth(i), tr._rays, tr.stride, p.min_range_m, p.max_range_m))
            n = cloud_normals(c.points, 2.5 * tr.reg.voxel_m)
            phi.append(wall_heading(n @ ref[i][:3, :3].T, np.array([0.0, 0.0, 1.0]))[0])
            v = floor_vertical(n @ ref[i][:3, :3].T, np.array([0.0, 0.0, 1.0]))[0]
            vert.append(np.full(3, np.nan) if v is None else v)
        phi = np.degrees(np.array(phi))
        ok = np.isfinite(phi)
        out["heading_true_poses"] = {"frames": int(ok.sum()), "std_deg": round(float(phi[ok].std()), 4),
                                     "median_deg": round(float(np.median(phi[ok])), 4)}
        v = np.degrees(np.array(vert)[:, :2])  # the vertical's x and y components: its tilt, small angles
        ok = np.all(np.isfinite(v), axis=1)
        out["vertical_true_poses"] = {"frames": int(ok.sum()),
                                      "std_deg_x_y": [round(float(x), 4) for x in v[ok].std(0)],
                                      "mean_deg_x_y": [round(float(x), 4) for x in v[ok].mean(0)]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
