"""Measure the lifted ground truth against mesh truth, beside the mapper on the same frames (docs/gt.md,
README "Pan-Holo360D").

For each seed: ``synth`` a scene, ``render`` it clean and with ``--noise realistic``, build its mesh ground
truth, lift ground truth from each sequence (the multi-view consensus, gt/consensus.py) with every 5th /
10th / 20th frame annotated and score it against the mesh one (IoU / mIoU under both masks, label
agreement on voxels occupied in both); map the same sequence with ``panovocc map`` (geometry only:
``--segmenter none``, its occupancy does not depend on the classes) and score that map's occupancy
against the same mesh truth. ``--sweep-seeds`` adds a table of the consensus rules on other seeds (the
ones the defaults were chosen on: 10 11).

    python scripts/gt_protocol.py work/gt-protocol --seeds 0 1 2 3 --width 512

Writes OUT/protocol.csv/.md (every row), OUT/goals.csv/.md (per seed and depth: lifted vs mapper IoU,
label agreement, the issue's goals), OUT/protocol_mean.csv/.md, OUT/rules.csv/.md (with --sweep-seeds)
and prints the Markdown tables.
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

SWEEP = ({}, {"min_points": 2}, {"min_points": 5}, {"min_frames": 1}, {"min_frames": 3}, {"min_hit_ratio": 0.0},
         {"min_hit_ratio": 0.1}, {"min_hit_ratio": 0.2}, {"min_hit_ratio": 0.3}, {"min_hit_ratio": 0.35},
         {"min_hit_ratio": 0.4}, {"surface_tol_r2": 0.002}, {"surface_tol_r2": 0.008}, {"surface_tol": 0.04})


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


def _data(out: Path, seed: int, frames: int, width: int):
    """Scene, mesh truth and the clean / realistic sequences of one seed (built once, reused)."""
    from panovocc_cli.datasets.synth import SynthConfig, run_synth
    from panovocc_cli.gt import GtConfig, run_mesh_gt
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.rendering.render import RenderConfig, run_render

    scene = out / f"scene{seed}"
    if not (scene / "traj.txt").is_file():
        run_synth(SynthConfig(out=scene, seed=seed, frames=frames))
    gt_path = out / f"mesh{seed}.npz"
    if not gt_path.is_file():
        run_mesh_gt(GtConfig(scene=scene, out=gt_path))
    seqs = {}
    for noise in ("none", "realistic"):
        seq_path = out / f"seq{seed}_{noise}"
        if not (seq_path / "poses.txt").is_file():
            run_render(RenderConfig(scene=scene, out=seq_path, width=width, noise=noise, seed=seed, progress=False))
        seqs[noise] = seq_path
    return read_grid(gt_path), seqs


def _mapper(seq_path: Path, out: Path):
    """The mapper's occupancy on the same frames (``panovocc map SEQ OUT --segmenter none``), its grid."""
    from panovocc_cli.io.grid import read_grid
    from panovocc_cli.mapping.config import MapConfig, SemanticParams
    from panovocc_cli.mapping.pipeline import run_map

    if not (out / "prediction.npz").is_file():
        run_map(MapConfig(seq=str(seq_path), out=str(out), semantic=SemanticParams(segmenter="none")), overwrite=True,
                progress=False)
    return read_grid(out / "prediction.npz")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    ap.add_argument("--sweep-seeds", type=int, nargs="*", default=[])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--every", type=int, nargs="+", default=[5, 10, 20])
    args = ap.parse_args()

    from panovocc_cli.gt import LiftParams
    from panovocc_cli.gt.agreement import compare_to_mesh
    from panovocc_cli.gt.run import lift_sequence
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.runtime import setup

    setup()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    lift0 = LiftParams()
    rows, goal_rows, rule_rows = [], [], []
    cols = ["seed", "depth", "annotated", "IoU", "mIoU", "IoU obs", "mIoU obs", "label agree", "classed",
            "agree among classed", "voted", "transferred", "254", "cpu s"]
    for seed in args.seeds:
        mesh, seqs = _data(out, seed, args.frames, args.width)
        for noise, seq_path in seqs.items():
            depth = "clean" if noise == "none" else noise
            seq = Sequence(seq_path)
            m = compare_to_mesh(_mapper(seq_path, out / f"map{seed}_{noise}"), mesh)
            for k in args.every:
                t = time.process_time()
                g, st = lift_sequence(seq, 0.08, replace(lift0, annotated=f"every:{k}"))
                cpu = time.process_time() - t
                c = compare_to_mesh(g, mesh)
                rows.append([seed, depth, f"every {k} ({st['annotated']})", c["iou"], c["miou"], c["iou_observed"],
                             c["miou_observed"], c["agree"], c["classed"], c["agree_classed"], st["voted"],
                             st["transferred"], st["no_class"], round(cpu, 1)])
                print(rows[-1], flush=True)
                if k != 10:
                    continue
                goal = c["iou"] >= m["iou"] if noise == "realistic" else c["iou_observed"] >= 90.0
                goal_rows.append([seed, depth, c["iou"], m["iou"], c["iou_observed"], m["iou_observed"], c["agree"],
                                  ("IoU >= mapper" if noise == "realistic" else "IoU obs >= 90")
                                  + (": met" if goal else ": MISSED")])
    for seed in args.sweep_seeds:
        mesh, seqs = _data(out, seed, args.frames, args.width)
        for noise, seq_path in seqs.items():
            seq = Sequence(seq_path)
            for kw in SWEEP:
                g, _ = lift_sequence(seq, 0.08, replace(lift0, **kw))
                c = compare_to_mesh(g, mesh)
                rule_rows.append([seed, "clean" if noise == "none" else noise,
                                  ", ".join(f"{k} {v:g}" for k, v in kw.items()) or "defaults", c["iou"], c["miou"],
                                  c["iou_observed"], c["agree"]])
                print(rule_rows[-1], flush=True)
    rules = (f"min points {lift0.min_points}, min frames {lift0.min_frames}, hit ratio {lift0.min_hit_ratio}, "
             f"surface tol {lift0.surface_tol} m + {lift0.surface_tol_r2} m/m^2 r^2, "
             f"label radius {lift0.label_radius} m")
    md = _write(out, "goals", ["seed", "depth", "lifted IoU", "mapper IoU", "lifted IoU obs", "mapper IoU obs",
                               "label agree", "goal"], goal_rows,
                f"Lifted ground truth and the mapper on the same frames, both against mesh truth (percent; every "
                f"10th frame annotated; width {args.width}, {args.frames} frames; {rules})")
    md += "\n" + _write(out, "protocol", cols, rows, "Lifted vs mesh ground truth (percent)")
    keys = sorted({(r[1], r[2].split(" (")[0]) for r in rows}, key=lambda x: (x[0], int(x[1].split()[1])))
    mean_rows = []
    for d, a in keys:
        sel = np.array([r[3:10] for r in rows if r[1] == d and r[2].startswith(a + " ")], dtype=np.float64)
        mean_rows.append([d, a, *[float(x) for x in np.nanmean(sel, 0)]])
    md += "\n" + _write(out, "protocol_mean", ["depth", "annotated"] + cols[3:10], mean_rows,
                        f"Mean over seeds {' '.join(map(str, args.seeds))}")
    if rule_rows:
        md += "\n" + _write(out, "rules", ["seed", "depth", "change from the defaults", "IoU", "mIoU", "IoU obs",
                                           "label agree"], rule_rows,
                            f"The consensus rules on seeds {' '.join(map(str, args.sweep_seeds))} (every 10th frame "
                            "annotated)")
    print(md)


if __name__ == "__main__":
    main()
