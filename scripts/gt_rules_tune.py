"""The consensus's span rule and hit ratio on the tuning seeds (docs/gt.md, "The protocol measured against
mesh truth"): each sequence is lifted once and its settled consensus re-thresholded, so a row costs a grid,
not a lifting. Reads what ``scripts/gt_protocol.py OUT --seeds ...`` built in OUT (scenes, mesh truth,
sequences, the mapper's maps).

    python scripts/gt_protocol.py work/gt-tune --seeds 10 11 --every 10     # the data (and the mapper)
    python scripts/gt_rules_tune.py work/gt-tune --seeds 10 11

Prints, per seed and depth, IoU / IoU obs / label agreement against mesh truth with the spans off
(SPAN_MAX 0) and on, and with the hit ratio 0.2, 0.25, 0.3, 0.35, 0.4 (every 10th frame annotated).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[10, 11])
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.2, 0.25, 0.3, 0.35, 0.4])
    args = ap.parse_args()

    from panovocc_cli.gt import LiftParams, consensus
    from panovocc_cli.gt.agreement import compare_to_mesh
    from panovocc_cli.gt.run import accumulate_sequence
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.runtime import setup

    setup()
    print("| seed | depth | spans | hit ratio | IoU | IoU obs | label agree | mapper IoU |\n" + "|---" * 8 + "|")
    span_max = consensus.SPAN_MAX
    for seed in args.seeds:
        mesh = read_grid(args.out / f"mesh{seed}.npz")
        for noise in ("none", "realistic"):
            seq = Sequence(args.out / f"seq{seed}_{noise}")
            m = compare_to_mesh(read_grid(args.out / f"map{seed}_{noise}" / "prediction.npz"), mesh)
            for spans in (0, span_max):
                consensus.SPAN_MAX = spans
                acc, _ = accumulate_sequence(seq, 0.08, replace(LiftParams(), annotated="every:10"))
                for ratio in args.ratios:
                    acc.min_hit_ratio = ratio
                    c = compare_to_mesh(acc.grid(seq.meta.class_names, LiftParams().label_radius), mesh)
                    depth = "clean" if noise == "none" else noise
                    print(f"| {seed} | {depth} | {'on' if spans else 'off'} | {ratio:g} | {c['iou']:.2f} | "
                          f"{c['iou_observed']:.2f} | {c['agree']:.2f} | {m['iou']:.2f} |", flush=True)
    consensus.SPAN_MAX = span_max


if __name__ == "__main__":
    main()
