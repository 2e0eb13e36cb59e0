"""Revisions of a saved map's frames in one process, arm after arm: wall and CPU time per revised frame, so
that two variants are compared under the same load (docs/mapping.md, "Building revise, third pass").

    cp -r MAP W/m && python scripts/revise_ab.py W/m POSES [--arms many,loop,all,many,loop,all]

The frames whose pose differs in POSES are revised to it and then back to the map's poses (the same work
twice; the memory ends as it began). An arm is ``many`` (``Mapper.revise_many``, as ``panovocc revise``:
the next frame's delta computed while the last one is swapped in on a second thread), ``loop`` (a loop of
``Mapper.revise``, one thread) or ``all`` (that loop with every voxel of the difference added,
``memory.SKIP_UNCHANGED = False``: the swap before 2026-12-03's third pass). The map folder's log gets
records that are never committed (reopening it cuts them off): use a copy. Prints one JSON line an arm.
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
    ap.add_argument("--arms", default="many,loop,all,many,loop,all")
    args = ap.parse_args()

    from panovocc_cli.runtime import setup

    setup()
    import numpy as np

    from panovocc_cli.io.poses import frame_poses
    from panovocc_cli.io.sequence import read_meta
    from panovocc_cli.mapping import Mapper, memory
    from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config

    cfg = load_config(args.map)
    target = frame_poses(args.poses, read_meta(cfg.seq).frames)
    read = SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=str(args.poses)), target)).read
    mapper = Mapper.load(args.map, frame_source=read)
    try:
        kept = {i: mapper.pose(i) for i in mapper.frame_ids}
        ids = [i for i in kept if not np.array_equal(target[i], kept[i])]
        for arm in args.arms.split(","):
            if arm not in ("many", "loop", "all"):
                raise SystemExit(f"arm {arm!r}: expected many, loop or all")
            memory.SKIP_UNCHANGED = arm != "all"
            t0, c0 = time.perf_counter(), time.process_time()
            for poses in (target, kept):
                if arm == "many":
                    mapper.revise_many((i, poses[i], None) for i in ids)
                else:
                    for i in ids:
                        mapper.revise(i, poses[i])
            n = 2 * len(ids)
            print(json.dumps({"arm": arm, "revised": n, "wall_ms": round(1e3 * (time.perf_counter() - t0) / n, 1),
                              "cpu_ms": round(1e3 * (time.process_time() - c0) / n, 1)}), flush=True)
    finally:
        memory.SKIP_UNCHANGED = True
        mapper.close()


if __name__ == "__main__":
    main()
