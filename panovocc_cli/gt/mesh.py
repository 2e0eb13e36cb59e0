"""Mesh ground truth: the scene's surface voxelised on the global lattice, one class per voxel.

Every triangle is clipped exactly against the voxel slabs (Sutherland-Hodgman, x then y then z), so a
voxel is occupied when the surface passes through it with positive area; thin parts (chair legs, a 1 cm
rug, a curtain) cannot fall between samples. Each occupied voxel takes the class with the most surface
area inside it (ties: the lower class id). Surface with no class (id 0) only counts when nothing else is
there: such voxels become 254 (occupied, no class). Every other voxel inside the scene's bounds is 0
(empty). A surface lying exactly on a voxel boundary belongs to the voxel above it ([n h, (n+1) h)).
"""

from __future__ import annotations


import numpy as np
from numba import njit

from ..config import DEFAULT_VOXEL_SIZE, GT_BOUNDARY_EPS
from ..errors import PanovoccError
from ..geometry.lattice import bounds_to_grid, index_to_center
from ..grid import OCCUPIED_UNKNOWN_CLASS, Grid

BOUNDARY_EPS = GT_BOUNDARY_EPS  # voxel units (config.py)
MIN_AREA = 1e-10  # voxel units^2: pieces smaller than this (edges, corners touching a voxel) are dropped


@njit(cache=True)
def _clip(P, n, axis, val, keep_ge, out):
    """Clip polygon P[:n] by ``coord >= val`` (keep_ge) or ``coord <= val``; returns the new vertex count."""
    m = 0
    for a in range(n):
        b = (a + 1) % n
        da = P[a, axis] - val
        db = P[b, axis] - val
        if not keep_ge:
            da, db = -da, -db
        if da >= 0:
            out[m] = P[a]
            m += 1
        if (da >= 0) != (db >= 0):
            t = da / (da - db)
            out[m] = P[a] + t * (P[b] - P[a])
            m += 1
    return m


@njit(cache=True)
def _area(P, n):
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for a in range(1, n - 1):
        ux, uy, uz = P[a, 0] - P[0, 0], P[a, 1] - P[0, 1], P[a, 2] - P[0, 2]
        vx, vy, vz = P[a + 1, 0] - P[0, 0], P[a + 1, 1] - P[0, 1], P[a + 1, 2] - P[0, 2]
        sx += uy * vz - uz * vy
        sy += uz * vx - ux * vz
        sz += ux * vy - uy * vx
    return 0.5 * np.sqrt(sx * sx + sy * sy + sz * sz)


@njit(cache=True)
def _grow(a, n):
    b = np.empty((max(2 * a.shape[0], n),) + a.shape[1:], a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True)
def voxel_areas(q, faces, face_class):
    """Surface area of each triangle in each voxel it crosses.

    Parameters
    ----------
    q : (V, 3) float64 vertices in voxel units (world / h, plus the boundary epsilon)
    faces : (F, 3) int32; face_class : (F,) int32

    Returns
    -------
    ijk : (n, 3) int64 lattice indices; cls : (n,) int32; area : (n,) float64 in voxel units^2
    """
    cap = faces.shape[0] * 4 + 16
    ijk = np.empty((cap, 3), np.int64)
    cls = np.empty(cap, np.int32)
    area = np.empty(cap, np.float64)
    cnt = 0
    P0 = np.empty((16, 3))
    P1 = np.empty((16, 3))
    P2 = np.empty((16, 3))
    P3 = np.empty((16, 3))
    P4 = np.empty((16, 3))
    P5 = np.empty((16, 3))
    for t in range(faces.shape[0]):
        for a in range(3):
            P0[a] = q[faces[t, a]]
        lo0 = np.floor(min(P0[0, 0], P0[1, 0], P0[2, 0]))
        hi0 = np.floor(max(P0[0, 0], P0[1, 0], P0[2, 0]))
        for i in range(int(lo0), int(hi0) + 1):
            n1 = _clip(P0, 3, 0, float(i), True, P1)
            n1 = _clip(P1, n1, 0, float(i + 1), False, P2)
            if n1 < 3:
                continue
            lo1 = P2[0, 1]
            hi1 = P2[0, 1]
            for a in range(1, n1):
                lo1 = min(lo1, P2[a, 1])
                hi1 = max(hi1, P2[a, 1])
            for j in range(int(np.floor(lo1)), int(np.floor(hi1)) + 1):
                n2 = _clip(P2, n1, 1, float(j), True, P3)
                n2 = _clip(P3, n2, 1, float(j + 1), False, P4)
                if n2 < 3:
                    continue
                lo2 = P4[0, 2]
                hi2 = P4[0, 2]
                for a in range(1, n2):
                    lo2 = min(lo2, P4[a, 2])
                    hi2 = max(hi2, P4[a, 2])
                for k in range(int(np.floor(lo2)), int(np.floor(hi2)) + 1):
                    n3 = _clip(P4, n2, 2, float(k), True, P5)
                    n3 = _clip(P5, n3, 2, float(k + 1), False, P3)
                    if n3 < 3:
                        continue
                    ar = _area(P3, n3)
                    if ar <= MIN_AREA:
                        continue
                    if cnt == ijk.shape[0]:
                        ijk = _grow(ijk, cnt + 1)
                        cls = _grow(cls, cnt + 1)
                        area = _grow(area, cnt + 1)
                    ijk[cnt, 0] = i
                    ijk[cnt, 1] = j
                    ijk[cnt, 2] = k
                    cls[cnt] = face_class[t]
                    area[cnt] = ar
                    cnt += 1
    return ijk[:cnt], cls[:cnt], area[:cnt]


BYTES_PER_PIECE = 120  # voxel_areas' records (36 B, grown by doubling) and the per-voxel vote arrays after it


def gt_memory_estimate(scene, voxel_size: float) -> tuple[tuple[int, int, int], int]:
    """Grid shape and bytes :func:`voxelize_scene` would need at ``voxel_size`` metres, before allocating.

    The dense uint8 grid over the scene's bounds, plus about ``BYTES_PER_PIECE`` per (triangle, voxel)
    piece; a triangle of area a crosses about 2 a / h^2 + 1 voxels.
    """
    lo, hi = scene.bounds
    shape = tuple(int(np.floor(x)) + 2 for x in (hi - lo) / voxel_size)
    cells = float(np.prod(np.asarray(shape, dtype=np.float64)))
    pieces = 2.0 * float(scene.triangle_areas().sum()) / voxel_size ** 2 + len(scene.faces)
    return shape, int(min(cells + BYTES_PER_PIECE * pieces, 2.0 ** 62))


def check_gt_memory(scene, voxel_size: float) -> None:
    """Refuse a voxel size whose grid cannot fit in the memory available now (one line with the size needed)."""
    from ..runtime import check_memory

    shape, need = gt_memory_estimate(scene, voxel_size)
    check_memory(need, f"--voxel-size {voxel_size:g} m: a {shape[0]}x{shape[1]}x{shape[2]} grid",
                 "choose a larger voxel size")


def voxelize_scene(scene, voxel_size: float = DEFAULT_VOXEL_SIZE) -> Grid:
    """Voxelise a :class:`~panovocc_cli.datasets.scene.Scene`'s surface on the global lattice.

    Parameters
    ----------
    scene : Scene (world frame, metres), class ids into ``scene.class_names`` (0 = unlabeled)
    voxel_size : h, metres

    Returns
    -------
    Grid with labels (X, Y, Z) uint8: 0 empty, k = the class ``scene.class_names[k]`` with most surface
    area, 254 surface with no class; ``class_names = ["empty"] + scene.class_names[1:]``; covers the
    scene's bounds on the lattice (``origin / h - 0.5`` whole).
    """
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise PanovoccError(f"voxel size must be positive, got {voxel_size}")
    if len(scene.class_names) > OCCUPIED_UNKNOWN_CLASS:
        raise PanovoccError(f"scene has {len(scene.class_names)} classes; a uint8 grid holds at most 253")
    h = float(voxel_size)
    check_gt_memory(scene, h)
    q = scene.vertices / h + BOUNDARY_EPS
    ijk, cls, area = voxel_areas(q, scene.faces, scene.face_class)
    lo, hi = scene.bounds
    i0, shape, _ = bounds_to_grid(lo, hi, h)
    if len(ijk):
        i1 = np.maximum(i0 + shape - 1, ijk.max(0))
        i0 = np.minimum(i0, ijk.min(0))
        shape = i1 - i0 + 1
    labels = np.zeros(tuple(int(s) for s in shape), np.uint8)
    if len(ijk):
        local = ijk - i0
        lin = np.ravel_multi_index(local.T, labels.shape)
        C = len(scene.class_names)
        key = lin * C + cls
        uk, inv = np.unique(key, return_inverse=True)
        tot = np.bincount(inv, weights=area)
        vox, c = uk // C, (uk % C).astype(np.int64)
        score = np.where(c > 0, tot, -1.0)  # unlabeled surface loses to any class
        order = np.lexsort((c, -score, vox))  # per voxel: largest area first, then the lower class id
        first = np.ones(len(order), bool)
        first[1:] = vox[order][1:] != vox[order][:-1]
        win = order[first]
        lab = np.where(c[win] > 0, c[win], OCCUPIED_UNKNOWN_CLASS).astype(np.uint8)
        labels.reshape(-1)[vox[win]] = lab
    names = ["empty"] + list(scene.class_names[1:])
    return Grid(labels, index_to_center(i0, h), h, names).validate()
