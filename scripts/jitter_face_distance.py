"""How the pose-jitter loss depends on where the floor lies against the voxel lattice (issue 22, docs/slam.md
"Pose jitter": a floor a millimetre from a voxel face).

    python scripts/jitter_face_distance.py WORK [--seed 5] [--mm -1,0,0.5,1,2,4,8,16,24] [--jitter 0.01:0.1]
                                                [--resolve-behind Z] [--frames 60]

One home (``synth --seed S --frames N``, 60 by default) placed at its seeded x, y offset and at z = 0.8 m + d
for each d in ``--mm`` (millimetres: the floor d above a face of the 8 cm lattice; negative: below one), its
mesh ground truth, a clean render at 512x256, and two maps with ``--offsets``: true poses and the poses jittered by
``--jitter`` (``traj perturb --jitter T --rot-jitter-deg R --seed 0``). Each map is exported with the
default occupancy and with ``--spill 0.3 --resolve`` (``--resolve-behind Z``: that margin instead of
the default's) and scored like ``panovocc eval`` (FreeOcc IoU).
Prints and writes ``WORK/face_distance_behindZ_fN.csv``: d, the ceiling's distance from the nearest face, and
per export the true-pose IoU, the jittered IoU and the loss. Every step's output is kept in WORK and reused.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import subprocess
import sys
from pathlib import Path

from panovocc_cli.benchmark import panovocc_command
from panovocc_cli.datasets.home import generate_scene
from panovocc_cli.datasets.layout import lattice_offset
from panovocc_cli.evaluation.metrics import count_pair
from panovocc_cli.io.grid import read_grid
from panovocc_cli.mapping.params import OccupancyParams
from panovocc_cli.mapquery import open_map

H = 0.08
EXPORTS = (("default", 0.0, False), ("spill 0.3 + resolve", 0.3, True))


def _run(*args) -> None:
    subprocess.run(panovocc_command(*args), check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _iou(map_dir: Path, gt, spill: float, resolve: bool, behind: float) -> float:
    m = open_map(map_dir)
    try:
        m.config = dataclasses.replace(m.config, occupancy=dataclasses.replace(
            OccupancyParams(), spill=spill, resolve=resolve, resolve_behind=behind))
        c = count_pair(m.export().grid, gt)["freeocc"]
        return 100.0 * c.tp / max(c.tp + c.fp + c.fn, 1)
    finally:
        m.close()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--mm", default="-1,0,0.5,1,2,4,8,16,24")
    ap.add_argument("--jitter", default="0.01:0.1", help="sigma_t metres:sigma_r degrees")
    ap.add_argument("--resolve-behind", type=float, default=OccupancyParams().resolve_behind)
    ap.add_argument("--frames", type=int, default=60, help="frames of the home's walk (synth --frames)")
    a = ap.parse_args(argv)
    t, r = (float(v) for v in a.jitter.split(":"))
    a.work.mkdir(parents=True, exist_ok=True)
    x, y, _ = lattice_offset(a.seed)
    hc = float(generate_scene(a.seed, None, a.frames, (0.0, 0.0, 0.0))["ceiling_height"])
    rows = []
    for d in (float(v) for v in a.mm.split(",")):
        z = 0.8 + d / 1000.0
        tag = f"s{a.seed}_d{d:g}mm" + (f"_f{a.frames}" if a.frames != 60 else "")
        scene, gt_path, seq = a.work / tag, a.work / f"{tag}.gt.npz", a.work / f"{tag}.clean"
        if not scene.exists():
            _run("synth", scene, "--seed", a.seed, "--frames", a.frames, "--offset", f"{x:.3f},{y:.3f},{z:.4f}")
        if not gt_path.exists():
            _run("gt", scene, gt_path)
        if not seq.exists():
            _run("render", scene, seq, "--width", 512)
        poses = a.work / f"{tag}.jitter.txt"
        if not poses.exists():
            _run("traj", "perturb", seq / "poses.txt", poses, "--jitter", t, "--rot-jitter-deg", r, "--seed", 0)
        maps = {}
        for name, extra in (("true", []), ("jitter", ["--poses", poses])):
            out = a.work / f"{tag}.{name}.map"
            if not (out / "prediction.npz").exists():
                _run("map", seq, out, *extra, "--segmenter", "none", "--checkpoint-every", 0, "--offsets", "--quiet",
                     "--overwrite")
            maps[name] = out
        gt = read_grid(gt_path)
        ceil = (z + hc) % H
        row = {"floor_mm": d, "ceiling_mm": round(1000 * min(ceil, H - ceil), 1)}
        for label, spill, resolve in EXPORTS:
            i0, i1 = (_iou(maps[k], gt, spill, resolve, a.resolve_behind) for k in ("true", "jitter"))
            row.update({f"{label}: true": round(i0, 2), f"{label}: jitter": round(i1, 2),
                        f"{label}: loss": round(i0 - i1, 2)})
        rows.append(row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    with open(a.work / f"face_distance_behind{a.resolve_behind:g}_f{a.frames}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    try:
        main()
    except subprocess.CalledProcessError as e:
        sys.exit(f"error: {' '.join(map(str, e.cmd[2:]))} failed: {e.stderr.decode(errors='replace').strip()}")
