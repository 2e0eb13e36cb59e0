"""The export of a saved map (``prediction.npz`` and ``map.ply``, as ``map`` and ``revise`` write them) in
one process, arm after arm: its CPU and wall time and its peak above the loaded map, so that two variants
are compared under the same load (docs/mapping.md, "Revise at building scale").

    python scripts/export_ab.py MAP OUT [--arms new,old,new,old] [--block 64]

An arm is ``new`` (the export as it is) or ``old`` (as it was before the changes of 2026-12-03: the GSC steps
by the scipy formulation, ``gsc.iterate_scipy``, instead of compiled, ``gsc_kernels.iterate``, and each slab's cubes
found by ``np.unique(..., axis=0)`` instead of ``gsc._unique_pairs``), with an optional cube edge:
``new@128`` (default ``--block``). MAP is only
read; each arm writes OUT/ARM/. Prints one JSON line an arm; compare the arms' bytes with ``cmp``.
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
    ap.add_argument("--arms", default="new,old,new,old")
    ap.add_argument("--block", type=int, default=None, help="GSC cube edge, voxels (default: the export's)")
    args = ap.parse_args()

    from panovocc_cli.runtime import process_status_mb, release_freed_heap, setup

    setup()  # the heap settings every command runs with
    import panovocc_cli.mapping.export as export
    import panovocc_cli.semantics.gsc as gsc
    import panovocc_cli.semantics.gsc_kernels as kernels
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.pipeline import load_config, write_exports

    import numpy as np

    compiled, pairs = kernels.iterate, gsc._unique_pairs
    default_block = export.BLOCK if args.block is None else args.block
    mapper = Mapper.load(args.map)
    color = load_config(args.map).semantic.ply_color
    try:
        for arm in args.arms.split(","):
            kind, _, block = arm.partition("@")
            if kind not in ("new", "old"):
                raise SystemExit(f"arm {arm!r}: expected new or old, optionally @BLOCK")
            kernels.iterate = compiled if kind == "new" else gsc.iterate_scipy
            gsc._unique_pairs = pairs if kind == "new" else (lambda a, b: np.unique(np.stack([a, b], 1), axis=0))
            export.BLOCK = int(block) if block else default_block
            out = args.out / arm
            out.mkdir(parents=True, exist_ok=True)
            release_freed_heap()
            Path("/proc/self/clear_refs").write_text("5")  # the peak (VmHWM) restarts from the resident memory now
            before = process_status_mb("VmRSS")
            t0, c0 = time.perf_counter(), time.process_time()
            write_exports(out, mapper, color)
            print(json.dumps({"arm": arm, "block": export.BLOCK, "wall_s": round(time.perf_counter() - t0, 1),
                              "cpu_s": round(time.process_time() - c0, 1),
                              "peak_above_loaded_mb": round(process_status_mb("VmHWM") - before, 1)}), flush=True)
    finally:
        kernels.iterate, gsc._unique_pairs = compiled, pairs
        mapper.close()


if __name__ == "__main__":
    main()
