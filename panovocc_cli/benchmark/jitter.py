"""``make bench-jitter``: occupancy IoU against per-frame pose jitter (issue 22), with and without the spill
thinning and the face resolution.

    python -m panovocc_cli.benchmark.jitter WORK [--seeds 2,3,4] [--house] [--spill 0,0.2] [--resolve 0,1] ...

For each home ``panovocc synth sK --seed K`` (``--house``: ``--house --seed K --frames 150``; ``--frames N``: N
poses of the same walk instead, the scene named ``homeK.fN``): its mesh ground
truth (``panovocc gt``), a clean and a realistic-noise render (``panovocc render --width W [--noise realistic
--seed K]``), and for each jitter (sigma_t metres, sigma_r degrees) a jittered copy of the true poses
(``panovocc traj perturb SEQ/poses.txt P --jitter T --rot-jitter-deg R --seed S``) mapped as the CLI maps
(``panovocc map SEQ OUT --poses P --segmenter none --checkpoint-every 0 --offsets``; (0, 0) maps SEQ/poses.txt). Each
map's memory is then exported with this panovocc's occupancy defaults and each ``--spill`` value and each
``--resolve`` value (0 off, 1 on: the face resolution, ``--resolve`` of ``panovocc map``) (``Mapper.export``, the function ``panovocc map`` writes
prediction.npz with) and scored like ``panovocc eval`` (FreeOcc IoU, ``evaluation.metrics.count_pair``).
Every step's output is kept in WORK and reused when present, so a rerun only adds what is missing (a map
made before the surface-offset channel P is made again: the face resolution needs it).

Writes ``WORK/jitter.csv`` (scene, depth, sigma_t_mm, sigma_r_deg, spill, resolve, iou, loss = true-pose IoU
with the same export minus this one) and ``WORK/jitter.md`` (one row per scene, depth and export). With
``--grid T1,T2,..:R1,R2,..`` the jitters are every (sigma_t, sigma_r) pair of the two lists (translation and
rotation apart, the issue's grid) and ``jitter.md`` holds one table per scene, depth and export: a row per
sigma_t, a column per sigma_r; ``jitter.png`` draws the same losses as heat maps (a column per scene and depth, a
row per export).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

from . import panovocc_command

JITTERS = ((0.0, 0.0), (0.005, 0.05), (0.01, 0.1), (0.02, 0.2))  # (sigma_t metres, sigma_r degrees)
DEPTHS = ("clean", "realistic")


def _panovocc(*args) -> None:
    subprocess.run(panovocc_command(*args), check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _scene(work: Path, seed: int, house: bool, width: int, frames: int | None = None) -> tuple[str, Path, dict]:
    """Name, ground truth and the two renders of one scene (made when missing)."""
    name = f"{'house' if house else 'home'}{seed}" + (f".f{frames}" if frames else "")
    scene, gt = work / name, work / f"{name}.gt.npz"
    if not scene.exists():
        n = frames or (150 if house else None)
        _panovocc("synth", scene, "--seed", seed, *(["--house"] if house else []), *(["--frames", n] if n else []))
    if not gt.exists():
        _panovocc("gt", scene, gt)
    seqs = {}
    for depth in DEPTHS:
        seq = work / f"{name}.{depth}"
        if not seq.exists():
            _panovocc("render", scene, seq, "--width", width,
                      *(["--noise", "realistic", "--seed", seed] if depth == "realistic" else []))
        seqs[depth] = seq
    return name, gt, seqs


def _map(work: Path, seq: Path, name: str, depth: str, jitter: tuple, seed: int) -> Path:
    """The map of ``seq`` with its poses jittered by ``jitter`` (made when missing)."""
    t, r = jitter
    tag = f"{name}.{depth}.t{t * 1000:g}mm.r{r:g}deg"
    out = work / f"{tag}.map"
    if (out / "prediction.npz").exists() and _has_offsets(out):
        return out
    poses = []
    if t or r:
        pf = work / f"{name}.t{t * 1000:g}mm.r{r:g}deg.s{seed}.poses.txt"
        if not pf.exists():
            _panovocc("traj", "perturb", seq / "poses.txt", pf, "--jitter", t, "--rot-jitter-deg", r, "--seed", seed)
        poses = ["--poses", pf]
    _panovocc("map", seq, out, *poses, "--segmenter", "none", "--checkpoint-every", 0, "--offsets", "--quiet",
              "--overwrite")
    return out


def _has_offsets(map_dir: Path) -> bool:
    """Whether the map in ``map_dir`` keeps the surface-offset channel P (made with ``geometry.offsets``)."""
    from ..mapping.pipeline import load_config

    return bool(load_config(map_dir).geometry.offsets)


def _ious(map_dir: Path, gt, exports, behind: float = 0.0) -> dict:
    """FreeOcc IoU (%) of the map's memory exported with each (spill, resolve) pair."""
    from ..evaluation.metrics import count_pair
    from ..mapping.params import OccupancyParams
    from ..mapquery import open_map

    mapper = open_map(map_dir)
    try:
        out = {}
        base = mapper.config
        for k, r in exports:  # this panovocc's occupancy defaults, whatever the map was made with
            mapper.config = dataclasses.replace(base, occupancy=dataclasses.replace(
                OccupancyParams(), spill=float(k), resolve=bool(r), resolve_behind=float(behind)))
            c = count_pair(mapper.export().grid, gt)["freeocc"]
            out[k, r] = 100.0 * c.tp / max(c.tp + c.fp + c.fn, 1)
        mapper.config = base
        return out
    finally:
        mapper.close()


def run(work: Path, seeds, house: bool, width: int, exports, jitters, jitter_seed: int, progress=None,
        behind: float = 0.0, frames: int | None = None) -> list:
    """Rows of the table (dicts), every map made or reused in ``work``; ``exports``: (spill, resolve) pairs."""
    from ..io.grid import read_grid

    rows = []
    for seed in seeds:
        name, gt_path, seqs = _scene(work, seed, house, width, frames)
        gt = read_grid(gt_path)
        for depth in DEPTHS:
            ref = None
            for jitter in jitters:
                ious = _ious(_map(work, seqs[depth], name, depth, jitter, jitter_seed), gt, exports, behind)
                ref = ious if jitter == (0.0, 0.0) else ref
                for k, r in exports:
                    rows.append({"scene": name, "depth": depth, "sigma_t_mm": round(jitter[0] * 1000, 3),
                                 "sigma_r_deg": jitter[1], "spill": k, "resolve": int(r), "iou": round(ious[k, r], 2),
                                 "loss": None if ref is None else round(ref[k, r] - ious[k, r], 2)})
                if progress:
                    progress(rows[-len(exports):])
    return rows


def markdown(rows, jitters) -> str:
    """One line per scene, depth and export: the true-pose IoU, then the IoU (loss) at each jitter."""
    head = ["scene", "depth", "spill", "resolve"] + [f"{t * 1000:g} mm / {r:g}°" for t, r in jitters]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    keyed = {}
    for r in rows:
        keyed.setdefault((r["scene"], r["depth"], r["spill"], r["resolve"]), {})[(r["sigma_t_mm"], r["sigma_r_deg"])] = r
    for (scene, depth, k, res), cells in keyed.items():
        vals = []
        for t, rr in jitters:
            c = cells.get((round(t * 1000, 3), rr))
            vals.append("–" if c is None else f"{c['iou']:.2f}" if not (t or rr) or c["loss"] is None
                        else f"{c['iou']:.2f} (−{c['loss']:.2f})" if c["loss"] >= 0 else f"{c['iou']:.2f} (+{-c['loss']:.2f})")
        lines.append("| " + " | ".join([scene, depth, f"{k:g}", "on" if res else "off"] + vals) + " |")
    return "\n".join(lines) + "\n"


def grid_markdown(rows, ts, rs) -> str:
    """One table per scene, depth and export: IoU (loss against the true-pose map) with a row per translation
    jitter ``ts`` (metres) and a column per rotation jitter ``rs`` (degrees)."""
    keyed = {}
    for r in rows:
        keyed.setdefault((r["scene"], r["depth"], r["spill"], r["resolve"]), {})[(r["sigma_t_mm"], r["sigma_r_deg"])] = r
    out = []
    for (scene, depth, k, res), cells in keyed.items():
        out.append(f"{scene}, {depth} depth, spill {k:g}, resolve {'on' if res else 'off'}:\n")
        out.append("| σ_t \\ σ_r | " + " | ".join(f"{r:g}°" for r in rs) + " |")
        out.append("|" + "---|" * (len(rs) + 1))
        for t in ts:
            vals = []
            for rr in rs:
                c = cells.get((round(t * 1000, 3), rr))
                vals.append("–" if c is None else f"{c['iou']:.2f}" if not (t or rr) or c["loss"] is None
                            else f"{c['iou']:.2f} ({'−' if c['loss'] >= 0 else '+'}{abs(c['loss']):.2f})")
            out.append(f"| {t * 1000:g} mm | " + " | ".join(vals) + " |")
        out.append("")
    return "\n".join(out)


def grid_figure(rows, ts, rs):
    """A matplotlib Figure of the grid's losses: one heat map per scene and depth (columns) and export (rows),
    sigma_t down, sigma_r across, each cell the IoU points lost against the true-pose map (one colour scale)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    cols = list(dict.fromkeys((r["scene"], r["depth"]) for r in rows))
    kinds = list(dict.fromkeys((r["spill"], r["resolve"]) for r in rows))
    cell = {(r["scene"], r["depth"], r["spill"], r["resolve"], r["sigma_t_mm"], r["sigma_r_deg"]): r["loss"] for r in rows}
    vmax = max([abs(r["loss"]) for r in rows if r["loss"] is not None] + [1.0])
    fig = Figure(figsize=(2.4 * len(cols) + 1.8, 2.3 * len(kinds) + 0.4), constrained_layout=True)
    axes = fig.subplots(len(kinds), len(cols), squeeze=False)
    im = None
    for i, (k, res) in enumerate(kinds):
        for j, (scene, depth) in enumerate(cols):
            ax = axes[i, j]
            z = np.array([[cell.get((scene, depth, k, res, round(t * 1000, 3), rr)) or 0.0 for rr in rs] for t in ts],
                         dtype=float)
            im = ax.imshow(z, cmap="magma_r", vmin=0.0, vmax=vmax)
            for a in range(len(ts)):
                for b in range(len(rs)):
                    ax.text(b, a, f"{z[a, b]:.1f}", ha="center", va="center", fontsize=7,
                            color="white" if z[a, b] > 0.55 * vmax else "black")
            ax.set_xticks(range(len(rs)), [f"{r:g}°" for r in rs], fontsize=7)
            ax.set_yticks(range(len(ts)), [f"{t * 1000:g} mm" for t in ts], fontsize=7)
            if i == 0:
                ax.set_title(f"{scene}, {depth}", fontsize=9)
            if j == 0:
                ax.set_ylabel(f"spill {k:g}, resolve {'on' if res else 'off'}", fontsize=8)
    fig.colorbar(im, ax=axes, shrink=0.6, label="IoU points lost against true poses")
    return fig


def _floats(text: str) -> tuple:
    return tuple(float(v) for v in text.split(","))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", default="2,3,4", help="scene seeds, comma-separated (default 2,3,4)")
    ap.add_argument("--house", action="store_true", help="houses (synth --house --frames 150) instead of homes")
    ap.add_argument("--frames", type=int, default=None,
                    help="poses of each scene's walk (synth --frames; default 60 for homes, 150 for houses)")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--spill", default="0,0.3", help="spill thinning values to export with (0 = off)")
    ap.add_argument("--resolve", default="0,1", help="face resolution off (0) and/or on (1) in each export")
    ap.add_argument("--jitters", default=",".join(f"{t}:{r}" for t, r in JITTERS),
                    help="sigma_t_metres:sigma_r_degrees pairs; 0:0 (true poses) must be first")
    ap.add_argument("--grid", metavar="T1,T2,..:R1,R2,..",
                    help="every (sigma_t metres, sigma_r degrees) pair of the two lists instead of --jitters; both "
                         "lists start with 0 (e.g. 0,0.005,0.01,0.02:0,0.05,0.1,0.2)")
    ap.add_argument("--jitter-seed", type=int, default=0, help="seed of traj perturb (default 0)")
    ap.add_argument("--resolve-behind", type=float, default=0.0,
                    help="the face resolution's resolve_behind in the exports with it (default 0, the mapper's)")
    a = ap.parse_args(argv)
    grid = None
    if a.grid:
        try:
            grid = tuple(_floats(part) for part in a.grid.split(":"))
        except ValueError:
            ap.error(f"--grid {a.grid}: expected T1,T2,..:R1,R2,.. (numbers)")
        if len(grid) != 2 or grid[0][0] != 0 or grid[1][0] != 0:
            ap.error(f"--grid {a.grid}: expected T1,T2,..:R1,R2,.., each list starting with 0 (the true poses)")
        jitters = tuple((t, r) for t in grid[0] for r in grid[1])
    else:
        jitters = tuple(tuple(float(v) for v in j.split(":")) for j in a.jitters.split(","))
    if jitters[0] != (0.0, 0.0):
        ap.error("--jitters must start with 0:0 (the true-pose map every loss is measured against)")
    exports = [(float(k), int(r)) for k in a.spill.split(",") for r in a.resolve.split(",")]
    a.work.mkdir(parents=True, exist_ok=True)

    def show(rows):
        for r in rows:
            print(" ".join(f"{k}={v}" for k, v in r.items()), flush=True)

    try:
        rows = run(a.work, [int(s) for s in a.seeds.split(",")], a.house, a.width, exports, jitters, a.jitter_seed, show,
                   a.resolve_behind, a.frames)
    except subprocess.CalledProcessError as e:
        sys.exit(f"error: {' '.join(map(str, e.cmd[2:]))} failed: {e.stderr.decode(errors='replace').strip()}")
    with open(a.work / "jitter.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    md = markdown(rows, jitters) if grid is None else grid_markdown(rows, *grid)
    (a.work / "jitter.md").write_text(md)
    if grid is not None:
        grid_figure(rows, *grid).savefig(a.work / "jitter.png", dpi=110)
    print(md)


if __name__ == "__main__":
    main()
