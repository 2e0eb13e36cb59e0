"""Probe (issue 22, docs/mapping.md "Face resolution"): where the false positives left by pose jitter lie, and
what a pooled-plane test on top of the export would do to them. Not a rule of the mapper: a measurement.

    python scripts/pose_error_plane_probe.py WORK SCENE [--cos 0.9] [--margin 0.05] [--gap 2] [--spread within]

WORK is a ``make bench-jitter`` folder (``python -m panovocc_cli.benchmark.jitter WORK --seeds K --jitters
0:0,0.01:0.1``) holding ``SCENE.gt.npz`` and the maps ``SCENE.{clean,realistic}.t{0,10}mm.r{0,0.1}deg.map``.
Each map is exported with ``--spill 0.3 --resolve``; then

* the false positives at 10 mm / 0.1° are broken down: how many hold a single frame's hits, and how many have
  a mean measured normal (channel P) with a second component above 0.3 (rotated surfaces, or corner and edge
  samples whose kernels are ray-aligned), out of the face resolution's reach (it needs |n_i| >= 0.9);
* the pooled-plane test: for each occupied voxel v with measurements, the plane of the measurements of v and of
  its 26 neighbours that the base rule occupies and whose mean normal is within ``--cos`` of v's (weighted by
  their frames with a measurement; centroid and normal from channel P). v is dropped when that plane misses
  v's box by more than ``--margin`` voxel edges (|distance of v's centre| > (|n|_1)/2 + margin) while v's own
  mean position lies within ``--gap`` spreads of the plane (``--spread within``: the frames' scatter inside
  each voxel; ``pooled``: the scatter of every pooled position, which also counts the distance between two
  parallel surfaces). Prints the IoU (FreeOcc, ``panovocc eval``'s) before and after, at true poses and at
  10 mm / 0.1°, on clean and realistic depth.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools

import numpy as np

from panovocc_cli.geometry.lattice import pack_keys
from panovocc_cli.grid import UNKNOWN
from panovocc_cli.io.grid import read_grid
from panovocc_cli.mapping.export import _offsets, classify
from panovocc_cli.mapping.params import OccupancyParams
from panovocc_cli.mapquery import open_map

NEIGHBOURS = [np.array(d) for d in itertools.product((-1, 0, 1), repeat=3) if any(d)]


def occupied(grid) -> np.ndarray:
    """World lattice indices (n, 3) of a grid's occupied voxels."""
    return np.argwhere((grid.labels > 0) & (grid.labels != UNKNOWN)) + grid.index0


def counts(pred: set, gt: set, known: set) -> tuple:
    tp = len(pred & gt)
    fp = sum(1 for p in pred if p not in gt and p in known)
    fn = len(gt - pred)
    return 100.0 * tp / max(tp + fp + fn, 1), tp, fp, fn


def _unit(n):
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def plane_drop(vox, mem, origin, p, cos_t, margin, gap, spread_mode):
    """Whether each occupied voxel ``vox`` (world indices) fails the pooled-plane test."""
    mv, offv, nrmv, varv = _offsets(mem.gather(pack_keys(vox - origin), ["P"])["P"])
    nv = _unit(nrmv)
    W, S, Nsum = mv.copy(), mv[:, None] * offv, mv[:, None] * nrmv
    V = mv[:, None] * (varv if spread_mode == "within" else varv + offv * offv)
    for d in NEIGHBOURS:
        c = mem.gather(pack_keys(vox + d - origin), ["A", "N", "F", "O", "P"])
        mu, offu, nrmu, varu = _offsets(c["P"])
        w = np.where(classify(c["A"], c["N"], c["F"], c["O"], p)[0] & (mu > 0)
                     & ((_unit(nrmu) * nv).sum(1) >= cos_t), mu, 0.0)
        pos = d + offu
        W += w
        S += w[:, None] * pos
        Nsum += w[:, None] * nrmu
        V += w[:, None] * (varu if spread_mode == "within" else varu + pos * pos)
    cen = S / np.maximum(W, 1e-12)[:, None]
    n = _unit(Nsum)
    var = V / np.maximum(W, 1e-12)[:, None]
    if spread_mode != "within":
        var = np.maximum(var - cen * cen, 0.0)
    dist = -(n * cen).sum(1)  # v's centre from the plane, voxel edges
    e_v = (n * (offv - cen)).sum(1)  # v's own mean position from the plane
    spread = np.sqrt((n * n * var).sum(1))
    return (mv > 0) & (W > mv) & (np.abs(dist) > 0.5 * np.abs(n).sum(1) + margin) & (np.abs(e_v) <= gap * spread)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work")
    ap.add_argument("scene")
    ap.add_argument("--cos", type=float, default=0.9)
    ap.add_argument("--margin", type=float, default=0.05)
    ap.add_argument("--gap", type=float, default=2.0)
    ap.add_argument("--spread", choices=("within", "pooled"), default="within")
    a = ap.parse_args(argv)
    gt = read_grid(f"{a.work}/{a.scene}.gt.npz")
    gt_occ = set(map(tuple, occupied(gt)))
    known = set(map(tuple, np.argwhere(gt.labels != UNKNOWN) + gt.index0))
    p = dataclasses.replace(OccupancyParams(), spill=0.3, resolve=True)
    for depth in ("clean", "realistic"):
        line = []
        for tag in ("t0mm.r0deg", "t10mm.r0.1deg"):
            m = open_map(f"{a.work}/{a.scene}.{depth}.{tag}.map")
            try:
                m.config = dataclasses.replace(m.config, occupancy=p)
                vox = occupied(m.export().grid)
                origin = m.config.origin_index()
                before = counts(set(map(tuple, vox)), gt_occ, known)
                if tag != "t0mm.r0deg":
                    fp = np.array([v for v in map(tuple, vox) if v not in gt_occ and v in known]).reshape(-1, 3)
                    c = m.memory.gather(pack_keys(fp - origin), ["N", "P"])
                    nrm = np.sort(np.abs(_unit(_offsets(c["P"])[2])), 1)
                    print(f"{a.scene} {depth} 10 mm / 0.1°: {len(fp)} false positives, {np.mean(c['N'][:, 0] == 1):.0%} "
                          f"with one frame's hits, {np.mean(nrm[:, 1] > 0.3):.0%} with a mean normal off the axes "
                          f"(second component > 0.3)")
                drop = plane_drop(vox, m.memory, origin, p, a.cos, a.margin, a.gap, a.spread)
                after = counts(set(map(tuple, vox[~drop])), gt_occ, known)
            finally:
                m.close()
            line.append(f"{'true' if tag == 't0mm.r0deg' else '10 mm'} {before[0]:.2f} -> {after[0]:.2f} "
                        f"({int(drop.sum())} dropped; fp {before[2]} -> {after[2]}, fn {before[3]} -> {after[3]})")
        print(f"{a.scene} {depth}: " + " | ".join(line), flush=True)


if __name__ == "__main__":
    main()
