"""An edge's information matrix, equal to Open3D's ``get_information_matrix_from_point_clouds`` bit for bit, without
its KD-tree: a hash of the target's points in cells twice the correspondence distance wide.

Open3D's matrix (``EvaluateRegistration`` then ``GetInformationMatrixFromPointClouds``): every source point moved by
``T_target_source`` is matched to its nearest target point within ``max_corr`` (a strict radius), in source order, and
each match adds ``g g'`` for the three rows ``g`` of ``[-[q]x | I]`` at the target point ``q`` (rotation first), entry
by entry in that order. Open3D builds a KD-tree of the target for every call: 42 % of the final refinement's CPU on a
building's floor (docs/slam.md, "A store that lasts"). Here the target's points are sorted into cells twice the
correspondence distance wide (a point within it of a source point lies in the 2 x 2 x 2 cells on that point's side of
its own cell's middle along each axis), found through an open-addressing hash, and the sums are made in Open3D's order (the products with a zero entry of g
add nothing and are skipped), so the matrix is the same bytes (tested against Open3D on registered and perturbed
pairs, tests/slam/test_information.py). Two target points exactly as far from a source point are a tie that Open3D's
tree may break either way; here the lower index wins. Maths only.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_SPAN = 1 << 20  # cells either side of the origin in a key (21 bits an axis)
_LIMIT = 100_000  # cells from the origin that a target point may lie (20 km at 0.1 m correspondences)


@nb.njit(cache=True, inline="always")
def _cell_key(cx, cy, cz):
    return ((cx + _SPAN) << 42) | ((cy + _SPAN) << 21) | (cz + _SPAN)


@nb.njit(cache=True, inline="always")
def _slot(key, shift):
    """Fibonacci hashing: the top bits of the key times 2^64 / golden ratio."""
    return np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(shift))


@nb.njit(cache=True, inline="always")
def _add_outer(G, a, b, c, va, vb, vc):
    """``G += g g'`` for the vector g with entries va, vb, vc at a < b < c and zeros elsewhere, entry by entry."""
    G[a, a] += va * va
    G[a, b] += va * vb
    G[a, c] += va * vc
    G[b, a] += vb * va
    G[b, b] += vb * vb
    G[b, c] += vb * vc
    G[c, a] += vc * va
    G[c, b] += vc * vb
    G[c, c] += vc * vc


@nb.njit(cache=True)
def information_matrix(target, source, T, max_corr):
    """Open3D's information matrix (6, 6) float64 of ``source`` (n, 3) float64 moved by ``T`` (4, 4) onto ``target``
    (m, 3) float64 within ``max_corr`` metres (module docstring); the number of correspondences is its (5, 5) entry.
    A target point more than 100,000 cells from the origin is refused (ValueError)."""
    m = target.shape[0]
    G = np.zeros((6, 6))
    if m == 0 or source.shape[0] == 0:
        return G
    # cells two correspondence distances wide (a hair more: rounding): a point within max_corr of p lies in the
    # 2 x 2 x 2 cells on p's side of the middle of its cell along each axis
    cell = 2.0 * max_corr * (1.0 + 1e-9)
    keys = np.empty(m, np.int64)
    for j in range(m):
        fx = np.floor(target[j, 0] / cell)
        fy = np.floor(target[j, 1] / cell)
        fz = np.floor(target[j, 2] / cell)
        if not (abs(fx) <= _LIMIT and abs(fy) <= _LIMIT and abs(fz) <= _LIMIT):
            raise ValueError("information_matrix: a target point lies too far from the origin for its cells")
        keys[j] = _cell_key(np.int64(fx), np.int64(fy), np.int64(fz))
    order = np.argsort(keys, kind="mergesort")  # stable: a cell's points in index order
    pts = np.empty((m, 3))
    for o in range(m):
        pts[o, 0] = target[order[o], 0]
        pts[o, 1] = target[order[o], 1]
        pts[o, 2] = target[order[o], 2]
    size, bits = 2, 1
    while size < 2 * m:
        size *= 2
        bits += 1
    mask, shift = size - 1, 64 - bits
    slots = np.full((size, 3), -1, np.int64)  # key, first, end (in sorted order)
    a = 0
    while a < m:
        k = keys[order[a]]
        b = a + 1
        while b < m and keys[order[b]] == k:
            b += 1
        s = _slot(k, shift)
        while slots[s, 0] != -1:
            s = (s + 1) & mask
        slots[s, 0], slots[s, 1], slots[s, 2] = k, a, b
        a = b
    r2 = max_corr * max_corr
    for i in range(source.shape[0]):
        x, y, z = source[i, 0], source[i, 1], source[i, 2]
        px = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
        py = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
        pz = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
        ux, uy, uz = px / cell, py / cell, pz / cell
        fx, fy, fz = np.floor(ux), np.floor(uy), np.floor(uz)
        if not (abs(fx) <= _LIMIT + 1 and abs(fy) <= _LIMIT + 1 and abs(fz) <= _LIMIT + 1):
            continue  # no target point within max_corr of it (or not a number)
        x0 = np.int64(fx) - (1 if ux - fx < 0.5 else 0)
        y0 = np.int64(fy) - (1 if uy - fy < 0.5 else 0)
        z0 = np.int64(fz) - (1 if uz - fz < 0.5 else 0)
        best, best_d = -1, r2
        for cx in range(x0, x0 + 2):
            for cy in range(y0, y0 + 2):
                for cz in range(z0, z0 + 2):
                    k = _cell_key(cx, cy, cz)
                    s = _slot(k, shift)
                    while slots[s, 0] != -1 and slots[s, 0] != k:
                        s = (s + 1) & mask
                    if slots[s, 0] == -1:
                        continue
                    for o in range(slots[s, 1], slots[s, 2]):
                        ex = pts[o, 0] - px
                        ey = pts[o, 1] - py
                        ez = pts[o, 2] - pz
                        d = ex * ex + ey * ey + ez * ez
                        if d < best_d or (d == best_d and best >= 0 and order[o] < best):
                            best, best_d = order[o], d
        if best < 0:
            continue
        tx, ty, tz = target[best, 0], target[best, 1], target[best, 2]
        # the rows (0, z, -y, 1, 0, 0), (-z, 0, x, 0, 1, 0), (y, -x, 0, 0, 0, 1), in turn
        _add_outer(G, 1, 2, 3, tz, -ty, 1.0)
        _add_outer(G, 0, 2, 4, -tz, tx, 1.0)
        _add_outer(G, 0, 1, 5, ty, -tx, 1.0)
    return G
