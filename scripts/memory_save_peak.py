"""Peak resident memory of writing a map's ``memory.npz``, above the loaded memory (docs/mapping.md, "Memory
layout", "On the building").

    python scripts/memory_save_peak.py MAP OUT            # streamed, a key range at a time (what save does)
    python scripts/memory_save_peak.py MAP OUT --whole    # from whole arrays (to_arrays, the former save)
    python scripts/memory_save_peak.py MAP OUT --chunk 65536   # streamed, 2^16 allocated voxels a chunk

Loads MAP's ``memory.npz`` into a :class:`~panovocc_cli.mapping.memory.VoxelMemory`, hands the freed heap
back, writes a one-voxel memory's file (the compiled kernels load once), resets the process's peak resident memory (``/proc/self/clear_refs``), writes ``OUT/memory.npz``
(OUT is created; it must not hold one) and prints one JSON object: resident memory after the load and
the write's peak (MB), the peak above the loaded process, the memory held (``VoxelMemory.nbytes``), the
write's wall and CPU seconds and the file's SHA-256 (equal for both forms). Run each form in its own process.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--whole", action="store_true", help="write from whole arrays (VoxelMemory.to_arrays)")
    ap.add_argument("--chunk", type=int, default=None,
                    help="allocated voxels a chunk of the stream (memory.SAVE_CHUNK; the same file whatever it is)")
    args = ap.parse_args()
    if args.chunk is not None:
        import panovocc_cli.mapping.memory as memory_module

        memory_module.SAVE_CHUNK = args.chunk

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping.memory import Delta, VoxelMemory
    from panovocc_cli.runtime import process_status_mb, release_freed_heap

    if (args.out / mapstore.MEMORY_NAME).exists():
        raise SystemExit(f"{args.out / mapstore.MEMORY_NAME}: exists (give an empty folder)")
    arrays, done, poses, ids = mapstore.read_memory(args.map, sparse=True)
    memory = VoxelMemory.from_arrays(arrays)
    del arrays
    release_freed_heap()
    held = sum(memory.nbytes().values()) / 2 ** 20
    import tempfile

    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:  # load the compiled kernels first: a one-off cost, not the write's
        tiny = VoxelMemory(memory.voxel_size, memory.specs)
        tiny.add(Delta(np.zeros(1, np.int64), {s.name: np.ones((1, s.width), np.int64) for s in memory.specs}))
        mapstore.write_memory(tmp, tiny.to_arrays(sparse=True) if args.whole else tiny.chunked(), 1, np.eye(4)[None])
    release_freed_heap()
    Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) starts again from the current RSS
    rss0 = process_status_mb("VmRSS")
    args.out.mkdir(parents=True, exist_ok=True)
    t0, c0 = time.perf_counter(), time.process_time()
    source = memory.to_arrays(sparse=True) if args.whole else memory.chunked()
    mapstore.write_memory(args.out, source, done, poses, ids)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    peak = process_status_mb("VmHWM")
    sha = hashlib.sha256((args.out / mapstore.MEMORY_NAME).read_bytes()).hexdigest()
    print(json.dumps({"form": "whole" if args.whole else "streamed", "rss_after_load_mb": round(rss0, 1),
                      "peak_mb": round(peak, 1), "peak_above_load_mb": round(peak - rss0, 1),
                      "memory_held_mb": round(held, 1), "write_wall_s": round(wall, 2), "write_cpu_s": round(cpu, 2),
                      "sha256": sha}))


if __name__ == "__main__":
    main()
