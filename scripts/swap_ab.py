"""The swap of ``panovocc revise`` (``VoxelMemory.replace`` of a frame's kept delta by its delta under another
pose) on a saved map, in one process, arm after arm: CPU of the swapping thread per frame, so that two
variants are compared under the same load (docs/mapping.md, "Building revise, third pass").

    python scripts/swap_ab.py MAP POSES [--frames A:B] [--arms skip,all,skip,all]

For each frame of ``A:B`` (default: the last 40 whose pose differs in POSES), its kept delta and its delta
under POSES are read and computed once; each arm then swaps every frame in (kept -> new) and back (new ->
kept), so the memory ends as it began. An arm is ``skip`` (the difference leaves out the kept voxels it
does not change, ``memory.SKIP_UNCHANGED``, the default) or ``all`` (every voxel of the union added, as
before). Both give the same memory (tests/mapping/test_mapping_memory.py); MAP is only read. Prints one JSON
line an arm.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("poses", type=Path)
    ap.add_argument("--frames", default=None, help="A:B, frame ids (default: the last 40 moved frames)")
    ap.add_argument("--arms", default="skip,all,skip,all")
    args = ap.parse_args()

    from panovocc_cli.runtime import setup

    setup()
    import numpy as np

    from panovocc_cli.io.poses import frame_poses
    from panovocc_cli.io.sequence import read_meta
    from panovocc_cli.mapping import Mapper, memory
    from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config

    cfg = load_config(args.map)
    poses = frame_poses(args.poses, read_meta(cfg.seq).frames)
    mapper = Mapper.load(args.map)
    try:
        if args.frames:
            a, b = (int(x) for x in args.frames.split(":"))
            ids = list(range(a, b))
        else:
            ids = [i for i in mapper.frame_ids if not np.array_equal(poses[i], mapper.pose(i))][-40:]
        read = SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=str(args.poses)), poses)).read
        pairs = []
        for i in ids:
            old = mapper._rpu.store.get(i)
            pairs.append((old, mapper.delta(dataclasses.replace(read(i), T_world_cam=poses[i]), old.observation)))
        for arm in args.arms.split(","):
            if arm not in ("skip", "all"):
                raise SystemExit(f"arm {arm!r}: expected skip or all")
            memory.SKIP_UNCHANGED = arm == "skip"
            c0 = time.thread_time()
            for old, new in pairs:
                mapper.memory.replace(old, new)
            for old, new in pairs:
                mapper.memory.replace(new, old)
            ms = 1e3 * (time.thread_time() - c0) / (2 * len(pairs))
            print(json.dumps({"arm": arm, "frames": len(pairs), "cpu_ms_per_swap": round(ms, 1)}), flush=True)
    finally:
        memory.SKIP_UNCHANGED = True
        mapper.close()


if __name__ == "__main__":
    main()
