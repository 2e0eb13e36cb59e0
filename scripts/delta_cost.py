"""What a revised frame's new delta costs (docs/mapping.md, "Incremental revise export"): the mean wall time
of ``Mapper._delta`` (geometry and semantics, from the kept observation) and of the geometry part alone over
the first ``--frames`` frames whose pose in POSES differs from MAP's, then a cProfile of the whole delta.

    python scripts/delta_cost.py MAP POSES [--frames 60]
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import pstats
import time
from pathlib import Path

import numpy as np

from panovocc_cli.io.poses import frame_poses
from panovocc_cli.io.sequence import read_meta
from panovocc_cli.mapping import Mapper
from panovocc_cli.mapping import mapper as mapper_module
from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("poses", type=Path)
    ap.add_argument("--frames", type=int, default=60)
    a = ap.parse_args()
    cfg = load_config(a.map)
    poses = frame_poses(a.poses, read_meta(cfg.seq).frames)
    m = Mapper.load(a.map)
    try:
        reader = SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=str(a.poses)), poses)).read
        ids = [i for i in m.frame_ids if not np.array_equal(poses[i], m.pose(i))][:a.frames]
        work = [(dataclasses.replace(reader(i), T_world_cam=poses[i]), m._rpu.store.get(i).observation) for i in ids]
        for frame, obs in work[:5]:  # compiled kernels loaded
            m._delta(frame, obs)
        geo = whole = 0.0
        for frame, obs in work:
            t = time.perf_counter()
            list(mapper_module.geometry_parts(frame.depth, frame.T_world_cam, m.config.geometry))
            geo += time.perf_counter() - t
            t = time.perf_counter()
            m._delta(frame, obs)
            whole += time.perf_counter() - t
        print(f"{len(work)} frames: delta {1e3 * whole / len(work):.1f} ms, geometry {1e3 * geo / len(work):.1f} ms")
        prof = cProfile.Profile()
        prof.enable()
        for frame, obs in work:
            m._delta(frame, obs)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)
    finally:
        m.close()


if __name__ == "__main__":
    main()
