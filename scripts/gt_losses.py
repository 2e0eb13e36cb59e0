"""Where the lifted ground truth loses against mesh truth, beside the mapper (docs/gt.md): missing and extra
voxels, what the consensus made of them, how many lie next to a lifted voxel, their mesh classes.

    python scripts/gt_protocol.py work/gt-protocol --seeds 1 --every 10       # the data (and the mapper)
    python scripts/gt_losses.py work/gt-protocol 1 realistic

Reads OUT/mesh{seed}.npz, OUT/seq{seed}_{noise} (noise: none or realistic), OUT/map{seed}_{noise}/prediction.npz;
lifts the sequence with the default rules (every 10th frame annotated) and prints the counts.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np


def _next_to(x: np.ndarray) -> np.ndarray:
    """Voxels with a 6-neighbour in ``x``."""
    n = np.zeros_like(x)
    for ax in range(3):
        for s in (-1, 1):
            n |= np.roll(x, s, ax)
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("seed", type=int)
    ap.add_argument("noise", choices=("none", "realistic"))
    args = ap.parse_args()

    from panovocc_cli.evaluation.align import resample_onto
    from panovocc_cli.grid import Grid
    from panovocc_cli.gt import LiftParams
    from panovocc_cli.gt.run import accumulate_sequence
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.runtime import setup

    setup()
    out, tag = args.out, f"{args.seed}_{args.noise}"
    mesh = read_grid(out / f"mesh{args.seed}.npz")
    seq = Sequence(out / f"seq{tag}")
    lift = replace(LiftParams(), annotated="every:10")
    acc, _ = accumulate_sequence(seq, 0.08, lift)
    g = acc.grid(seq.meta.class_names, lift.label_radius)
    base, span_vox, _ = acc._spanned()
    cand = np.isfinite(acc.surface[0]) | np.isfinite(acc.surface[1]) | np.isfinite(acc.surface[2])
    status = np.zeros(base.shape, np.uint8)  # 0 never crossed, no mode; 1 crossed, no mode; 2 mode not confirmed
    status[acc.seen] = 1  # 3 confirmed mode voxel; 4 span voxel
    status[cand] = 2
    status[base] = 3
    status[span_vox] = 4
    names = ("unseen, no mode", "seen, no mode", "mode not confirmed", "mode voxel", "span voxel")
    S = resample_onto(Grid(status.reshape(acc.shape), g.origin, g.voxel_size, g.class_names), mesh, fill=255)
    L = resample_onto(g, mesh, fill=255)
    M = resample_onto(read_grid(out / f"map{tag}" / "prediction.npz"), mesh, fill=255)
    G = mesh.labels
    scored = G != 255
    gt, lo, mo = ((x > 0) & (x < 255) & scored for x in (G, L, M))
    near = _next_to(lo)
    rows = (("missing (mesh, not lifted)", gt & ~lo), ("missing, the mapper has them", gt & ~lo & mo),
            ("extra (lifted, not mesh)", lo & ~gt & scored), ("extra, the mapper has not", lo & ~gt & scored & ~mo))
    for title, sel in rows:
        cls = {mesh.class_names[k]: int((sel & (G == k)).sum()) for k in np.unique(G[sel]) if k < len(mesh.class_names)}
        print(f"{title}: {int(sel.sum())}; next to a lifted voxel {int((sel & near).sum())}; "
              + ", ".join(f"{n} {int((sel & (S == k)).sum())}" for k, n in enumerate(names))
              + "; mesh classes: " + ", ".join(f"{n} {c}" for n, c in sorted(cls.items(), key=lambda x: -x[1])[:8]))


if __name__ == "__main__":
    main()
