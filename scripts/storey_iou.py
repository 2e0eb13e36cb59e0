"""Occupancy IoU storey by storey of a building map (issue 22, docs/slam.md "Translation and rotation apart"):
where a map from estimated or shifted poses loses against the mesh ground truth.

    python scripts/storey_iou.py GT.npz MAP_DIR [MAP_DIR ...] [--seed 0]

The storeys are those of ``synth --building --seed S`` (``floor_heights``): storey k spans from 0.2 m below its
floor to 0.2 m below the next one's (the last one upwards). Per map and storey: true positives, false positives
(occupied in the map, free in the ground truth), false negatives (occupied in the ground truth, not in the map;
the ground truth's unknown voxels left out) and their IoU, from each map's ``prediction.npz``; and the whole map's.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from panovocc_cli.datasets.building import generate_building
from panovocc_cli.geometry.lattice import pack_keys
from panovocc_cli.grid import UNKNOWN
from panovocc_cli.io.grid import read_grid


def _keys(grid, mask) -> tuple[np.ndarray, np.ndarray]:
    """Packed world lattice keys of ``mask``'s voxels, and their z (metres, centres)."""
    ijk = np.argwhere(mask) + grid.index0
    return pack_keys(ijk), (ijk[:, 2] + 0.5) * grid.voxel_size


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("gt")
    ap.add_argument("maps", nargs="+")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    floors = list(generate_building(a.seed, None, None, 2, None)["floor_heights"])
    edges = [f - 0.2 for f in floors] + [np.inf]
    edges[0] = -np.inf
    gt = read_grid(a.gt)
    g_occ, g_z = _keys(gt, (gt.labels > 0) & (gt.labels != UNKNOWN))
    g_known, _ = _keys(gt, gt.labels != UNKNOWN)
    free = np.setdiff1d(g_known, g_occ)
    print("| map | " + " | ".join(f"storey {k} (floor {z:.3f} m)" for k, z in enumerate(floors)) + " | all |")
    print("|---|" + "---|" * (len(floors) + 1))
    for m in a.maps:
        pred = read_grid(Path(m) / "prediction.npz")
        p_occ, p_z = _keys(pred, (pred.labels > 0) & (pred.labels != UNKNOWN))
        cells = []
        for lo, hi in list(zip(edges[:-1], edges[1:])) + [(-np.inf, np.inf)]:
            p = p_occ[(p_z >= lo) & (p_z < hi)]
            g = g_occ[(g_z >= lo) & (g_z < hi)]
            tp = len(np.intersect1d(p, g, assume_unique=True))
            fp = int(np.isin(p, free).sum())
            fn = len(g) - tp
            cells.append(f"{100.0 * tp / max(tp + fp + fn, 1):.2f} (fp {fp}, fn {fn})")
        print(f"| {m} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
