"""``panovocc revise``'s parts on a saved map in one process, arm after arm, so that two variants are
compared under the same load (docs/mapping.md, "Building revise, third pass"). MAP is only read, but the
``frames`` measure appends log records that are never committed (reopening cuts them off): use a copy.
Prints one JSON line an arm.

    cp -r MAP W/m
    python scripts/revise_ab.py write W/m OUT [--arms threaded,serial,threaded,serial]
    python scripts/revise_ab.py swap W/m POSES [--frames A:B] [--arms skip,all,skip,all]
    python scripts/revise_ab.py frames W/m POSES [--arms many,loop,all,many,loop,all]

``write``: ``memory.npz`` streamed from the memory (``VoxelMemory.chunked``, as a foreground save): arm
``threaded`` (as ``map`` and ``revise`` write it: entries compressed on a second thread while the next ones
are read, ``io.npz.write_npz(threaded=True)``) or ``serial`` (all in the calling thread); its CPU (all
threads, and ``calling_thread_cpu_s``: what a second core cannot take over), wall time and peak above the
loaded map; each arm writes OUT/ARM/memory.npz (compare them with ``cmp``).

``swap``: ``VoxelMemory.replace`` of each frame of ``A:B`` (default: the last 40 whose pose differs in POSES),
its kept delta by its delta under POSES, in and back (the memory ends as it began): arm ``skip`` (the kept
voxels the difference does not change left out, ``memory.SKIP_UNCHANGED``) or ``all`` (every voxel of the
union added, as before); CPU of the swapping thread per swap.

``frames``: the frames whose pose differs in POSES revised to it and back: arm ``many``
(``Mapper.revise_many``, as ``panovocc revise``: the next frame's delta computed while the last one is
swapped in on a second thread), ``loop`` (a loop of ``Mapper.revise``) or ``all`` (that loop with
``memory.SKIP_UNCHANGED = False``: the swap before the third pass); wall and CPU per revised frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

ARMS = {"write": "threaded,serial,threaded,serial", "swap": "skip,all,skip,all", "frames": "many,loop,all,many,loop,all"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("measure", choices=sorted(ARMS))
    ap.add_argument("map", type=Path)
    ap.add_argument("path", type=Path, help="write: the output folder; swap, frames: the pose file")
    ap.add_argument("--frames", default=None, help="swap: A:B, frame ids (default: the last 40 moved frames)")
    ap.add_argument("--arms", default=None)
    args = ap.parse_args()
    arms = (args.arms or ARMS[args.measure]).split(",")
    bad = [a for a in arms if a not in ARMS[args.measure].split(",")]
    if bad:
        raise SystemExit(f"{args.measure}: unknown arm {bad[0]!r} (expected one of {ARMS[args.measure]})")

    from panovocc_cli.runtime import setup

    setup()  # the heap settings every command runs with
    {"write": _write, "swap": _swap, "frames": _frames}[args.measure](args, arms)


def _sequence(mapper_folder: Path, poses_path: Path):
    """(the pose table of ``poses_path`` for the map's sequence, a reader of its frames under those poses)."""
    from panovocc_cli.io.poses import frame_poses
    from panovocc_cli.io.sequence import read_meta
    from panovocc_cli.mapping.pipeline import SequenceFrames, _open_sequence, load_config

    cfg = load_config(mapper_folder)
    poses = frame_poses(poses_path, read_meta(cfg.seq).frames)
    return poses, SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=str(poses_path)), poses)).read


def _write(args, arms) -> None:
    from panovocc_cli.io import mapstore, npz
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.runtime import process_status_mb, release_freed_heap

    mapper = Mapper.load(args.map)
    ids, poses = mapper._rpu.poses()
    try:
        for arm in arms:
            mapstore.write_npz = (lambda *a, _arm=arm, **k:  # noqa: E731 - write_memory's own threaded= is overridden
                                  npz.write_npz(*a, **{**k, "threaded": _arm == "threaded"}))
            out = args.path / arm
            out.mkdir(parents=True, exist_ok=True)
            release_freed_heap()
            Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) restarts from the resident memory now
            before = process_status_mb("VmRSS")
            t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
            mapstore.write_memory(out, mapper.memory.chunked(), len(ids), poses)
            print(json.dumps({"arm": arm, "wall_s": round(time.perf_counter() - t0, 2),
                              "cpu_s": round(time.process_time() - c0, 2),
                              "calling_thread_cpu_s": round(time.thread_time() - m0, 2),
                              "peak_above_loaded_mb": round(process_status_mb("VmHWM") - before, 1)}), flush=True)
    finally:
        mapstore.write_npz = npz.write_npz
        mapper.close()


def _swap(args, arms) -> None:
    import numpy as np

    from panovocc_cli.mapping import Mapper, memory

    poses, read = _sequence(args.map, args.path)
    mapper = Mapper.load(args.map)
    try:
        if args.frames:
            a, b = (int(x) for x in args.frames.split(":"))
            ids = list(range(a, b))
        else:
            ids = [i for i in mapper.frame_ids if not np.array_equal(poses[i], mapper.pose(i))][-40:]
        pairs = []
        for i in ids:
            old = mapper._rpu.store.get(i)
            pairs.append((old, mapper.delta(dataclasses.replace(read(i), T_world_cam=poses[i]), old.observation)))
        for arm in arms:
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


def _frames(args, arms) -> None:
    import numpy as np

    from panovocc_cli.mapping import Mapper, memory

    target, read = _sequence(args.map, args.path)
    mapper = Mapper.load(args.map, frame_source=read)
    try:
        kept = {i: mapper.pose(i) for i in mapper.frame_ids}
        ids = [i for i in kept if not np.array_equal(target[i], kept[i])]
        for arm in arms:
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
