"""What a user whose poses carry per-frame jitter gets from the front end instead (issue 22, docs/slam.md "Pose
jitter", "The front end placed by a noisy trajectory"): for each scene and depth of a ``benchmark.jitter`` folder,
four maps, all ``--segmenter none`` and scored against the scene's mesh ground truth (IoU), and the front end's ATE:

* ``true``: the sequence's own poses;
* ``jittered``: the jittered poses the bench made (``W/SCENE.JITTER.poses.txt``), as they are;
* ``placed``: the front end's poses, fitted to the jittered ones at the end of the run (``map --poses slam
  --poses-align se3 --poses-reference JITTERED``): all that a user with only the jittered poses can place it by;
* ``aligned``: the same poses fitted to the true ones (``map --poses placed/poses.txt --poses-align se3``, how the
  paper scores SLAM maps).

    python scripts/jitter_front_end.py W [--jitter t10mm.r0.1deg.s0] [--export "--resolve --spill 0.3"]
                                         [--align se3-pose]

W is a folder of ``python -m panovocc_cli.benchmark.jitter W ...`` (its sequences ``SCENE.clean`` /
``SCENE.realistic``, ``SCENE.gt.npz`` and the jittered poses); the results go to W/front_end/ (one folder a scene
and depth) and a Markdown table to stdout and W/front_end/table.md. ``--export``: map options added to every map
(the face resolution and spill, say). ``--align``: how ``placed`` fits the front end's poses to the jittered ones
(``se3``, the default: Umeyama on the positions; ``se3-pose``: the whole poses, orientations too; its results go to
W/front_end.se3-pose/). Nothing in W is changed.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

PANOVOCC = [sys.executable, "-m", "panovocc_cli"]


def _run(args: list) -> str:
    r = subprocess.run(PANOVOCC + [str(a) for a in args], capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["failed"])[-1]
        raise SystemExit(f"panovocc {' '.join(map(str, args))}: {last}")
    return r.stdout


def _iou(pred: Path, gt: Path) -> float:
    return float(json.loads(_run(["eval", pred, gt, "--json"]))["iou"])


def _map(seq: Path, out: Path, extra: list) -> Path:
    if not (out / "prediction.npz").is_file():
        _run(["map", seq, out, "--segmenter", "none", "--checkpoint-every", "0", "--quiet", "--overwrite", *extra])
    return out / "prediction.npz"


def bench_runs(w: Path):
    """(scene, depth, sequence, ground truth) of every scene and depth a ``benchmark.jitter`` folder ``w`` holds."""
    scenes = sorted(p.name[: -len(".gt.npz")] for p in w.glob("*.gt.npz"))
    if not scenes:
        raise SystemExit(f"{w}: no SCENE.gt.npz (a benchmark.jitter folder was expected)")
    for sc in scenes:
        for depth in ("clean", "realistic"):
            if (w / f"{sc}.{depth}" / "meta.json").is_file():
                yield sc, depth, w / f"{sc}.{depth}", w / f"{sc}.gt.npz"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--jitter", default="t10mm.r0.1deg.s0", help="the jittered poses' tag in W (SCENE.TAG.poses.txt)")
    ap.add_argument("--export", default="", help="map options added to every map")
    ap.add_argument("--align", default="se3", choices=("se3", "se3-pose"), help="placed: --poses-align of the fit")
    a = ap.parse_args()
    w, extra = a.work, shlex.split(a.export)
    out = w / ("front_end" if a.align == "se3" else f"front_end.{a.align}")
    out.mkdir(exist_ok=True)
    lines = ["| scene | depth | ATE (mm) | true poses | jittered | front end, placed by the jittered | front end, "
             "aligned to the true |", "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for sc, depth, seq, gt in bench_runs(w):
        jit = w / f"{sc}.{a.jitter}.poses.txt"
        d = out / f"{sc}.{depth}"
        true = _iou(_map(seq, d / "true", extra), gt)
        jittered = _iou(_map(seq, d / "jittered", ["--poses", jit, *extra]), gt)
        placed = _iou(_map(seq, d / "placed", ["--poses", "slam", "--poses-align", a.align,
                                               "--poses-reference", jit,
                                               *extra]), gt)
        est = d / "placed" / "poses.txt"
        _run(["traj", "eval", est, seq / "poses.txt", "--json", d / "ate.json", "--overwrite"])
        ate = 1e3 * json.loads((d / "ate.json").read_text())["ate_m"]["rmse"]
        aligned = _iou(_map(seq, d / "aligned", ["--poses", est, "--poses-align", "se3", *extra]), gt)
        row = (f"| {sc} | {depth} | {ate:.2f} | {true:.2f} | {jittered:.2f} ({jittered - true:+.2f}) | "
               f"{placed:.2f} ({placed - true:+.2f}) | {aligned:.2f} ({aligned - true:+.2f}) |")
        lines.append(row)
        print(row, flush=True)
    (out / "table.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
