"""Ground truth lifted from a capture: the pieces around the occupancy (the Pan-Holo360D protocol;
docs/gt.md has the rules' measurements). The occupancy itself is the multi-view consensus of
:mod:`panovocc_cli.gt.consensus`.

* :func:`depth_bounds`: the world box of a frame's depth, to size the dense grid;
* :func:`parse_annotated`: the annotated frames of ``--annotated``;
* **labels** (:func:`frame_votes`, :func:`label_grid`): each annotated frame lifts its label image through
  its own depth and pose; per voxel the frame casts one vote, split over the classes of its pixels in
  that voxel (fractions summing to 1, in fixed point so the sum does not depend on the frames' order), so
  a frame close to a surface does not outvote several far ones by pixel count. An occupied voxel takes
  the class covering the most of its area (where the caller measures it: the consensus's area cells), then
  the class with the largest summed vote (ties: the lower class id). Unlabelled pixels (id 0) vote for
  nothing; votes falling in voxels that are not occupied are dropped;
* **bounded transfer** (:func:`transfer_labels`): an occupied voxel no annotation reached takes the most
  common class of the nearest labelled occupied voxels within ``label_radius`` metres (centre to centre),
  among those on its own surface where there are any (the caller's consensus surfaces, within
  ``SAME_SURFACE_TOL`` voxels); ties: the class with fewer labelled voxels, then the lower class id; else 254
  (occupied, no class).

No file I/O here: ``run_lifted_gt`` (the reading and writing) lives in :mod:`panovocc_cli.gt.run`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import PanovoccError
from ..geometry.erp import cam_point, trig_tables
from ..geometry.lattice import index_to_center
from ..grid import OCCUPIED_UNKNOWN_CLASS, UNKNOWN, Grid

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


VOTE_UNITS = 1 << 20  # fixed-point units of one frame's vote in one voxel


def frame_votes(pix_lin: np.ndarray, labels: np.ndarray, n_classes: int) -> tuple[np.ndarray, np.ndarray]:
    """One annotated frame's votes: one vote per voxel split over its pixels' classes there.

    Parameters
    ----------
    pix_lin : (H, W) int64 voxel (linear index into the box) each pixel votes in, -1 for none
    labels : (H, W) int class ids, 0 = unlabelled
    n_classes : number of label ids

    Returns
    -------
    keys : (m,) int64 ``voxel * n_classes + class``; votes : (m,) int64 in ``VOTE_UNITS`` (about one a voxel)
    """
    ok = (pix_lin >= 0) & (labels > 0)
    C = int(n_classes)
    key = pix_lin[ok] * C + labels[ok].astype(np.int64)
    uk, cnt = np.unique(key, return_counts=True)
    _, inv = np.unique(uk // C, return_inverse=True)
    tot = np.bincount(inv, weights=cnt).astype(np.int64)
    return uk, (cnt.astype(np.int64) * VOTE_UNITS) // tot[inv]


SAME_SURFACE_TOL = 0.25  # voxels: a source voxel is on the same surface when its position is this close (transfer)


def transfer_labels(cls: np.ndarray, src: np.ndarray, dst: np.ndarray, shape, r_vox: float,
                    surfaces: list[np.ndarray] | None = None, same_tol: float = 0.0) -> np.ndarray:
    """The bounded transfer: a class for each voxel ``dst`` from the labelled voxels ``src`` within ``r_vox``.

    The candidates are the sources within ``r_vox`` voxels (centre to centre); where some of them lie on the
    voxel's own surface (an axis along which both have a consensus surface, positions within ``same_tol``
    metres) only those. Among the nearest candidates the most common class wins; between equally common
    classes the one with fewer labelled voxels in the grid (an object's hidden side beside a wall or the floor
    is the object's), then the lower class id. Integer distances and counts: the result depends neither on the
    order of ``src`` / ``dst`` nor on any tree's.

    Parameters
    ----------
    cls : (n,) uint8 class of every voxel of the box (read at ``src``)
    src, dst : int64 linear indices into the box (C order of ``shape``)
    r_vox : bound, voxels
    surfaces : optional, per axis (n,) float64 consensus surface position, metres (NaN: none)
    same_tol : metres

    Returns
    -------
    (len(dst),) uint8: the class, ``OCCUPIED_UNKNOWN_CLASS`` where no source lies within ``r_vox``
    """
    from scipy.spatial import cKDTree

    out = np.full(len(dst), OCCUPIED_UNKNOWN_CLASS, np.uint8)
    if not len(dst) or not len(src) or r_vox <= 0:
        return out
    ps_all = np.stack(np.unravel_index(src, shape), 1).astype(np.int64)
    pd_all = np.stack(np.unravel_index(dst, shape), 1).astype(np.int64)
    near = cKDTree(ps_all.astype(np.float64)).query_ball_point(pd_all.astype(np.float64), r_vox * (1 + 1e-9))
    n_per = np.fromiter((len(x) for x in near), np.int64, len(near))
    if not n_per.any():
        return out
    pd = np.repeat(np.arange(len(dst)), n_per)
    ps = np.fromiter((j for x in near for j in x), np.int64, int(n_per.sum()))
    d2 = ((ps_all[ps] - pd_all[pd]) ** 2).sum(1)
    keep = np.ones(len(pd), bool)
    if surfaces is not None:
        same = np.zeros(len(pd), bool)
        for S in surfaces:
            a, b = S[dst[pd]], S[src[ps]]
            same |= np.isfinite(a) & np.isfinite(b) & (np.abs(np.nan_to_num(a) - np.nan_to_num(b)) <= same_tol)
        keep = same | (np.bincount(pd, weights=same, minlength=len(dst)) == 0)[pd]
    pd, ps, d2 = pd[keep], ps[keep], d2[keep]
    dmin = np.full(len(dst), np.iinfo(np.int64).max)
    np.minimum.at(dmin, pd, d2)
    at = d2 == dmin[pd]
    c = cls[src[ps[at]]].astype(np.int64)
    key, cnt = np.unique(pd[at] * 256 + c, return_counts=True)
    kd, kc = key // 256, key % 256
    size = np.bincount(cls[src], minlength=256)
    order = np.lexsort((kc, size[kc], -cnt, kd))
    first = order[np.r_[True, kd[order][1:] != kd[order][:-1]]]
    out[kd[first]] = kc[first]
    return out


def label_grid(occ: np.ndarray, free: np.ndarray, votes: list[tuple[np.ndarray, np.ndarray]], n_classes: int,
               class_names: list[str], label_radius: float, index0, shape, voxel_size: float,
               area: tuple[np.ndarray, np.ndarray] | None = None,
               surfaces: list[np.ndarray] | None = None) -> tuple[Grid, dict]:
    """The lifted grid from its occupancy, its observed free space and the annotated frames' votes.

    Parameters
    ----------
    occ, free : (n,) bool over the box (C order of ``shape``): occupied; observed and not occupied
    votes : :func:`frame_votes` of each annotated frame
    area : optional ``(keys, cells)``: sorted unique ``voxel * n_classes + class`` and how much of the voxel's
        surface that class covers (any whole measure); a voxel takes the class covering the most, the summed
        vote deciding between equal covers (and where no class covers any)
    class_names : the annotations' names, ``class_names[0]`` = unlabelled (becomes ``empty``)
    label_radius : metres, bound of the nearest-label transfer
    surfaces : optional, per axis (n,) float the position in metres of the voxel's consensus surface along that
        axis (NaN: none): the transfer's same-surface sources (:func:`transfer_labels`)
    index0, shape, voxel_size : the box on the lattice

    Returns
    -------
    grid : 0 observed free, 1..253 class, 254 occupied without class, 255 never observed;
    stats : dict (occupied, voted, transferred, no_class, free, unknown)
    """
    if len(class_names) > OCCUPIED_UNKNOWN_CLASS:
        raise PanovoccError(f"{len(class_names)} classes; a uint8 grid holds at most 253")
    shape = tuple(int(s) for s in shape)
    labels = np.full(occ.shape, UNKNOWN, np.uint8)
    labels[free & ~occ] = 0
    cls = np.full(occ.shape, OCCUPIED_UNKNOWN_CLASS, np.uint8)
    if votes:
        keys, inv = np.unique(np.concatenate([k for k, _ in votes]), return_inverse=True)
        w = np.bincount(inv, weights=np.concatenate([v for _, v in votes])).astype(np.int64)
        cover = np.zeros(len(keys), np.int64)
        if area is not None and len(area[0]):
            at = np.minimum(np.searchsorted(area[0], keys), len(area[0]) - 1)
            cover = np.where(area[0][at] == keys, area[1][at], 0).astype(np.int64)
        vox, c = keys // n_classes, keys % n_classes
        keep = occ[vox] & (c < len(class_names))
        vox, c, w, cover = vox[keep], c[keep], w[keep], cover[keep]
        if len(vox):
            order = np.lexsort((c, -w, -cover, vox))  # per voxel: the largest cover, vote, then the lower class id
            first = np.ones(len(order), bool)
            first[1:] = vox[order][1:] != vox[order][:-1]
            win = order[first]
            cls[vox[win]] = c[win]
    labelled = occ & (cls != OCCUPIED_UNKNOWN_CLASS)
    todo = occ & ~labelled
    r_vox = float(label_radius) / float(voxel_size)
    transferred = 0
    if todo.any() and labelled.any() and r_vox > 0:
        dst = np.flatnonzero(todo)
        got = transfer_labels(cls, np.flatnonzero(labelled), dst, shape, r_vox, surfaces,
                              SAME_SURFACE_TOL * float(voxel_size))
        cls[dst] = got
        transferred = int((got != OCCUPIED_UNKNOWN_CLASS).sum())
    labels[occ] = cls[occ]
    stats = {"occupied": int(occ.sum()), "voted": int(labelled.sum()), "transferred": transferred,
             "no_class": int(occ.sum()) - int(labelled.sum()) - transferred,
             "free": int((labels == 0).sum()), "unknown": int((labels == UNKNOWN).sum())}
    names = ["empty"] + list(class_names[1:])
    grid = Grid(labels.reshape(shape), index_to_center(np.asarray(index0, np.int64), voxel_size), voxel_size, names)
    return grid.validate(), stats
