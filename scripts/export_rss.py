"""Peak memory of the export alone (the labelled grid and the PLY a run writes after its last frame) of a
saved map, above the loaded memory (issue 21, docs/mapping.md "On the building").

    python scripts/export_rss.py MAP OUT [--block 64] [--chunk 262144] [--phases]

Loads MAP (read only: nothing is written there; ``Mapper.load`` of a finished ``panovocc map`` folder),
hands the freed heap back as ``map`` does before its export, resets the process's peak resident memory
(Linux ``/proc/self/clear_refs``), then writes OUT/prediction.npz and OUT/map.ply the way ``map`` does
(``pipeline.write_exports``; OUT must not exist). Prints one JSON object: the memory held
(``VoxelMemory.nbytes``), the resident memory before the export and the peak during it (MB), the peak
above the loaded process and that over the memory held, seconds, occupied voxels. Compare two versions'
bytes with ``cmp OUT1/prediction.npz OUT2/prediction.npz`` (and map.ply). ``--chunk``: the voxels of one slice of
the export's per-voxel work (``export.CHUNK``; the same bytes whatever it is). ``--phases``: also the peak above
the loaded process while each step runs (the grid of the non-zero slabs, the labels, the grid's and the PLY's
writes), from a thread that reads the resident memory every millisecond.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--block", type=int, default=None, help="GSC cube edge, voxels (default: the export's)")
    ap.add_argument("--chunk", type=int, default=None, help="voxels a slice of the export's per-voxel work")
    ap.add_argument("--phases", action="store_true", help="the peak of each step of the export too")
    args = ap.parse_args()

    from panovocc_cli.runtime import process_status_mb, release_freed_heap, setup

    setup()  # the heap settings every command runs with
    import panovocc_cli.mapping.export as export
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.pipeline import load_config, write_exports

    if args.block is not None:
        if not hasattr(export, "BLOCK"):
            raise SystemExit("this version's export has no GSC blocks (--block)")
        export.BLOCK = args.block
    if args.chunk is not None:
        export.CHUNK = args.chunk
    import panovocc_cli.mapping.pipeline as pipeline

    phase, peaks = ["other"], {}
    if args.phases:
        def marked(module, name):
            f = getattr(module, name)

            def run(*a, **k):
                outer, phase[0] = phase[0], name
                try:
                    return f(*a, **k)
                finally:
                    phase[0] = outer

            setattr(module, name, run)

        for name in ("_grid_of_pieces", "label_occupied"):
            marked(export, name)
        for name in ("write_grid", "write_ply_points"):
            marked(pipeline, name)
    args.out.mkdir(parents=True)
    mapper = Mapper.load(args.map)
    held = sum(mapper.memory.nbytes().values()) / 2 ** 20
    release_freed_heap()
    Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) restarts from the resident memory now
    before = process_status_mb("VmRSS")
    done = threading.Event()

    def sample():
        while not done.is_set():
            peaks[phase[0]] = max(peaks.get(phase[0], 0.0), process_status_mb("VmRSS"))
            time.sleep(0.001)

    sampler = threading.Thread(target=sample, daemon=True)
    if args.phases:
        sampler.start()
    t0 = time.perf_counter()
    summary = write_exports(args.out, mapper, load_config(args.map).semantic.ply_color)
    seconds = time.perf_counter() - t0
    done.set()
    if args.phases:
        sampler.join()
    peak = process_status_mb("VmHWM")
    mapper.close()
    print(json.dumps({"memory_held_mb": round(held, 1), "rss_before_export_mb": round(before, 1),
                      "peak_rss_export_mb": round(peak, 1), "export_above_loaded_mb": round(peak - before, 1),
                      "export_above_over_held": round((peak - before) / held, 3) if held else None,
                      "seconds": round(seconds, 2), **summary,
                      **({"phase_peaks_above_loaded_mb": {k: round(v - before, 1) for k, v in peaks.items()}}
                         if args.phases else {})}))


if __name__ == "__main__":
    main()
