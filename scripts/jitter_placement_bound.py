"""How much of the jitter bench's loss no mapper can avoid (issue 22, docs/slam.md "Pose jitter", "The placement
the jittered poses allow"): per scene and depth, the map made with the *true* poses fitted to the jittered ones
(``panovocc map SEQ OUT --poses SEQ/poses.txt --poses-align FIT --poses-reference JITTERED``, the default export,
``--segmenter none``; FIT ``se3``, Umeyama on the positions, and ``se3-pose``, the whole poses), scored against the
scene's mesh ground truth like ``panovocc eval`` (IoU), against the same map at the true poses.

Per-frame jitter is independent from frame to frame: the frames' images give their poses relative to each other,
but where the whole map lies in the world is known from the jittered poses only, through their fit (about sigma /
sqrt(n) an axis over n frames; a rotation fitted to the positions alone is only as good as sigma_t over the path's
extent, on a room-sized path several times what the orientations give). A mapper with perfect relative poses (this
map) still sits where the fit puts it: its loss is what the placement costs any mapper, however robust.

    python scripts/jitter_placement_bound.py W [--seeds 0,1,2,3,4] [--jitter 0.01:0.1]

W is a folder of ``python -m panovocc_cli.benchmark.jitter W ...`` (its sequences ``SCENE.clean`` /
``SCENE.realistic`` and ``SCENE.gt.npz``); the jittered poses of each seed are made there as the bench makes
them (``panovocc traj perturb SEQ/poses.txt P --jitter T --rot-jitter-deg R --seed S``, reused when present) and
the maps go to W/placement/ (nothing else in W changes). Prints a Markdown table (one row per scene, depth and fit:
the true-pose IoU, then per jitter seed the loss and the fit's offset from the truth) and writes it to
W/placement/table.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from jitter_front_end import _iou, _map, _run, bench_runs  # scripts/: the same panovocc calls


def _offset(map_dir: Path, seq: Path) -> tuple[float, float]:
    """Translation (mm) and rotation (degrees) between the fitted poses the map used and the true ones."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from panovocc_cli.io.poses import read_poses

    a, b = read_poses(map_dir / "poses.txt")[0], read_poses(seq / "poses.txt")[0]
    d = a @ np.linalg.inv(b)  # the same rigid move of every frame
    angle = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1.0, 1.0)))
    return 1e3 * float(np.linalg.norm(d[:3, 3] + d[:3, :3] @ b[:3, 3] - b[:3, 3])), float(angle)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", default="0,1,2,3,4", help="jitter seeds (traj perturb --seed)")
    ap.add_argument("--jitter", default="0.01:0.1", help="sigma_t metres : sigma_r degrees")
    a = ap.parse_args()
    w = a.work
    t, r = (float(x) for x in a.jitter.split(":"))
    seeds = [int(s) for s in a.seeds.split(",")]
    out = w / "placement"
    out.mkdir(exist_ok=True)
    head = (["scene", "depth", "fit", "true poses"] + [f"seed {s}: loss (offset mm, deg)" for s in seeds]
            + ["largest loss"])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    print("\n".join(lines), flush=True)
    for sc, depth, seq, gt in bench_runs(w):
        d = out / f"{sc}.{depth}"
        true = _iou(_map(seq, d / "true", []), gt)
        for fit in ("se3", "se3-pose"):
            cells, losses = [], []
            for s in seeds:
                jit = w / f"{sc}.t{t * 1000:g}mm.r{r:g}deg.s{s}.poses.txt"
                if not jit.is_file():
                    _run(["traj", "perturb", seq / "poses.txt", jit, "--jitter", t, "--rot-jitter-deg", r,
                          "--seed", s])
                m = d / f"{fit}.s{s}"
                iou = _iou(_map(seq, m, ["--poses", seq / "poses.txt", "--poses-align", fit,
                                         "--poses-reference", jit]), gt)
                mm, deg = _offset(m, seq)
                losses.append(true - iou)
                cells.append(f"{true - iou:.2f} ({mm:.1f}, {deg:.3f})")
            row = f"| {sc} | {depth} | {fit} | {true:.2f} | " + " | ".join(cells) + f" | {max(losses):.2f} |"
            lines.append(row)
            print(row, flush=True)
    (out / "table.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
