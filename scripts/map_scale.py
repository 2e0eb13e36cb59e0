"""Scale figures of a finished map run (README "Pan-Holo360D", docs/gt.md): memory per occupied voxel and
the delta store's size on disk, optionally with the peak memory of the run from a ``/usr/bin/time -v`` log.

    /usr/bin/time -v panovocc map work/pan-holo/seq work/pan-holo/map --quiet 2> work/pan-holo/map.time
    python scripts/map_scale.py work/pan-holo/map --time-log work/pan-holo/map.time

Prints one JSON object: frames, occupied voxels (prediction.npz), the voxel memory the mapper keeps in RAM
(``Mapper.load``, ``VoxelMemory.nbytes``: geometry blocks, semantic pages and rows, hash table; per
allocated voxel and per semantic row),
the memory file and the delta store on disk (bytes; per frame), and from the time log the peak resident
memory of the whole run and it per occupied voxel.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("--time-log", type=Path, default=None)
    args = ap.parse_args()

    import numpy as np

    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.mapstore import DELTAS_DIR, MEMORY_NAME, read_memory
    from panovocc_cli.mapping import Mapper

    _, frames, _, _ = read_memory(args.map)
    g = read_grid(args.map / "prediction.npz")
    occ = int(((g.labels > 0) & (g.labels < 255)).sum())
    m = Mapper.load(args.map).memory
    b = m.nbytes()  # what the memory holds: geometry blocks, sparse semantic pages and rows, hash table
    mem = int(sum(b.values()))
    nonzero = len(m.nonzero()[0])
    deltas = [p for p in (args.map / DELTAS_DIR).rglob("*") if p.is_file()]
    dbytes = sum(p.stat().st_size for p in deltas)
    out = {"frames": frames, "occupied_voxels": occ, "nonzero_voxels": nonzero, "blocks": int(m.n_blocks),
           "allocated_voxels": int(m.allocated_voxels), "semantic_rows": int(m.n_rows),
           "ram_memory_bytes": mem, "ram_bytes": b,
           "geometry_bytes_per_allocated_voxel": b["dense"] / max(m.allocated_voxels, 1),
           "semantic_bytes_per_row": (b["rows"] + b["pages"]) / m.n_rows if m.n_rows else None,
           "ram_memory_bytes_per_occupied_voxel": mem / occ if occ else None,
           "memory_file_bytes": (args.map / MEMORY_NAME).stat().st_size, "delta_files": len(deltas),
           "delta_store_bytes": dbytes, "delta_store_mb_per_frame": dbytes / 1e6 / max(frames, 1)}
    if args.time_log is not None:
        text = args.time_log.read_text()
        m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", text)
        u = re.search(r"User time \(seconds\): ([\d.]+)", text)
        s = re.search(r"System time \(seconds\): ([\d.]+)", text)
        w = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", text)
        if m:
            out["peak_rss_bytes"] = int(m.group(1)) * 1024
            out["peak_rss_bytes_per_occupied_voxel"] = out["peak_rss_bytes"] / occ if occ else None
        if u and s:
            out["cpu_s_per_frame"] = (float(u.group(1)) + float(s.group(1))) / max(frames, 1)
        if w:
            parts = [float(x) for x in w.group(1).split(":")]
            wall = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
            out["wall_s_per_frame"] = wall / max(frames, 1)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
