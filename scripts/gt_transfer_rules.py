"""The lifted truth's label transfer against mesh truth (docs/gt.md, "The label rule"): label agreement with
the voxels no annotated pixel reached labelled by one nearest labelled voxel (the KD-tree's first, the rule
before), by the most common class of the nearest ones (ties: the class with fewer labelled voxels), and by
the default (the same among those on the voxel's own consensus surface first), at label radii
``--radius`` (percent, every 10th frame annotated).
Each sequence is lifted once; the rules differ only in the transfer.

    python scripts/gt_protocol.py work/gt-tune --seeds 10 11 --every 10     # the data (seeds 12 13 the same way)
    python scripts/gt_transfer_rules.py work/gt-tune --seeds 10 11 12 13
    python scripts/gt_transfer_rules.py --seq work/pan-holo/seq --mesh work/pan-holo/gt_mesh.npz --miou   # the split

``--miou`` adds each rule's mIoU against mesh truth (eval8, FreeOcc mask) after its agreement.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, nargs="?", help="gt_protocol.py's folder (seqS_none, seqS_realistic, meshS.npz)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[10, 11])
    ap.add_argument("--seq", type=Path, help="one sequence instead (with --mesh)")
    ap.add_argument("--mesh", type=Path)
    ap.add_argument("--miou", action="store_true")
    ap.add_argument("--radius", type=float, nargs="+", default=[0.16])
    args = ap.parse_args()

    from scipy.spatial import cKDTree

    from panovocc_cli.gt import LiftParams
    from panovocc_cli.gt.agreement import compare_to_mesh, label_agreement
    from panovocc_cli.gt.lifted import SAME_SURFACE_TOL, transfer_labels
    from panovocc_cli.gt.run import accumulate_sequence
    from panovocc_cli.grid import OCCUPIED_UNKNOWN_CLASS as NO_CLASS
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.runtime import setup

    setup()
    lift = replace(LiftParams(), annotated="every:10")

    def plain_nearest(cls, src, dst, shape, r):
        out = np.full(len(dst), NO_CLASS, np.uint8)
        tree = cKDTree(np.stack(np.unravel_index(src, shape), 1).astype(np.float64))
        d, j = tree.query(np.stack(np.unravel_index(dst, shape), 1).astype(np.float64),
                          distance_upper_bound=r * (1 + 1e-9))
        hit = np.isfinite(d)
        out[hit] = cls[src[j[hit]]]
        return out

    rules = {"one nearest (before)": lambda c, s, d, sh, r, acc: plain_nearest(c, s, d, sh, r),
             "most common of the nearest": lambda c, s, d, sh, r, acc: transfer_labels(c, s, d, sh, r),
             "on its own surface first (default)": lambda c, s, d, sh, r, acc: transfer_labels(
                 c, s, d, sh, r, acc.surface, SAME_SURFACE_TOL * acc.h)}
    cols = [f"{k} r {r:g}" for r in args.radius for k in rules]
    print("| seed | depth | " + " | ".join(cols) + " |\n" + "|---" * (2 + len(cols)) + "|")
    table = []
    if args.seq is not None:
        if args.mesh is None:
            ap.error("--seq needs --mesh")
        cases = [(args.seq.name, "", args.seq, args.mesh)]
    elif args.out is not None:
        cases = [(seed, "clean" if noise == "none" else noise, args.out / f"seq{seed}_{noise}",
                  args.out / f"mesh{seed}.npz") for seed in args.seeds for noise in ("none", "realistic")]
    else:
        ap.error("give OUT (with --seeds) or --seq and --mesh")
    for name, depth, seq_path, mesh_path in cases:
        mesh = read_grid(mesh_path)
        seq = Sequence(seq_path)
        acc, _ = accumulate_sequence(seq, 0.08, lift)
        g = acc.grid(seq.meta.class_names, 0.0)  # no transfer: 254 where no annotation reached
        base = g.labels.reshape(-1).copy()
        occ = (base > 0) & (base < 255)
        src, dst = np.flatnonzero(occ & (base != NO_CLASS)), np.flatnonzero(base == NO_CLASS)
        cells, row = [], []
        for r in args.radius:
            for rule in rules.values():
                lab = base.copy()
                lab[dst] = rule(base, src, dst, g.labels.shape, r / acc.h, acc)
                g.labels[...] = lab.reshape(g.labels.shape)
                a = label_agreement(g, mesh)["agree"]
                row.append(a)
                cells.append(f"{a:.3f}" + (f" / {compare_to_mesh(g, mesh)['miou']:.2f}" if args.miou else ""))
        table.append(row)
        print(f"| {name} | {depth} | " + " | ".join(cells) + " |", flush=True)
    print("| mean | | " + " | ".join(f"{x:.3f}" for x in np.mean(table, 0)) + " |")


if __name__ == "__main__":
    main()
