"""The lifted truth's label rule against mesh truth (docs/gt.md, "The label rule"): label agreement with the
votes alone (the support votes and the span voxels' owners, the rule before the area cells), with the votes
in the voxel each point lies in added, and the default (the class covering the most area cells first), and
beside each, the percent of them that disagree among the mode voxels with votes / the span voxels / the
voxels labelled by the transfer (or 254).
Each sequence is lifted once; the rules differ only in what the grid is given.

    python scripts/gt_protocol.py work/gt-tune --seeds 10 11 --every 10     # the data
    python scripts/gt_label_rules.py work/gt-tune --seeds 10 11
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[10, 11])
    args = ap.parse_args()

    from panovocc_cli.classes import canonical_name
    from panovocc_cli.evaluation.align import resample_onto
    from panovocc_cli.gt import LiftParams
    from panovocc_cli.gt.agreement import label_agreement
    from panovocc_cli.gt.run import accumulate_sequence
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.runtime import setup

    setup()
    lift = replace(LiftParams(), annotated="every:10")
    print("| seed | depth | votes alone | + votes where the point lies | + area cells first (default) |\n"
          + "|---" * 5 + "|")
    for seed in args.seeds:
        mesh = read_grid(args.out / f"mesh{seed}.npz")
        for noise in ("none", "realistic"):
            seq = Sequence(args.out / f"seq{seed}_{noise}")
            acc, _ = accumulate_sequence(seq, 0.08, lift)
            names = seq.meta.class_names
            pos, cells = acc._pos_votes, acc._cells
            base, span_vox, _ = acc._spanned()
            voted = np.zeros(base.size, bool)
            for k, _ in acc._votes:
                voted[np.unique(k // acc.n_classes)] = True
            kind = np.full(base.size, 2)  # 0 mode voxel with votes, 1 span voxel, 2 transferred or 254
            kind[span_vox] = 1
            kind[base & voted] = 0
            ids: dict[str, int] = {}
            to_id = lambda grid: np.array([ids.setdefault(canonical_name(n), len(ids)) if 0 < k < 254 else -1  # noqa: E731
                                           for k, n in enumerate(grid.class_names)] + [-1] * (256 - len(grid.class_names)))
            agree, parts = [], []
            for p, c in (([], []), (pos, []), (pos, cells)):
                acc._pos_votes, acc._cells = p, c
                g = acc.grid(names, lift.label_radius)
                agree.append(label_agreement(g, mesh)["agree"])
                # where it disagrees with the mesh truth, by what labelled the voxel: wrong / all, percent
                M = resample_onto(mesh, g, fill=255).reshape(-1)
                L = g.labels.reshape(-1)
                both = (L > 0) & (L < 255) & (M > 0) & (M < 255)
                wrong = both & (to_id(g)[L] != to_id(mesh)[M])
                parts.append(" / ".join(f"{100 * (wrong & (kind == k)).sum() / max(1, (both & (kind == k)).sum()):.1f}"
                                        for k in range(3)))
            depth = "clean" if noise == "none" else noise
            print(f"| {seed} | {depth} | " + " | ".join(f"{a:.2f} ({w})" for a, w in zip(agree, parts)) + " |", flush=True)


if __name__ == "__main__":
    main()
