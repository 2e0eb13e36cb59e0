"""How much of a map an incremental export labels again (docs/mapping.md, "Incremental revise export").

BEFORE is a map folder, AFTER a copy of it after ``panovocc revise`` (or any change of some frames' poses).
The blocks the changed frames' old and new deltas reach stand for what ``revise`` tracks
(``VoxelMemory.changed_blocks``); AFTER's memory is then exported incrementally against BEFORE's
``prediction.npz`` and in full, for each GSC cube side given, and one line a side reports the voxels
labelled again and read (``export.relabel_region``), the rows handed to the GSC (``export.gsc_inputs``) and
the export's process CPU, and checks that both exports give the same grid.

    python scripts/export_region_count.py BEFORE AFTER [--blocks 128 64]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from panovocc_cli.geometry.lattice import unpack_keys
from panovocc_cli.io.grid import read_grid
from panovocc_cli.mapping import Mapper, export
from panovocc_cli.mapping.memory import BLOCK


def changed_blocks(before: Mapper, after: Mapper) -> np.ndarray:
    """Block indices (m, 3) of every key of the old and new deltas of the frames whose pose differs."""
    ids = [i for i in after.frame_ids if not np.array_equal(before.pose(i), after.pose(i))]
    blocks = [np.zeros((0, 3), np.int64)]
    for m in (before, after):
        for i in ids:
            blocks += [np.unique(unpack_keys(p.keys) // BLOCK, axis=0) for p in m._rpu.store.get(i).parts]
    print(f"{len(ids)} frames changed")
    return np.unique(np.concatenate(blocks), axis=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--blocks", type=int, nargs="+", default=[128])
    a = ap.parse_args()
    m0, m1 = Mapper.load(a.before), Mapper.load(a.after)
    blocks = changed_blocks(m0, m1)
    del m0
    previous = read_grid(f"{a.before}/prediction.npz")
    rows, seen = [], {}
    real_inputs, real_region = export.gsc_inputs, export.relabel_region
    export.gsc_inputs = lambda c, g, r: rows.append(len(r)) or real_inputs(c, g, r)

    def region(*args, **kwargs):
        r = real_region(*args, **kwargs)
        seen.update(relabel=int((r == 2).sum()), read=int((r >= 1).sum()), occupied=len(r))
        return r

    export.relabel_region = region
    for side in a.blocks:
        out = {}
        for kind in ("incremental", "full"):
            rows.clear()
            t = time.process_time()
            ex = m1.export(previous, changed_blocks=blocks, block=side) if kind == "incremental" \
                else m1.export(block=side)
            out[kind] = (ex, time.process_time() - t, sum(rows), len(rows))
        (inc, ti, ri, ci), (full, tf, rf, cf) = out["incremental"], out["full"]
        same = np.array_equal(inc.grid.labels, full.grid.labels)
        print(f"cubes of {side}: {len(blocks)} changed blocks; relabelled {seen['relabel']:,}, read {seen['read']:,} "
              f"of {seen['occupied']:,} occupied voxels; GSC rows {ri:,} in {ci} cubes against {rf:,} in {cf}; "
              f"export CPU {ti:.2f} s against {tf:.2f} s; the same grid: {same}")


if __name__ == "__main__":
    main()
