"""The jitter grid of the front end placed by a noisy trajectory (issue 22, docs/slam.md "The front end placed by a
noisy trajectory"): for each scene and depth that ``scripts/jitter_front_end.py W --align FIT`` ran, the front end's
poses of that run (``placed/poses.txt``) placed again by the true poses jittered by each (sigma_t, sigma_r) of the
grid (``panovocc traj perturb SEQ/poses.txt P --jitter T --rot-jitter-deg R --seed S``, as the jitter bench makes
them), mapped as ``panovocc map SEQ OUT --poses placed/poses.txt --poses-align FIT --poses-reference P
--segmenter none --checkpoint-every 0`` and scored against the scene's mesh ground truth (IoU, loss against the
run's true-pose map).

The front end's relative poses do not depend on the reference it is fitted to (its frames are tracked from their
depth alone); the cell a ``jitter_front_end.py`` run used (10 mm / 0.1 deg by default) is that run's own map, the
others are these re-placements (the same poses moved by another fit, not another tracking run).

    python scripts/jitter_front_end_grid.py W [--align se3-pose] [--grid 0,0.005,0.01,0.02:0,0.05,0.1,0.2] [--seed 0]

Writes W/front_end[.FIT]/grid.sS.csv (scene, depth, sigma_t_mm, sigma_r_deg, iou, loss; S the jitter seed) and
prints, per cell, how many of the scene x depth pairs lose at most 2 points and the largest loss (Markdown, also in
grid.sS.md).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from jitter_front_end import _iou, _map, _run  # scripts/: the same panovocc calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--align", default="se3-pose", choices=("se3", "se3-pose"))
    ap.add_argument("--grid", default="0,0.005,0.01,0.02:0,0.05,0.1,0.2", help="T1,T2,..:R1,R2,.. (metres:degrees)")
    ap.add_argument("--seed", type=int, default=0, help="jitter seed (traj perturb --seed)")
    a = ap.parse_args()
    w = a.work
    ts, rs = ([float(x) for x in part.split(",")] for part in a.grid.split(":"))
    fe = w / ("front_end" if a.align == "se3" else f"front_end.{a.align}")
    runs = sorted(p.parent.parent for p in fe.glob("*/placed/poses.txt"))
    if not runs:
        raise SystemExit(f"{fe}: no SCENE.DEPTH/placed/poses.txt (run scripts/jitter_front_end.py {w} first)")
    rows = []
    for run in runs:
        scene, depth = run.name.rsplit(".", 1)
        seq, gt = w / f"{scene}.{depth}", w / f"{scene}.gt.npz"
        true = _iou(run / "true" / "prediction.npz", gt)
        for t in ts:
            for r in rs:
                tag = f"t{t * 1000:g}mm.r{r:g}deg.s{a.seed}"
                jit = w / f"{scene}.{tag}.poses.txt"
                if not jit.is_file():
                    _run(["traj", "perturb", seq / "poses.txt", jit, "--jitter", t, "--rot-jitter-deg", r,
                          "--seed", a.seed])
                iou = _iou(_map(seq, run / "grid" / tag, ["--poses", run / "placed" / "poses.txt", "--poses-align",
                                                          a.align, "--poses-reference", jit]), gt)
                rows.append({"scene": scene, "depth": depth, "sigma_t_mm": round(t * 1000, 3), "sigma_r_deg": r,
                             "iou": round(iou, 2), "loss": round(true - iou, 2)})
                print(f"{scene} {depth} {t * 1000:g} mm {r:g} deg: {iou:.2f} ({iou - true:+.2f})", flush=True)
    with open(fe / f"grid.s{a.seed}.csv", "w", newline="") as f:
        wr = csv.DictWriter(f, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    n = len(runs)
    lines = ["| sigma_t | " + " | ".join(f"{r:g} deg" for r in rs) + " |", "|---|" + "---|" * len(rs)]
    for t in ts:
        cells = []
        for r in rs:
            losses = [x["loss"] for x in rows if x["sigma_t_mm"] == round(t * 1000, 3) and x["sigma_r_deg"] == r]
            cells.append(f"{sum(v <= 2.0 for v in losses)}/{n} ({max(losses):.2f})")
        lines.append(f"| {t * 1000:g} mm | " + " | ".join(cells) + " |")
    (fe / f"grid.s{a.seed}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
