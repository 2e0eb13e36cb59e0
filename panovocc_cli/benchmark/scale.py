"""``make bench-scale``: the long-term memory at building scale, end to end, as a user runs the commands.

    python -m panovocc_cli.benchmark.scale work/bench-scale [--scene building|house] [--width 512]
                                           [--frames N] [--revise 1000] [--seed 0] [--segmenter SPEC]

Each stage is a ``panovocc`` command in its own process (start to files written): ``synth`` (the building,
or a house with ``--scene house``), ``render``, ``gt``, ``map --frame-times``, ``eval``, and ``revise`` of
a pose file that moves ``--revise`` frames (the tail of the run, as a late loop closure would: turned by
0.2 degrees and shifted by 1 cm). Finished stages are reused when their outputs exist (a rerun measures
``map`` and ``revise`` again, never the scene). It prints one table and writes it as ``scale.md``,
``scale.csv`` and ``scale.json`` in the work folder:

* frames; occupied, non-zero and allocated voxels; semantic rows;
* bytes per voxel in RAM: geometry per allocated voxel, semantics per row (with its share of the pages),
  all of the memory per occupied voxel (``VoxelMemory.nbytes``);
* peak RSS of ``map`` (the kernel's ``ru_maxrss`` of the process), its resident memory after the first frame
  (its start-up footprint) and the ratio of the peak above that to the memory held; the same above its
  resident memory once the frame pipeline is full (after the third frame: the reading, integrating and
  writing threads have each held a frame, a working set that depends on the image size, not on the map);
* the delta store: bytes per frame, files, and what an hour at 10 Hz would take at that rate;
* wall time per frame (from ``--frame-times``: checkpoints, reading and segmentation included), the
  median over frames 10-20 % of the run and over the last 10 %, and their ratio; the same for the
  process's CPU time per frame (all its threads), which other jobs on the machine disturb less;
* checkpoint cost: the median wall time of frames that checkpointed less that of the others;
* revising ``--revise`` frames (``panovocc revise``, whole process: wall and CPU time) against integrating
  the same frames in the run (the sum of their wall and CPU times); and the revisions alone, from the first
  frame read to the last record written, as ``revise`` prints them (what the same loop closure costs inside a
  run, which has the map loaded and exports it once at its end);
* IoU / mIoU of the map against the scene's mesh ground truth.

``--segmenter SPEC`` maps with that segmenter (``map --segmenter``; default: the simulated one, whose
perception costs a few ms a frame): e.g. ``clip:FOLDER`` to measure what a revision saves where perception
is a network's (a revision never runs the segmenter; with a randomly initialised network the timings are a
trained one's and the labels are noise).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import subprocess
import time
from pathlib import Path

import numpy as np

from . import panovocc_command

HOUR_FRAMES = 36_000  # an hour at 10 Hz
PIPELINE_FRAMES = 3  # frames after which map's reading, integrating and writing threads have each held one




def timed(cmd: list, log: Path) -> dict:
    """Run ``cmd`` (stdout and stderr to ``log``); its wall seconds and peak RSS (bytes). Raises on failure."""
    t0 = time.perf_counter()
    with open(log, "w") as f:
        p = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        tail = log.read_text(errors="replace")[-2000:]
        raise SystemExit(f"{' '.join(map(str, cmd))} failed (exit {code}):\n{tail}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_rss_bytes": int(usage.ru_maxrss) * 1024}


def early_late(n: int) -> tuple[slice, slice]:
    """The windows issue 21's and 22's per-frame goals compare, over a run of ``n`` frames: frames 10-20 %
    and the last 10 %, each at least one frame long."""
    a = int(0.1 * n)
    return slice(a, max(int(0.2 * n), a + 1)), slice(n - max(n // 10, 1), n)


def frame_costs(csv_path: Path) -> dict:
    """Per-frame wall times from a ``map --frame-times`` CSV: early (10-20 %) and late (last 10 %) medians,
    the checkpoint cost, the resident memory after the first frame and once the frame pipeline is full (after
    the third frame: frame k + 1 read and segmented and frame k - 1's record written while frame k is
    integrated, so each of the three threads has held a frame)."""
    rows = list(csv.DictReader(open(csv_path)))
    t = np.array([float(r["t_s"]) for r in rows])
    cpu = np.diff(np.array([float(r["cpu_s"]) for r in rows]), prepend=0.0)  # the first: from the loop's start
    ck = np.array([int(r["checkpoint"]) for r in rows], bool)
    rss = np.array([float(r["rss_mb"]) for r in rows])
    dt = np.diff(t, prepend=0.0)  # frame k's wall: from the end of frame k-1 (the first: from the loop's start)
    n = len(dt)
    sl_early, sl_late = early_late(n)
    early, late = dt[sl_early], dt[sl_late]
    # a checkpoint's commit runs on the writer thread: its cost lands on the frame after it
    after = np.zeros(n, bool)
    after[1:] = ck[:-1]
    return {"frames": n, "ms_early": 1e3 * float(np.median(early)), "ms_late": 1e3 * float(np.median(late)),
            "cpu_ms_early": 1e3 * float(np.median(cpu[sl_early])), "cpu_ms_late": 1e3 * float(np.median(cpu[sl_late])),
            "late_over_early": float(np.median(late) / np.median(early)),
            "checkpoint_ms": 1e3 * float(np.median(dt[ck | after]) - np.median(dt[~(ck | after)])) if ck.any() else None,
            "checkpoints": int(ck.sum()), "startup_rss_bytes": float(rss[0]) * 2 ** 20,
            "pipeline_rss_bytes": float(rss[:PIPELINE_FRAMES].max()) * 2 ** 20, "dt": dt, "cpu": cpu}


def memory_figures(map_dir: Path) -> dict:
    """What the map's memory holds (``Mapper.load``), its delta store on disk, and the occupied voxels."""
    from ..io.grid import read_grid
    from ..io.mapstore import DELTAS_DIR
    from ..mapping import Mapper

    g = read_grid(map_dir / "prediction.npz")
    occ = int(((g.labels > 0) & (g.labels < 255)).sum())
    mapper = Mapper.load(map_dir)
    try:
        m = mapper.memory
        b = m.nbytes()
        nonzero = len(m.nonzero()[0])
        frames = len(mapper)
    finally:
        mapper.close()
    files = [p for p in (map_dir / DELTAS_DIR).rglob("*") if p.is_file()]
    dbytes = sum(p.stat().st_size for p in files)
    held = int(sum(b.values()))
    return {"occupied_voxels": occ, "nonzero_voxels": nonzero, "allocated_voxels": int(m.allocated_voxels),
            "semantic_rows": int(m.n_rows), "memory_bytes": held, "memory_bytes_by_part": {k: int(v) for k, v in b.items()},
            "geometry_bytes_per_allocated_voxel": b["dense"] / max(m.allocated_voxels, 1),
            "semantic_bytes_per_row": (b["rows"] + b["pages"]) / m.n_rows if m.n_rows else None,
            "memory_bytes_per_occupied_voxel": held / occ if occ else None,
            "delta_store_bytes": dbytes, "delta_store_files": len(files),
            "delta_bytes_per_frame": dbytes / max(frames, 1), "frames_held": frames}


REVISIONS = re.compile(r"the revisions and their records ([0-9.]+) s, ([0-9.]+) s CPU")


def revisions_cost(text: str) -> tuple[float, float]:
    """The wall and CPU seconds of the revisions themselves (frames read, deltas computed and swapped, records
    written; no load, no export, no ``memory.npz``) from ``panovocc revise``'s output: what a loop closure
    that moves the same frames costs inside a run (``map --poses slam`` revises between frames)."""
    m = REVISIONS.search(text)
    if m is None:
        raise SystemExit("panovocc revise printed no figures for its revisions (expected 'the revisions and their "
                         "records W s, C s CPU')")
    return float(m.group(1)), float(m.group(2))


def moved_tail(poses: np.ndarray, k: int) -> np.ndarray:
    """The poses with the last ``k`` turned by 0.2 degrees about the vertical through the first of them and
    shifted by 1 cm (what a late loop closure does to the tail of a trajectory)."""
    out = poses.copy()
    k = min(k, len(poses))
    if k == 0:
        return out
    a = np.deg2rad(0.2)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    c = poses[len(poses) - k, :3, 3]
    for T in out[len(poses) - k:]:
        T[:3, :3] = R @ T[:3, :3]
        T[:3, 3] = R @ (T[:3, 3] - c) + c + np.array([0.01, 0.0, 0.0])
    return out


def run(work: Path, scene: str = "building", width: int = 512, frames: int | None = None, revise: int = 1000,
        seed: int = 0, segmenter: str | None = None) -> dict:
    from ..io.poses import read_poses, write_poses

    work.mkdir(parents=True, exist_ok=True)
    logs = work / "logs"
    logs.mkdir(exist_ok=True)
    sc, seq, mp, gt = work / "scene", work / "seq", work / "map", work / "gt.npz"
    if not (sc / "traj.txt").is_file():
        args = ["synth", str(sc), f"--{scene}", "--seed", str(seed), "--overwrite"]
        if frames:
            args += ["--frames", str(frames)]
        timed(panovocc_command(*args), logs / "synth.log")
    if not (seq / "meta.json").is_file():
        timed(panovocc_command("render", str(sc), str(seq), "--width", str(width), "--seed", str(seed), "--overwrite"),
              logs / "render.log")
    if not gt.is_file():
        timed(panovocc_command("gt", str(sc), str(gt), "--overwrite"), logs / "gt.log")
    times = work / "frames.csv"
    seg = () if segmenter is None else ("--segmenter", segmenter)
    mrun = timed(panovocc_command("map", str(seq), str(mp), "--frame-times", str(times), "--overwrite", *seg),
                 logs / "map.log")
    fc = frame_costs(times)
    mem = memory_figures(mp)
    ev = json.loads(subprocess.run(panovocc_command("eval", str(mp / "prediction.npz"), str(gt), "--classes", "eval12",
                                             "--json"), capture_output=True, text=True, check=True).stdout)
    poses = read_poses(mp / "poses.txt")
    k = min(revise, len(poses))
    write_poses(work / "poses_revised.txt", moved_tail(poses, k))
    rrun = timed(panovocc_command("revise", str(mp), str(work / "poses_revised.txt")), logs / "revise.log")
    rev_s, rev_cpu_s = revisions_cost((logs / "revise.log").read_text(errors="replace"))
    integrate_s = float(fc["dt"][len(poses) - k:].sum())
    integrate_cpu_s = float(fc["cpu"][len(poses) - k:].sum())
    peak = mrun["peak_rss_bytes"]
    out = {"scene": scene, "width": width, "seed": seed, "segmenter": segmenter or "simulated", "frames": fc["frames"],
           **mem,
           "map_wall_s": mrun["wall_s"], "peak_rss_bytes": peak, "startup_rss_bytes": fc["startup_rss_bytes"],
           "peak_above_startup_over_memory": (peak - fc["startup_rss_bytes"]) / mem["memory_bytes"],
           "pipeline_rss_bytes": fc["pipeline_rss_bytes"],
           "peak_above_pipeline_over_memory": (peak - fc["pipeline_rss_bytes"]) / mem["memory_bytes"],
           "ms_per_frame_early": fc["ms_early"], "ms_per_frame_late": fc["ms_late"],
           "late_over_early": fc["late_over_early"], "cpu_ms_per_frame_early": fc["cpu_ms_early"],
           "cpu_ms_per_frame_late": fc["cpu_ms_late"], "checkpoints": fc["checkpoints"],
           "checkpoint_ms": fc["checkpoint_ms"], "revised_frames": k, "revise_wall_s": rrun["wall_s"],
           "integrate_same_frames_s": integrate_s, "revise_over_integrate": rrun["wall_s"] / integrate_s,
           "revise_cpu_s": rrun["cpu_s"], "integrate_same_frames_cpu_s": integrate_cpu_s,
           "revise_over_integrate_cpu": rrun["cpu_s"] / integrate_cpu_s,
           "revisions_wall_s": rev_s, "revisions_cpu_s": rev_cpu_s,
           "revisions_over_integrate": rev_s / integrate_s, "revisions_over_integrate_cpu": rev_cpu_s / integrate_cpu_s,
           "hour_at_10hz_bytes": mem["delta_bytes_per_frame"] * HOUR_FRAMES,
           "iou": ev.get("iou"), "miou": ev.get("miou"), "load": os.getloadavg()}
    write_tables(work, out)
    return out


def table_rows(r: dict) -> list:
    mb = 1e6
    sem = r["semantic_bytes_per_row"]
    ck = r["checkpoint_ms"]
    return [
        ("scene", f"{r['scene']} (seed {r['seed']}), {r['width']}x{r['width'] // 2}"
                  + ("" if r["segmenter"] == "simulated" else f", segmenter {r['segmenter']}")),
        ("frames", f"{r['frames']:,}"),
        ("occupied / non-zero / allocated voxels", f"{r['occupied_voxels']:,} / {r['nonzero_voxels']:,} / "
                                                     f"{r['allocated_voxels']:,}"),
        ("semantic rows (voxels with evidence)", f"{r['semantic_rows']:,}"),
        ("RAM: geometry bytes per allocated voxel", f"{r['geometry_bytes_per_allocated_voxel']:.1f}"),
        ("RAM: semantic bytes per row (pages included)", "-" if sem is None else f"{sem:.1f}"),
        ("RAM: memory held (bytes per occupied voxel)", f"{r['memory_bytes'] / mb:.1f} MB "
                                                        f"({r['memory_bytes_per_occupied_voxel']:.0f})"),
        ("peak RSS of map (after the first frame)", f"{r['peak_rss_bytes'] / mb:.0f} MB "
                                                    f"({r['startup_rss_bytes'] / mb:.0f} MB)"),
        ("peak above start-up / memory held", f"{r['peak_above_startup_over_memory']:.2f}"),
        ("the same above the full frame pipeline (after the third frame)",
         f"{r['peak_above_pipeline_over_memory']:.2f} ({r['pipeline_rss_bytes'] / mb:.0f} MB)"),
        ("delta store: MB per frame, files", f"{r['delta_bytes_per_frame'] / mb:.3f}, {r['delta_store_files']}"),
        ("an hour at 10 Hz at that rate", f"{r['hour_at_10hz_bytes'] / 1e9:.1f} GB"),
        ("ms per frame, frames 10-20 % / last 10 %", f"{r['ms_per_frame_early']:.1f} / {r['ms_per_frame_late']:.1f}"
                                                      f" ({r['late_over_early']:.2f}x)"),
        ("CPU ms per frame (all threads), same frames", f"{r['cpu_ms_per_frame_early']:.1f} / "
                                                         f"{r['cpu_ms_per_frame_late']:.1f} "
                                                         f"({r['cpu_ms_per_frame_late'] / r['cpu_ms_per_frame_early']:.2f}x)"),
        ("checkpoint cost (every 25 frames)", "-" if ck is None else f"{ck:+.1f} ms ({r['checkpoints']} checkpoints)"),
        (f"revise {r['revised_frames']:,} frames / integrate them", f"{r['revise_wall_s']:.1f} s / "
                                                                  f"{r['integrate_same_frames_s']:.1f} s "
                                                                  f"({r['revise_over_integrate']:.2f}x)"),
        ("the same in CPU time (all threads)", f"{r['revise_cpu_s']:.1f} s / {r['integrate_same_frames_cpu_s']:.1f} s "
                                               f"({r['revise_over_integrate_cpu']:.2f}x)"),
        ("the revisions alone, as in a run (no load, export or memory.npz): wall / CPU",
         f"{r['revisions_wall_s']:.1f} s ({r['revisions_over_integrate']:.2f}x) / {r['revisions_cpu_s']:.1f} s "
         f"({r['revisions_over_integrate_cpu']:.2f}x)"),
        ("map wall time", f"{r['map_wall_s']:.0f} s"),
        ("IoU / mIoU (eval12, mesh ground truth)", f"{r['iou']:.2f} / {r['miou']:.2f}"),
    ]


def write_tables(work: Path, r: dict) -> None:
    from ..io.atomic import write_text

    rows = table_rows(r)
    md = "| figure | value |\n|---|---|\n" + "".join(f"| {a} | {b} |\n" for a, b in rows)
    write_text(work / "scale.md", md)
    write_text(work / "scale.csv", "figure,value\n" + "".join(f'"{a}","{b}"\n' for a, b in rows))
    write_text(work / "scale.json", json.dumps(r, indent=2, default=float) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--scene", choices=("building", "house"), default="building")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--frames", type=int, default=None, help="trajectory poses (default: the scene's)")
    ap.add_argument("--revise", type=int, default=1000, help="frames moved and revised")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--segmenter", default=None, help="map --segmenter SPEC (default: the simulated segmenter)")
    a = ap.parse_args(argv)
    r = run(a.work, a.scene, a.width, a.frames, a.revise, a.seed, a.segmenter)
    for k, v in table_rows(r):
        print(f"{k:48s} {v}")
    print(f"tables: {a.work / 'scale.md'}, scale.csv, scale.json (load average {r['load'][0]:.1f})")


if __name__ == "__main__":
    main()
