"""A revision's record work per frame on a saved map (docs/mapping.md, "Building revise, fifth pass"): for N
frames whose pose differs in POSES, the new delta is computed once, then timed (CPU ms a frame, this
process): ``encode`` (``rpu.encode_record`` of the new delta), ``decode`` (the kept record's payload decoded
to a FrameDelta, as ``DeltaStore.get`` does) and ``swap`` (``VoxelMemory.replace`` of the kept delta by the
new one and back). MAP is only read. Run it under each checkout's interpreter to compare two versions
(from outside the checkout, so that the interpreter's own package is imported):

    cd /tmp && /path/to/checkout/.venv/bin/python /path/to/scripts/record_costs.py MAP POSES [--frames 10]
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
    ap.add_argument("--frames", type=int, default=10, help="moved frames measured (spread over the moved ones)")
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()

    import numpy as np

    import panovocc_cli
    from panovocc_cli.io import mapstore
    from panovocc_cli.io.poses import frame_poses
    from panovocc_cli.io.sequence import read_meta
    from panovocc_cli.mapping import Mapper, rpu
    from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config
    from panovocc_cli.runtime import setup

    setup()  # the heap settings every command runs with
    cfg = load_config(args.map)
    poses = frame_poses(args.poses, read_meta(cfg.seq).frames)
    read = SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=str(args.poses)), poses)).read
    mapper = Mapper.load(args.map)
    try:
        moved = [i for i in mapper.frame_ids if not np.array_equal(poses[i], mapper.pose(i))]
        if not moved:
            raise SystemExit(f"{args.poses}: no frame's pose differs from the map's")
        ids = moved[::max(1, len(moved) // args.frames)][:args.frames]
        payloads = [mapper.record(i) for i in ids]
        olds = [rpu._frame_delta(*mapstore.decode_record(p)[::2]) for p in payloads]
        news = [mapper.delta(dataclasses.replace(read(i), T_world_cam=poses[i]), o.observation)
                for i, o in zip(ids, olds)]

        def timed(fn, reps):
            for k in range(len(ids)):
                fn(k)  # warm (compiled code loaded)
            c0 = time.process_time()
            for _ in range(reps):
                for k in range(len(ids)):
                    fn(k)
            return round(1e3 * (time.process_time() - c0) / (reps * len(ids)), 2)

        mem = mapper.memory
        out = {"package": str(Path(panovocc_cli.__file__).parent), "frames": len(ids),
               "encode_ms": timed(lambda k: rpu.encode_record(news[k], poses[ids[k]]), args.reps),
               "decode_ms": timed(lambda k: rpu._frame_delta(*mapstore.decode_record(payloads[k])[::2]), args.reps),
               "swap_ms": round(timed(lambda k: (mem.replace(olds[k], news[k]), mem.replace(news[k], olds[k])),
                                      max(1, args.reps // 2)) / 2, 2)}
        print(json.dumps(out), flush=True)
    finally:
        mapper.close()


if __name__ == "__main__":
    main()
