"""Peak memory of the export alone (the labelled grid and the PLY a run writes after its last frame) of a
saved map, above the loaded memory (issue 21, docs/mapping.md "On the building").

    python scripts/export_rss.py MAP OUT [--block 64]

Loads MAP (read only: nothing is written there; ``Mapper.load`` of a finished ``panovocc map`` folder),
hands the freed heap back as ``map`` does before its export, resets the process's peak resident memory
(Linux ``/proc/self/clear_refs``), then writes OUT/prediction.npz and OUT/map.ply the way ``map`` does
(``pipeline.write_exports``; OUT must not exist). Prints one JSON object: the memory held
(``VoxelMemory.nbytes``), the resident memory before the export and the peak during it (MB), the peak
above the loaded process and that over the memory held, seconds, occupied voxels. Compare two versions'
bytes with ``cmp OUT1/prediction.npz OUT2/prediction.npz`` (and map.ply).
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
    ap.add_argument("--block", type=int, default=None, help="GSC cube edge, voxels (default: the export's)")
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
    args.out.mkdir(parents=True)
    mapper = Mapper.load(args.map)
    held = sum(mapper.memory.nbytes().values()) / 2 ** 20
    release_freed_heap()
    Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) restarts from the resident memory now
    before = process_status_mb("VmRSS")
    t0 = time.perf_counter()
    summary = write_exports(args.out, mapper, load_config(args.map).semantic.ply_color)
    seconds = time.perf_counter() - t0
    peak = process_status_mb("VmHWM")
    mapper.close()
    print(json.dumps({"memory_held_mb": round(held, 1), "rss_before_export_mb": round(before, 1),
                      "peak_rss_export_mb": round(peak, 1), "export_above_loaded_mb": round(peak - before, 1),
                      "export_above_over_held": round((peak - before) / held, 3) if held else None,
                      "seconds": round(seconds, 2), **summary}))


if __name__ == "__main__":
    main()
