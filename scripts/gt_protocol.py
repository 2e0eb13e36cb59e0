"""Measure the lifted ground-truth protocol against mesh truth (docs/gt.md, README "Pan-Holo360D").

For each seed: ``synth`` a scene, ``render`` it clean and with ``--noise realistic``, build its mesh ground
truth, then lift ground truth from each sequence with every 5th / 10th / 20th frame annotated and score it
against the mesh one (IoU / mIoU under both masks, label agreement on voxels occupied in both). A second
table sweeps the support rule and the label radius (every 10th frame annotated) to justify the defaults.

    python scripts/gt_protocol.py work/gt-protocol --seeds 0 1 --width 512

Writes OUT/protocol.csv, OUT/protocol.md, OUT/rules.csv, OUT/rules.md and prints the Markdown tables.
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def _row_md(cols, rows) -> str:
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(f"{v:.1f}" if isinstance(v, float) else str(v) for v in r) + " |")
    return "\n".join(lines) + "\n"


def _write(out: Path, name: str, cols, rows, title: str) -> str:
    with open(out / f"{name}.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows(rows)
    md = f"{title}\n\n" + _row_md(cols, rows)
    (out / f"{name}.md").write_text(md)
    return md


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--every", type=int, nargs="+", default=[5, 10, 20])
    args = ap.parse_args()

    from panovocc_cli.datasets.synth import SynthConfig, run_synth
    from panovocc_cli.gt import GtConfig, LiftParams, run_mesh_gt
    from panovocc_cli.gt.agreement import compare_to_mesh
    from panovocc_cli.gt.run import accumulate_sequence
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.rendering.render import RenderConfig, run_render
    from panovocc_cli.runtime import setup

    setup()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    lift0 = LiftParams()
    rows, rule_rows = [], []
    cols = ["seed", "depth", "annotated", "IoU", "mIoU", "IoU obs", "mIoU obs", "label agree", "classed",
            "agree among classed", "voted", "transferred", "254", "cpu s"]
    for seed in args.seeds:
        scene = out / f"scene{seed}"
        if not (scene / "traj.txt").is_file():
            run_synth(SynthConfig(out=scene, seed=seed, frames=args.frames))
        gt_path = out / f"mesh{seed}.npz"
        if not gt_path.is_file():
            run_mesh_gt(GtConfig(scene=scene, out=gt_path))
        mesh = read_grid(gt_path)
        for noise in ("none", "realistic"):
            seq_path = out / f"seq{seed}_{noise}"
            if not (seq_path / "poses.txt").is_file():
                run_render(RenderConfig(scene=scene, out=seq_path, width=args.width, noise=noise, seed=seed,
                                        progress=False))
            seq = Sequence(seq_path)
            for k in args.every:
                lift = replace(lift0, annotated=f"every:{k}")
                t = time.process_time()
                acc, ann = accumulate_sequence(seq, 0.08, lift)
                g = acc.grid(seq.meta.class_names, lift.min_frames, lift.min_points, lift.label_radius,
                             lift.min_hit_ratio)
                cpu = time.process_time() - t
                c = compare_to_mesh(g, mesh)
                st = acc.stats
                rows.append([seed, "clean" if noise == "none" else noise, f"every {k} ({len(ann)})", c["iou"],
                             c["miou"], c["iou_observed"], c["miou_observed"], c["agree"], c["classed"],
                             c["agree_classed"], st["voted"], st["transferred"], st["no_class"], round(cpu, 1)])
                print(rows[-1], flush=True)
                if k != 10:
                    continue
                for mf, mp, ratio in ((1, 1, 0.0), (2, 1, 0.0), (2, 3, 0.0), (3, 3, 0.0), (5, 5, 0.0),
                                      (2, 3, 0.1), (2, 3, 0.2), (2, 3, 0.35), (2, 3, 0.5)):
                    for radius in ((0.0, 0.08, 0.16, 0.32) if (mf, mp, ratio) == (2, 3, 0.2) else (0.16,)):
                        g = acc.grid(seq.meta.class_names, mf, mp, radius, ratio)
                        c = compare_to_mesh(g, mesh)
                        rule_rows.append([seed, "clean" if noise == "none" else noise, mf, mp, f"{ratio:g}",
                                          f"{radius:g}",
                                          c["iou"], c["miou"], c["iou_observed"], c["miou_observed"], c["agree"],
                                          c["classed"]])
    md = _write(out, "protocol", cols, rows, "Lifted vs mesh ground truth (percent; defaults: min frames "
                f"{lift0.min_frames}, min points {lift0.min_points}, hit ratio {lift0.min_hit_ratio}, label "
                f"radius {lift0.label_radius} m; width {args.width}, {args.frames} frames)")
    # the mean over seeds, per (depth, annotated)
    keys = sorted({(r[1], r[2].split(" (")[0]) for r in rows}, key=lambda x: (x[0], int(x[1].split()[1])))
    mean_rows = []
    for d, a in keys:
        sel = np.array([r[3:10] for r in rows if r[1] == d and r[2].startswith(a + " ")], dtype=np.float64)
        mean_rows.append([d, a, *[float(x) for x in np.nanmean(sel, 0)]])
    md += "\n" + _write(out, "protocol_mean", ["depth", "annotated"] + cols[3:10], mean_rows,
                        f"Mean over seeds {' '.join(map(str, args.seeds))}")
    rcols = ["seed", "depth", "min frames", "min points", "hit ratio", "label radius m", "IoU", "mIoU", "IoU obs",
             "mIoU obs", "label agree", "classed"]
    md += "\n" + _write(out, "rules", rcols, rule_rows, "Support rule and label radius (every 10th frame annotated)")
    print(md)


if __name__ == "__main__":
    main()
