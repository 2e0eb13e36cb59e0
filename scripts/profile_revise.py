"""Where ``panovocc revise`` spends its time (docs/mapping.md, "Revise at building scale"): runs
:func:`panovocc_cli.mapping.pipeline.run_revise` on MAP with POSES, timing its phases (wall, and CPU of
the thread that runs them), and prints one JSON object.

    cp -r MAP W/m && python scripts/profile_revise.py W/m POSES

Phases: ``load`` (Mapper.load: memory.npz read and rebuilt, the log opened), per revised frame ``old``
(DeltaStore.get: the kept record read and decoded), ``delta`` (the new delta computed under the new pose),
``swap`` (VoxelMemory.replace), ``encode`` (mapstore.encode_delta of the new record, on the writer thread),
``read`` (the frame's depth and colours, on the reader thread); then ``memory_write`` (mapstore.write_memory),
``save`` (all of ReversibleMemory.save: memory.npz, snapshot, commit; since the fourth pass only its start on
the calling thread, the rest on the writer thread: ``memory_write``), ``labels`` (Mapper.export: the occupied
voxels and their GSC labels; since the fourth pass on the calling thread while ``memory_write`` runs) and
``export`` (prediction.npz and map.ply: write_exports, ``labels`` included when it makes the export itself);
``close`` (Mapper.close: the wait for the writer thread); ``total`` is the whole run_revise.
"""

from __future__ import annotations

import argparse
import functools
import json
import time
from collections import defaultdict
from pathlib import Path

T = defaultdict(lambda: [0, 0.0, 0.0])  # phase -> [calls, wall s, thread CPU s]


def _timed(owner, name: str, phase: str) -> None:
    fn = getattr(owner, name)

    @functools.wraps(fn)
    def wrapper(*a, **k):
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            return fn(*a, **k)
        finally:
            rec = T[phase]
            rec[0] += 1
            rec[1] += time.perf_counter() - t0
            rec[2] += time.thread_time() - c0

    setattr(owner, name, wrapper)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("poses", type=Path)
    args = ap.parse_args()

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping import mapper, pipeline, rpu
    from panovocc_cli.mapping.memory import VoxelMemory

    _timed(mapper.Mapper, "load", "load")
    _timed(rpu.DeltaStore, "get", "old")
    _timed(mapper.Mapper, "_delta", "delta")
    _timed(VoxelMemory, "replace", "swap")
    _timed(mapstore, "encode_delta", "encode")
    _timed(mapstore, "write_memory", "memory_write")
    _timed(rpu.ReversibleMemory, "save", "save")
    _timed(pipeline, "write_exports", "export")
    _timed(mapper.Mapper, "export", "labels")
    _timed(mapper.Mapper, "close", "close")
    _timed(pipeline.SequenceFrames, "read", "read")
    t0, c0 = time.perf_counter(), time.process_time()
    summary = pipeline.run_revise(args.map, args.poses, progress=False)
    out = {"revised": summary["revised"], "total_wall_s": round(time.perf_counter() - t0, 2),
           "total_cpu_s": round(time.process_time() - c0, 2)}
    out.update({k: {"calls": n, "wall_s": round(w, 2), "cpu_s": round(c, 2)} for k, (n, w, c) in T.items()})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
