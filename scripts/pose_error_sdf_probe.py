"""A fused signed distance as the judge of a surface smeared over a voxel face (issue 22, docs/mapping.md "Pose
error": tried and dropped in stop 58). Not toolkit code: a probe on the jitter bench's maps.

For each occupied voxel of an export and its six face neighbours, every frame's signed distance to the surface it
measured (TSDF-like, truncated at 3 voxel edges in front, nothing beyond 3 behind) is averaged over the frames:

* ``projective``: the depth at the pixel the voxel's centre projects to, minus the centre's range (Open3D's TSDF);
* ``plane`` (the default): the distance of the centre from the plane through that pixel's point and its normal
  (central differences of the back-projected depth; pixels at a depth edge, over 5 % of the range, give nothing).

Rule: an occupied voxel v loses to an occupied face neighbour u along axis k when their mean distances have
opposite signs (the fused surface lies between their centres), |d_v| > STRICT |d_u| (it lies nearer u), and the
distance field's gradient in both is along k (|g_k| / |g| >= AXIS, the same sign in both): one surface seen from
one side, smeared over the face they share. It is applied on top of the map's export with this panovocc's defaults
and with ``--spill 0.3 --resolve``, and scored like ``panovocc eval`` (FreeOcc IoU).

    python scripts/pose_error_sdf_probe.py W home0,home1 [--field plane|projective]

W: a folder of ``python -m panovocc_cli.benchmark.jitter W --seeds 0,1 --jitters 0:0,0.01:0.1`` (its maps carry
channel P). Prints, per scene, depth, export and rule, the IoU at true poses and at 10 mm / 0.1° and the loss.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from panovocc_cli.evaluation.metrics import count_pair  # noqa: E402
from panovocc_cli.geometry.erp import project_to_pixel, ray_directions  # noqa: E402
from panovocc_cli.geometry.lattice import index_to_center  # noqa: E402
from panovocc_cli.grid import EMPTY, UNKNOWN, Grid  # noqa: E402
from panovocc_cli.io.grid import read_grid  # noqa: E402
from panovocc_cli.io.poses import read_poses  # noqa: E402
from panovocc_cli.io.sequence import Sequence  # noqa: E402
from panovocc_cli.mapping.params import OccupancyParams  # noqa: E402
from panovocc_cli.mapquery import open_map  # noqa: E402

FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
TRUNC = 3.0  # voxel edges
RULES = [(axis, strict) for axis in (0.8, 0.9, 0.95) for strict in (1.0, 1.25)]


def _plane_field(depth: np.ndarray):
    """Back-projected points, unit normals towards the camera and the pixels that have both (no depth edge)."""
    H, W = depth.shape
    P = ray_directions(W, H) * depth[..., None]
    dc = np.roll(P, -1, 1) - np.roll(P, 1, 1)
    dr = np.zeros_like(P)
    dr[1:-1] = P[2:] - P[:-2]
    n = np.cross(dc, dr)
    nn = np.linalg.norm(n, axis=-1)
    n = n / np.maximum(nn, 1e-12)[..., None]
    n *= -np.sign(np.sum(n * P, -1))[..., None]
    ok = (depth > 0) & (nn > 0)
    ok[0] = ok[-1] = False
    up, down = np.vstack([depth[1:], depth[-1:]]), np.vstack([depth[:1], depth[:-1]])
    for a, b in ((np.roll(depth, -1, 1), np.roll(depth, 1, 1)), (up, down)):
        ok &= (a > 0) & (b > 0) & (np.abs(a - depth) < 0.05 * depth) & (np.abs(b - depth) < 0.05 * depth)
    return P, n, ok


def fuse(seq: Sequence, poses: np.ndarray, centres: np.ndarray, h: float, field: str, max_range: float = 12.0):
    """Mean truncated signed distance (metres, NaN where no frame gave one) at each centre (n, 3)."""
    total, count = np.zeros(len(centres)), np.zeros(len(centres))
    for i in range(len(seq)):
        D = seq.depth(i).astype(np.float64)
        T = poses[i]
        pc = (centres - T[:3, 3]) @ T[:3, :3]
        row, col, r = project_to_pixel(pc, D.shape[1], D.shape[0])
        ro = D[row, col]
        if field == "projective":
            d = ro - r
            ok = (ro > 0) & (r < max_range) & (d > -TRUNC * h)
        else:
            P, n, valid = _plane_field(D)
            d = np.einsum("ij,ij->i", n[row, col], pc - P[row, col])
            ok = valid[row, col] & (r < max_range) & (d > -TRUNC * h) & (ro - r > -2 * TRUNC * h)
        total[ok] += np.minimum(d[ok], TRUNC * h)
        count[ok] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def resolved(pred: Grid, seq: Sequence, poses: np.ndarray, field: str) -> dict:
    """The export with each rule of :data:`RULES` applied: {(axis, strict): Grid}."""
    h, L = pred.voxel_size, pred.labels
    occ = (L != EMPTY) & (L != UNKNOWN)
    ijk = np.argwhere(occ)
    pad = np.pad(occ, 1)
    near = pad.copy()
    for f in FACES:
        near |= np.roll(pad, tuple(f), axis=(0, 1, 2))
    cand = np.argwhere(near)
    S = np.full(pad.shape, np.nan)
    S[tuple(cand.T)] = fuse(seq, poses, index_to_center(cand - 1 + pred.index0, h), h, field)
    G = np.full(pad.shape + (3,), np.nan)
    inner = cand[np.all((cand > 0) & (cand < np.array(pad.shape) - 1), axis=1)]
    s0 = S[tuple(inner.T)]
    for k in range(3):
        e = np.eye(3, dtype=int)[k]
        a, b = S[tuple((inner + e).T)], S[tuple((inner - e).T)]
        G[tuple(inner.T) + (k,)] = np.where(np.isfinite(a) & np.isfinite(b), (a - b) / 2,
                                            np.where(np.isfinite(a), a - s0, np.where(np.isfinite(b), s0 - b, np.nan)))
    GN = np.linalg.norm(G, axis=-1)
    P = ijk + 1
    dv, gv, gnv = S[tuple(P.T)], G[tuple(P.T)], GN[tuple(P.T)]
    out = {}
    for axis, strict in RULES:
        keep = np.ones(len(P), bool)
        for j, f in enumerate(FACES):
            k = j // 2
            q = P + f
            du, gu, gnu = S[tuple(q.T)], G[tuple(q.T)], GN[tuple(q.T)]
            with np.errstate(invalid="ignore", divide="ignore"):
                along = (np.abs(gv[:, k]) / gnv >= axis) & (np.abs(gu[:, k]) / gnu >= axis)
            keep &= ~(pad[tuple(q.T)] & np.isfinite(du) & np.isfinite(dv) & (np.sign(du) != np.sign(dv))
                      & (np.abs(dv) > strict * np.abs(du)) & along & (np.sign(gv[:, k]) == np.sign(gu[:, k])))
        lab = L.copy()
        lab[tuple(ijk[~keep].T)] = UNKNOWN
        out[axis, strict] = Grid(lab, pred.origin, pred.voxel_size, pred.class_names)
    return out


def export(map_dir: Path, spill: float, resolve: bool) -> Grid:
    m = open_map(map_dir)
    try:
        m.config = dataclasses.replace(m.config, occupancy=dataclasses.replace(OccupancyParams(), spill=spill,
                                                                                resolve=resolve))
        return m.export().grid
    finally:
        m.close()


def iou(grid: Grid, gt: Grid) -> float:
    c = count_pair(grid, gt)["freeocc"]
    return 100.0 * c.tp / max(c.tp + c.fp + c.fn, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("scenes")
    ap.add_argument("--field", choices=("plane", "projective"), default="plane")
    a = ap.parse_args()
    w = a.work
    for scene in a.scenes.split(","):
        gt = read_grid(w / f"{scene}.gt.npz")
        for depth in ("clean", "realistic"):
            seq = Sequence(w / f"{scene}.{depth}")
            res = {}
            for tag, pf in (("true", None), ("10mm", w / f"{scene}.t10mm.r0.1deg.s0.poses.txt")):
                poses = read_poses(pf) if pf else seq.poses
                md = w / f"{scene}.{depth}.t{'10' if pf else '0'}mm.r{'0.1' if pf else '0'}deg.map"
                for spill, resolve in ((0.0, False), (0.3, True)):
                    g = export(md, spill, resolve)
                    res[tag, spill, resolve, None] = iou(g, gt)
                    for rule, gg in resolved(g, seq, poses, a.field).items():
                        res[tag, spill, resolve, rule] = iou(gg, gt)
            for spill, resolve in ((0.0, False), (0.3, True)):
                for rule in [None] + RULES:
                    t, j = res["true", spill, resolve, rule], res["10mm", spill, resolve, rule]
                    name = "none" if rule is None else f"axis {rule[0]}, strict {rule[1]}"
                    print(f"{scene} {depth:9s} spill {spill} resolve {int(resolve)} {name:24s} true {t:6.2f} "
                          f"10 mm {j:6.2f} loss {t - j:5.2f}", flush=True)


if __name__ == "__main__":
    main()
