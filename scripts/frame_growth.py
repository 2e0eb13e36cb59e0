"""Is a late frame dearer than an early one because of the run, or because of the frame? (issue 21, per-frame
cost growth; docs/mapping.md, "Revise at building scale"). On a saved map, for 30 frames at 10 % of the run
and its last 30: the delta under the kept pose with the kept semantic observation (what ``revise``
computes; CPU of the calling thread, the compiled kernels' other threads not counted, and wall), and
``VoxelMemory.add`` of their kept records into an empty memory and into the map's whole memory (there as
``-1`` then ``+1``: the memory ends as it was). Prints one JSON object of means per frame.

    cp -r MAP W/m && python scripts/frame_growth.py W/m
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args()

    from panovocc_cli.runtime import setup

    setup()
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.mapper import memory_channels
    from panovocc_cli.mapping.memory import VoxelMemory
    from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config

    m = Mapper.load(args.map)
    try:
        ids_all = m.frame_ids
        n, k = len(ids_all), args.frames
        reader = SequenceFrames(_open_sequence(load_config(args.map))).read
        out = {}
        for name, ids in (("early", ids_all[int(0.1 * n):int(0.1 * n) + k]), ("late", ids_all[n - k:])):
            recs = [m._rpu.store.get(i) for i in ids]
            frames = [reader(i) for i in ids]
            c0, t0 = time.thread_time(), time.perf_counter()
            for i, f, r in zip(ids, frames, recs):
                m.delta(dataclasses.replace(f, T_world_cam=m.pose(i)), r.observation)
            out[f"{name}_delta_thread_cpu_ms"] = 1e3 * (time.thread_time() - c0) / len(ids)
            out[f"{name}_delta_wall_ms"] = 1e3 * (time.perf_counter() - t0) / len(ids)
            fresh = VoxelMemory(m.memory.voxel_size, memory_channels(m.config))
            c0 = time.thread_time()
            for r in recs:
                fresh.add(r, +1)
            out[f"{name}_add_into_empty_ms"] = 1e3 * (time.thread_time() - c0) / len(ids)
            c0 = time.thread_time()
            for r in recs:
                m.memory.add(r, -1)
                m.memory.add(r, +1)
            out[f"{name}_add_into_whole_map_ms"] = 1e3 * (time.thread_time() - c0) / (2 * len(ids))
            out[f"{name}_delta_keys"] = float(np.mean([sum(len(p) for p in r.parts) for r in recs]))
    finally:
        m.close()
    print(json.dumps({k: round(v, 1) for k, v in out.items()}))


if __name__ == "__main__":
    main()
