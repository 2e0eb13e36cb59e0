"""Where pose jitter's errors lie against the floor and the ceiling (issue 22, docs/slam.md "Translation and
rotation apart"): false positives and false negatives in all and in the ground truth's lowest and highest
occupied layers and the layers next to them.

    python scripts/jitter_floor_layers.py GT.npz TRUE_MAP JITTERED_MAP

Each map is exported with the default occupancy and with ``--spill 0.3 --resolve`` (``Mapper.export``) and
compared with GT.npz voxel by voxel (false positives: occupied in the map, free in the ground truth; false
negatives: occupied in the ground truth, not in the map; the FreeOcc mask's unknown voxels left out).
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from panovocc_cli.grid import UNKNOWN
from panovocc_cli.io.grid import read_grid
from panovocc_cli.mapping.params import OccupancyParams
from panovocc_cli.mapquery import open_map


def occupied(grid) -> set:
    return set(map(tuple, np.argwhere((grid.labels > 0) & (grid.labels != UNKNOWN)) + grid.index0))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("gt")
    ap.add_argument("true_map")
    ap.add_argument("jittered_map")
    a = ap.parse_args(argv)
    gt = read_grid(a.gt)
    G = occupied(gt)
    known = set(map(tuple, np.argwhere(gt.labels != UNKNOWN) + gt.index0))
    z = np.array([v[2] for v in G])
    near = {int(z.min()) + d for d in (-1, 0, 1)} | {int(z.max()) + d for d in (-1, 0, 1)}
    for label, spill, resolve in (("default", 0.0, False), ("spill 0.3 + resolve", 0.3, True)):
        for name, path in (("true poses", a.true_map), ("jittered", a.jittered_map)):
            m = open_map(path)
            try:
                m.config = dataclasses.replace(m.config, occupancy=dataclasses.replace(
                    OccupancyParams(), spill=spill, resolve=resolve))
                P = occupied(m.export().grid)
            finally:
                m.close()
            fp = [v for v in P if v not in G and v in known]
            fn = [v for v in G if v not in P]
            tp = len(P & G)
            print(f"{label}, {name}: IoU {100 * tp / (tp + len(fp) + len(fn)):.2f}, false positives {len(fp)} "
                  f"({sum(v[2] in near for v in fp)} in the floor's and ceiling's layers +-1), false negatives "
                  f"{len(fn)} ({sum(v[2] in near for v in fn)} there)")


if __name__ == "__main__":
    main()
