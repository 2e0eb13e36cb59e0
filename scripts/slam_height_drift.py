"""How far the SLAM front end drifts along the vertical against the horizontal (docs/slam.md, "Loop candidates a
storey away"): for each sequence, the tracker over every frame with the final refinement off (the online
estimate, which the loop candidates see), started at the sequence's first pose; then for frame pairs more than 5 m
of path apart (about 600 frames sampled), the error of their relative position split into vertical (z) and
horizontal, and the largest of each over the path length between them. One line a sequence.

    python scripts/slam_height_drift.py SEQ [SEQ ...]
"""

from __future__ import annotations

import sys

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker

    for path in sys.argv[1:]:
        seq = Sequence(path)
        tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(refine=False), T_world_first=seq.poses[0])
        for i in range(len(seq.poses)):
            tr.track(i, seq.depth(i))
        placed = tr.committed()
        ids = np.array(sorted(placed))
        est, ref = np.stack([placed[i] for i in ids])[:, :3, 3], seq.poses[ids][:, :3, 3]
        odo = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(ref, axis=0), axis=1))]
        idx = np.arange(0, len(ids), max(1, len(ids) // 600))
        e = (est - ref)[idx]
        d = e[:, None, :] - e[None, :, :]
        dz, dh = np.abs(d[..., 2]), np.hypot(d[..., 0], d[..., 1])
        L = np.abs(odo[idx][:, None] - odo[idx][None, :])
        far = L > 5.0
        print(f"{path}: {len(ids)} frames, path {odo[-1]:.0f} m; largest vertical error {1e3 * dz.max():.1f} mm, "
              f"horizontal {1e3 * dh.max():.1f} mm; largest per metre of path (pairs > 5 m apart): vertical "
              f"{(dz[far] / L[far]).max():.2e}, horizontal {(dh[far] / L[far]).max():.2e}", flush=True)


if __name__ == "__main__":
    main()
