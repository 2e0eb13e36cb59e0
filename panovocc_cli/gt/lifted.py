"""Ground truth lifted from a capture: occupancy from the whole sequence's depth, classes from sparse
annotated panoramas (the Pan-Holo360D protocol; docs/gt.md has the rules' measurements).

On the global lattice of voxel size h (voxel n covers [n h, (n + 1) h)):

* **Occupancy (minimum support).** Every valid depth pixel of every frame is lifted to the world frame
  (``T_world_cam`` · ray · radial depth). A voxel is *occupied* when points of at least ``min_frames``
  different frames fall in it, at least ``min_points`` points in all, and the frames that hit it are at
  least ``min_hit_ratio`` of the frames that hit it or saw through it (``hit / (hit + pass)``): one
  frame's flying pixels or outliers never make a voxel on their own, and noise that lands in front of a
  surface, in space most frames see through, is dropped.
* **Observed free space.** Each frame carves the voxels its rays cross from the camera centre up to (not
  including) the voxel of the measured point, one ray every ``stride = max(1, W // 512)`` pixels on
  both axes (at 512 columns neighbouring rays are 0.70 degrees apart: 6 cm at 5 m, under the 8 cm voxel).
  A voxel that is not occupied and was crossed by at least one ray is *empty* (0).
* **Never observed** (no ray crossed it, no support): 255, ignored in scoring. A voxel hit by points
  but below the support and never crossed is also 255: nothing says what it is.
* **Labels.** Each annotated frame lifts its label image through its own depth and pose; per voxel the
  frame casts one vote, split over the classes of its pixels in that voxel (fractions summing to 1), so
  a frame close to a surface does not outvote several far ones by pixel count. An occupied voxel takes
  the class with the largest summed vote (ties: the lower class id). Unlabelled pixels (id 0) vote for
  nothing; votes falling in voxels that are not occupied are dropped.
* **Bounded transfer.** An occupied voxel no annotation reached takes the label of the nearest labelled
  occupied voxel within ``label_radius`` metres (centre to centre; among equally near ones the KD-tree's
  fixed order decides, the same on every run), else 254 (occupied, no class).

:class:`LiftAccumulator` holds the counts of a fixed dense box and takes frames from memory (no file
I/O here); :func:`depth_bounds` gives the box of a frame. ``run_lifted_gt`` (the reading and writing)
lives in :mod:`panovocc_cli.gt.run`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import PanovoccError
from ..geometry.erp import cam_point, trig_tables
from ..geometry.lattice import index_to_center
from ..grid import OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

BYTES_PER_VOXEL = 20  # hit frames, hit points, pass frames (int32 each) and two int32 frame stamps
CARVE_COLUMNS = 512  # a frame carves one ray every max(1, W // CARVE_COLUMNS) pixels on both axes


def carve_stride(width: int) -> int:
    """Pixel stride of the free-space rays of a ``width``-column ERP frame: ``max(1, width // 512)``."""
    return max(1, int(width) // CARVE_COLUMNS)


@nb.njit(cache=True)
def _bounds_kernel(depth, T, max_range):
    H, W = depth.shape
    sphi, cphi, sth, cth = trig_tables(H, W)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    n = 0
    for v in range(H):
        for u in range(W):
            r = depth[v, u]
            if not (r > 0.0) or (max_range > 0.0 and r > max_range) or not np.isfinite(r):
                continue
            x, y, z = cam_point(r, sphi[v], cphi[v], sth[u], cth[u])
            for a in range(3):
                w = T[a, 0] * x + T[a, 1] * y + T[a, 2] * z + T[a, 3]
                lo[a] = min(lo[a], w)
                hi[a] = max(hi[a], w)
            n += 1
    return lo, hi, n


def depth_bounds(depth: np.ndarray, T_world_cam: np.ndarray, max_range: float = 0.0):
    """World box of a frame's valid depth points and its camera centre.

    Parameters
    ----------
    depth : (H, W) float, metres, radial, 0 = invalid
    T_world_cam : (4, 4) float64
    max_range : metres; points farther are ignored (0: keep all)

    Returns
    -------
    lo, hi : (3,) float64 metres, world frame (the camera centre included)
    """
    T = np.ascontiguousarray(T_world_cam, dtype=np.float64)
    lo, hi, _ = _bounds_kernel(np.ascontiguousarray(depth, dtype=np.float32), T, float(max_range))
    c = T[:3, 3]
    return np.minimum(lo, c), np.maximum(hi, c)


@nb.njit(cache=True, inline="always")
def _lin(wx, wy, wz, h, i0, shape):
    """Linear index into the box of the voxel holding world point (wx, wy, wz); -1 outside."""
    ix = int(np.floor(wx / h)) - i0[0]
    iy = int(np.floor(wy / h)) - i0[1]
    iz = int(np.floor(wz / h)) - i0[2]
    if ix < 0 or iy < 0 or iz < 0 or ix >= shape[0] or iy >= shape[1] or iz >= shape[2]:
        return -1
    return (ix * shape[1] + iy) * shape[2] + iz


@nb.njit(cache=True)
def _frame_kernel(depth, T, h, i0, shape, f, stride, max_range, hit_frames, hit_points, hit_stamp,
                  pass_frames, pass_stamp, pix_lin):
    """Add one frame's support and carve its free space; ``pix_lin`` (H, W) int64 receives each pixel's voxel."""
    H, W = depth.shape
    sphi, cphi, sth, cth = trig_tables(H, W)
    ox, oy, oz = T[0, 3] / h, T[1, 3] / h, T[2, 3] / h
    for v in range(H):
        for u in range(W):
            pix_lin[v, u] = -1
            r = depth[v, u]
            if not (r > 0.0) or (max_range > 0.0 and r > max_range) or not np.isfinite(r):
                continue
            x, y, z = cam_point(r, sphi[v], cphi[v], sth[u], cth[u])
            wx = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
            wy = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
            wz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
            k = _lin(wx, wy, wz, h, i0, shape)
            pix_lin[v, u] = k
            if k >= 0:
                hit_points[k] += 1
                if hit_stamp[k] != f:
                    hit_stamp[k] = f
                    hit_frames[k] += 1
            if v % stride != 0 or u % stride != 0:
                continue
            # Amanatides-Woo walk in voxel units from the camera centre to the point's voxel (excluded)
            px, py, pz = wx / h, wy / h, wz / h
            cx, cy, cz = int(np.floor(ox)), int(np.floor(oy)), int(np.floor(oz))
            ex, ey, ez = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
            n = abs(ex - cx) + abs(ey - cy) + abs(ez - cz)
            dx, dy, dz = px - ox, py - oy, pz - oz
            sx = 1 if dx > 0 else -1
            sy = 1 if dy > 0 else -1
            sz = 1 if dz > 0 else -1
            tx = ((cx + (1 if dx > 0 else 0)) - ox) / dx if dx != 0 else np.inf
            ty = ((cy + (1 if dy > 0 else 0)) - oy) / dy if dy != 0 else np.inf
            tz = ((cz + (1 if dz > 0 else 0)) - oz) / dz if dz != 0 else np.inf
            ddx = abs(1.0 / dx) if dx != 0 else np.inf
            ddy = abs(1.0 / dy) if dy != 0 else np.inf
            ddz = abs(1.0 / dz) if dz != 0 else np.inf
            for _ in range(n):
                if cx == ex and cy == ey and cz == ez:
                    break
                lx, ly, lz = cx - i0[0], cy - i0[1], cz - i0[2]
                if 0 <= lx < shape[0] and 0 <= ly < shape[1] and 0 <= lz < shape[2]:
                    q = (lx * shape[1] + ly) * shape[2] + lz
                    if pass_stamp[q] != f:
                        pass_stamp[q] = f
                        pass_frames[q] += 1
                if tx <= ty and tx <= tz:
                    cx += sx
                    tx += ddx
                elif ty <= tz:
                    cy += sy
                    ty += ddy
                else:
                    cz += sz
                    tz += ddz


def parse_annotated(spec: str, frames: int) -> list[int]:
    """Frame numbers of an ``--annotated`` spec: ``every:K``, ``all``, ``none`` or ``I,J,...``.

    Raises
    ------
    PanovoccError naming ``--annotated`` on a malformed spec or a frame outside ``0 .. frames - 1``.
    """
    s = str(spec).strip().lower()
    if s == "all":
        return list(range(frames))
    if s == "none":
        return []
    if s.startswith("every:"):
        try:
            k = int(s[6:])
        except ValueError:
            k = 0
        if k < 1:
            raise PanovoccError(f"--annotated: {spec!r}: expected every:K with a whole K >= 1")
        return list(range(0, frames, k))
    try:
        ids = sorted({int(p) for p in s.split(",") if p.strip()})
    except ValueError:
        raise PanovoccError(f"--annotated: {spec!r}: expected every:K, all, none or a comma list of frame numbers") \
            from None
    bad = [i for i in ids if not 0 <= i < frames]
    if bad or not ids:
        raise PanovoccError(f"--annotated: frame {bad[0] if bad else '(none)'} is not one of the sequence's "
                            f"frames 0..{frames - 1}")
    return ids


class LiftAccumulator:
    """Counts of the lifting protocol on a fixed dense box of the global lattice (module docstring).

    Parameters
    ----------
    index0 : (3,) int, lattice index of the box's voxel [0, 0, 0]
    shape : (3,) int, voxels per axis
    voxel_size : h, metres
    n_classes : number of label ids of the annotations (ids 0 .. n_classes - 1; 0 = unlabelled)
    max_range : metres, depth beyond it is ignored (0: keep all)
    """

    def __init__(self, index0, shape, voxel_size: float, n_classes: int, max_range: float = 0.0):
        self.index0 = np.asarray(index0, dtype=np.int64).reshape(3)
        self.shape = tuple(int(s) for s in shape)
        self.h = float(voxel_size)
        self.n_classes = int(n_classes)
        self.max_range = float(max_range)
        n = int(np.prod(self.shape))
        self.hit_frames = np.zeros(n, np.int32)
        self.hit_points = np.zeros(n, np.int32)
        self.pass_frames = np.zeros(n, np.int32)
        self._hit_stamp = np.full(n, -1, np.int32)
        self._pass_stamp = np.full(n, -1, np.int32)
        self._votes: list[tuple[np.ndarray, np.ndarray]] = []
        self.frames = 0
        self.annotated = 0
        self.stats: dict[str, int] = {}

    def add_frame(self, depth: np.ndarray, T_world_cam: np.ndarray, labels: np.ndarray | None = None) -> None:
        """Add one frame.

        Parameters
        ----------
        depth : (H, W) float, metres, radial, 0 = invalid (ERP, W = 2 H)
        T_world_cam : (4, 4) float64
        labels : (H, W) int class ids (0 = unlabelled) of an annotated frame, or None
        """
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        H, W = depth.shape
        pix = np.empty((H, W), np.int64)
        _frame_kernel(depth, np.ascontiguousarray(T_world_cam, dtype=np.float64), self.h, self.index0,
                      np.asarray(self.shape, np.int64), np.int32(self.frames), carve_stride(W), self.max_range,
                      self.hit_frames, self.hit_points, self._hit_stamp, self.pass_frames, self._pass_stamp, pix)
        self.frames += 1
        if labels is None:
            return
        lab = np.asarray(labels)
        if lab.shape != depth.shape:
            raise PanovoccError(f"labels {lab.shape} and depth {depth.shape} differ in size")
        ok = (pix >= 0) & (lab > 0)
        C = self.n_classes
        key = pix[ok] * C + lab[ok].astype(np.int64)
        uk, cnt = np.unique(key, return_counts=True)
        vox = uk // C
        _, inv = np.unique(vox, return_inverse=True)
        tot = np.bincount(inv, weights=cnt)
        self._votes.append((uk, cnt / tot[inv]))
        self.annotated += 1

    def occupied(self, min_frames: int, min_points: int, min_hit_ratio: float = 0.0) -> np.ndarray:
        """(n,) bool over the box: the minimum-support rule (module docstring)."""
        hf = self.hit_frames
        return (hf >= min_frames) & (self.hit_points >= min_points) & (hf >= min_hit_ratio * (hf + self.pass_frames))

    def votes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Consolidated votes: voxel linear index (m,), class (m,) int64 and summed vote (m,) float64."""
        if not self._votes:
            e = np.zeros(0, np.int64)
            return e, e, np.zeros(0)
        uk = np.concatenate([k for k, _ in self._votes])
        w = np.concatenate([w for _, w in self._votes])
        keys, inv = np.unique(uk, return_inverse=True)
        tot = np.bincount(inv, weights=w)
        return keys // self.n_classes, keys % self.n_classes, tot

    def grid(self, class_names: list[str], min_frames: int, min_points: int, label_radius: float,
             min_hit_ratio: float = 0.0) -> Grid:
        """The lifted ground truth.

        Parameters
        ----------
        class_names : the annotations' names, ``class_names[0]`` = unlabelled (becomes ``empty``)
        min_frames, min_points, min_hit_ratio : the minimum-support rule
        label_radius : metres, bound of the nearest-label transfer

        Returns
        -------
        Grid over the box: 0 observed free, 1..253 class, 254 occupied without class, 255 never observed.
        """
        from scipy.spatial import cKDTree

        if len(class_names) > OCCUPIED_UNKNOWN_CLASS:
            raise PanovoccError(f"{len(class_names)} classes; a uint8 grid holds at most 253")
        occ = self.occupied(min_frames, min_points, min_hit_ratio)
        labels = np.full(occ.shape, UNKNOWN, np.uint8)
        labels[(self.pass_frames > 0) & ~occ] = 0
        cls = np.full(occ.shape, OCCUPIED_UNKNOWN_CLASS, np.uint8)
        vox, c, w = self.votes()
        keep = occ[vox] & (c < len(class_names))
        vox, c, w = vox[keep], c[keep], w[keep]
        if len(vox):
            order = np.lexsort((c, -w, vox))  # per voxel: the largest vote first, then the lower class id
            first = np.ones(len(order), bool)
            first[1:] = vox[order][1:] != vox[order][:-1]
            win = order[first]
            cls[vox[win]] = c[win]
        labelled = occ & (cls != OCCUPIED_UNKNOWN_CLASS)
        todo = occ & ~labelled
        r_vox = float(label_radius) / self.h
        if todo.any() and labelled.any() and r_vox > 0:
            src = np.flatnonzero(labelled)
            dst = np.flatnonzero(todo)
            tree = cKDTree(np.stack(np.unravel_index(src, self.shape), 1).astype(np.float64))
            d, j = tree.query(np.stack(np.unravel_index(dst, self.shape), 1).astype(np.float64),
                              distance_upper_bound=r_vox * (1 + 1e-9))
            hit = np.isfinite(d)
            cls[dst[hit]] = cls[src[j[hit]]]
            transferred = int(hit.sum())
        else:
            transferred = 0
        labels[occ] = cls[occ]
        self.stats = {"occupied": int(occ.sum()), "voted": int(labelled.sum()), "transferred": transferred,
                      "no_class": int(occ.sum()) - int(labelled.sum()) - transferred,
                      "free": int((labels == 0).sum()), "unknown": int((labels == UNKNOWN).sum())}
        names = ["empty"] + list(class_names[1:])
        return Grid(labels.reshape(self.shape), index_to_center(self.index0, self.h), self.h, names).validate()
