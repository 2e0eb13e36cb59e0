"""``memory.npz`` of a saved map written in one process, arm after arm: its CPU and wall time and its peak
above the loaded map, so that two variants are compared under the same load (docs/mapping.md, "Building
revise, third pass").

    python scripts/memory_write_ab.py MAP OUT [--arms threaded,serial,threaded,serial]

An arm is ``threaded`` (as ``map`` and ``revise`` write it: the entries compressed on a second thread while
the next ones are read from the memory, ``io.npz.write_npz(threaded=True)``) or ``serial`` (all in the
calling thread, as before). The file is streamed from the memory a key range at a time
(``VoxelMemory.chunked``) as a foreground save does. MAP is only read; each arm writes OUT/ARM/memory.npz.
Prints one JSON line an arm (``cpu_s``: all threads; ``calling_thread_cpu_s``: the thread that calls
``write_memory``, what a second core cannot take over); compare the arms' bytes with ``cmp``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--arms", default="threaded,serial,threaded,serial")
    args = ap.parse_args()

    from panovocc_cli.runtime import process_status_mb, release_freed_heap, setup

    setup()  # the heap settings every command runs with
    from panovocc_cli.io import mapstore, npz
    from panovocc_cli.mapping import Mapper

    mapper = Mapper.load(args.map)
    ids, poses = mapper._rpu.poses()
    try:
        for arm in args.arms.split(","):
            if arm not in ("threaded", "serial"):
                raise SystemExit(f"arm {arm!r}: expected threaded or serial")
            mapstore.write_npz = (lambda *a, _arm=arm, **k:  # noqa: E731 - write_memory's own threaded= is overridden
                                  npz.write_npz(*a, **{**k, "threaded": _arm == "threaded"}))
            out = args.out / arm
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


if __name__ == "__main__":
    main()
