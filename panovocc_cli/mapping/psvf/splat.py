"""The splat kernels: each lifted measurement's support added into the frame's dense voxel grid.

Three kernel shapes (``GeometryParams.extent``), all evaluated at voxel centres c of the frame box:

* ``surfel`` (:func:`splat_axis`, default): a Gaussian within the local surface plane (inverse
  covariance ``Pt``, rank 2) times the probability that the plane, displaced along its normal with
  scale ``s``, passes through the voxel's box: ``0.5 [erf((b - dn) / (sqrt 2 s)) + erf((b + dn) / (sqrt 2 s))]``;
* ``box`` (:func:`splat` with ``kernel="box"``): the tangential Gaussian of the ray-aligned kernel times
  the probability that the ray coordinate falls in the voxel's chord;
* ``centre`` (:func:`splat` with ``kernel="psvf"``): the paper's full 3D Gaussian ``exp(-d^2 / 2)``;

and the ``point`` ablation: each measurement's weight added to the one voxel that contains it.
Kernels are split into ``N_CHUNKS`` fixed chunks, one dense grid each, summed in chunk order, so the
result does not depend on the thread count.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

SPLAT_INNER = 6.5  # sigmas: deeper inside the box than this along the axis, P(plane in box) = 1 to 1e-10

N_CHUNKS = 2  # points are split into this many fixed chunks (deterministic whatever the thread count)


@nb.njit(cache=True, inline="always")
def _span(c, a, h, lo, n):
    """Grid-local indices (first, last) of the voxels whose centres lie in [c - a, c + a] (metres),
    clipped to the frame box of ``n`` voxels starting at lattice index ``lo``."""
    first = max(int(np.ceil((c - a) / h - 0.5)) - lo, 0)
    last = min(int(np.floor((c + a) / h - 0.5)) - lo, n - 1)
    return first, last


@nb.njit(cache=True, parallel=True)
def _splat_psvf(x, P, half, w, kappa, h, lo, grids):
    """Add the truncated Gaussians into ``grids[chunk]`` (dense frame-local float64 grids)."""
    n = x.shape[0]
    k2 = kappa * kappa
    nx, ny, nz = grids.shape[1], grids.shape[2], grids.shape[3]
    step = (n + N_CHUNKS - 1) // N_CHUNKS
    for ch in nb.prange(N_CHUNKS):
        g = grids[ch]
        for p in range(ch * step, min(n, (ch + 1) * step)):
            px, py, pz = x[p, 0], x[p, 1], x[p, 2]
            a00, a01, a02 = P[p, 0, 0], P[p, 0, 1], P[p, 0, 2]
            a11, a12, a22 = P[p, 1, 1], P[p, 1, 2], P[p, 2, 2]
            wp = w[p]
            i0, i1 = _span(px, kappa * half[p, 0], h, lo[0], nx)
            j0, j1 = _span(py, kappa * half[p, 1], h, lo[1], ny)
            k0, k1 = _span(pz, kappa * half[p, 2], h, lo[2], nz)
            for i in range(i0, i1 + 1):
                dx = (i + lo[0] + 0.5) * h - px
                for j in range(j0, j1 + 1):
                    dy = (j + lo[1] + 0.5) * h - py
                    qxy = a00 * dx * dx + 2.0 * a01 * dx * dy + a11 * dy * dy
                    bz = 2.0 * (a02 * dx + a12 * dy)
                    for k in range(k0, k1 + 1):
                        dz = (k + lo[2] + 0.5) * h - pz
                        d2 = qxy + dz * (bz + a22 * dz)
                        if d2 <= k2:
                            g[i, j, k] += wp * np.exp(-0.5 * d2)


@nb.njit(cache=True, parallel=True)
def _splat_box(x, P, half, w, er, sr, kappa, h, lo, grids):
    """Tangential Gaussian times the probability that the ray coordinate falls in the voxel's chord."""
    n = x.shape[0]
    k2 = kappa * kappa
    nx, ny, nz = grids.shape[1], grids.shape[2], grids.shape[3]
    step = (n + N_CHUNKS - 1) // N_CHUNKS
    for ch in nb.prange(N_CHUNKS):
        g = grids[ch]
        for p in range(ch * step, min(n, (ch + 1) * step)):
            px, py, pz = x[p, 0], x[p, 1], x[p, 2]
            a00, a01, a02 = P[p, 0, 0], P[p, 0, 1], P[p, 0, 2]
            a11, a12, a22 = P[p, 1, 1], P[p, 1, 2], P[p, 2, 2]
            ex, ey, ez = er[p, 0], er[p, 1], er[p, 2]
            s = sr[p]
            inv2s = 1.0 / (np.sqrt(2.0) * s)
            b = 0.5 * h / max(abs(ex), abs(ey), abs(ez))  # half chord of a voxel along the ray
            rlim = b + kappa * s
            wp = w[p]
            ax, ay, az = kappa * half[p, 0] + b * abs(ex), kappa * half[p, 1] + b * abs(ey), kappa * half[p, 2] + b * abs(ez)
            i0, i1 = _span(px, ax, h, lo[0], nx)
            j0, j1 = _span(py, ay, h, lo[1], ny)
            k0, k1 = _span(pz, az, h, lo[2], nz)
            for i in range(i0, i1 + 1):
                dx = (i + lo[0] + 0.5) * h - px
                for j in range(j0, j1 + 1):
                    dy = (j + lo[1] + 0.5) * h - py
                    qxy = a00 * dx * dx + 2.0 * a01 * dx * dy + a11 * dy * dy
                    bz = 2.0 * (a02 * dx + a12 * dy)
                    rxy = ex * dx + ey * dy
                    for k in range(k0, k1 + 1):
                        dz = (k + lo[2] + 0.5) * h - pz
                        dr = rxy + ez * dz
                        if abs(dr) > rlim:
                            continue
                        dt2 = qxy + dz * (bz + a22 * dz) - (dr / s) ** 2
                        if dt2 <= k2:
                            g[i, j, k] += wp * np.exp(-0.5 * dt2) * 0.5 * (math.erf((b - dr) * inv2s) + math.erf((b + dr) * inv2s))


@nb.njit(cache=True, parallel=True)
def _splat_axis(x, Pt, half, w, ax, sa, bb, kappa, h, lo, grids):
    """Tangential Gaussian (Pt) times P(axis coordinate within the voxel's support +-b along the axis)."""
    n = x.shape[0]
    k2 = kappa * kappa
    nx, ny, nz = grids.shape[1], grids.shape[2], grids.shape[3]
    step = (n + N_CHUNKS - 1) // N_CHUNKS
    for ch in nb.prange(N_CHUNKS):
        g = grids[ch]
        for p in range(ch * step, min(n, (ch + 1) * step)):
            px, py, pz = x[p, 0], x[p, 1], x[p, 2]
            a00, a01, a02 = Pt[p, 0, 0], Pt[p, 0, 1], Pt[p, 0, 2]
            a11, a12, a22 = Pt[p, 1, 1], Pt[p, 1, 2], Pt[p, 2, 2]
            ex, ey, ez = ax[p, 0], ax[p, 1], ax[p, 2]
            s = sa[p]
            inv2s = 1.0 / (np.sqrt(2.0) * s)
            b = bb[p]
            rlim = b + kappa * s
            inner = SPLAT_INNER * s
            wp = w[p]
            i0, i1 = _span(px, half[p, 0], h, lo[0], nx)
            j0, j1 = _span(py, half[p, 1], h, lo[1], ny)
            k0, k1 = _span(pz, half[p, 2], h, lo[2], nz)
            for i in range(i0, i1 + 1):
                dx = (i + lo[0] + 0.5) * h - px
                for j in range(j0, j1 + 1):
                    dy = (j + lo[1] + 0.5) * h - py
                    qxy = a00 * dx * dx + 2.0 * a01 * dx * dy + a11 * dy * dy
                    bz = 2.0 * (a02 * dx + a12 * dy)
                    rxy = ex * dx + ey * dy
                    for k in range(k0, k1 + 1):
                        dz = (k + lo[2] + 0.5) * h - pz
                        dr = rxy + ez * dz
                        adr = abs(dr)
                        if adr > rlim:
                            continue
                        dt2 = qxy + dz * (bz + a22 * dz)
                        if dt2 <= k2:
                            if b - adr >= inner:  # the plane lies well inside the box: both erf are 1 within 1e-9
                                g[i, j, k] += wp * np.exp(-0.5 * dt2)
                            else:
                                g[i, j, k] += wp * np.exp(-0.5 * dt2) * 0.5 * (
                                    math.erf((b - dr) * inv2s) + math.erf((b + dr) * inv2s))


@nb.njit(cache=True, inline="always")
def local_voxel(x, p, h, lo, shape):
    """Grid-local index (i, j, k) of the voxel holding point p of x (metres), and whether it lies in the
    frame grid of ``shape`` starting at lattice index ``lo``."""
    i = int(np.floor(x[p, 0] / h)) - lo[0]
    j = int(np.floor(x[p, 1] / h)) - lo[1]
    k = int(np.floor(x[p, 2] / h)) - lo[2]
    return i, j, k, 0 <= i < shape[0] and 0 <= j < shape[1] and 0 <= k < shape[2]


@nb.njit(cache=True)
def _splat_point(x, w, h, lo, grid):
    """Add each point's weight to the voxel that contains it."""
    for p in range(x.shape[0]):
        i, j, k, inside = local_voxel(x, p, h, lo, grid.shape)
        if inside:
            grid[i, j, k] += w[p]


def splat(x_world, P, half, w, kappa: float, voxel_size: float, lo: np.ndarray, shape, kernel: str,
          er=None, sr=None) -> np.ndarray:
    """Per-frame surface support on a dense frame-local grid.

    Parameters
    ----------
    x_world : (n, 3) float64 metres; P : (n, 3, 3) float64; half : (n, 3) float64 metres
    w : (n,) float64, omega of each measurement (c_norm included)
    lo : (3,) int64, lattice index of grid cell [0, 0, 0]; shape : (3,) int
    kernel : ``"psvf"`` or ``"point"``

    Returns
    -------
    A : (X, Y, Z) float64, dA of each voxel (before quantisation)
    """
    lo = np.asarray(lo, dtype=np.int64)
    shape = tuple(int(s) for s in shape)
    if kernel == "point":
        g = np.zeros(shape, np.float64)
        _splat_point(np.ascontiguousarray(x_world), np.ascontiguousarray(w), voxel_size, lo, g)
        return g
    grids = np.zeros((N_CHUNKS,) + shape, np.float64)
    if kernel == "box":
        _splat_box(np.ascontiguousarray(x_world), np.ascontiguousarray(P), np.ascontiguousarray(half),
                   np.ascontiguousarray(w), np.ascontiguousarray(er), np.ascontiguousarray(sr), float(kappa),
                   float(voxel_size), lo, grids)
    else:
        _splat_psvf(np.ascontiguousarray(x_world), np.ascontiguousarray(P), np.ascontiguousarray(half),
                    np.ascontiguousarray(w), float(kappa), float(voxel_size), lo, grids)
    out = grids[0]
    for c in range(1, N_CHUNKS):
        out += grids[c]
    return out


def splat_axis(x_world, Pt, half, w, axis, s_axis, b, kappa: float, voxel_size: float, lo: np.ndarray,
               shape) -> np.ndarray:
    """Per-frame support of surfel kernels (from :func:`lift_surfels`) on a dense frame-local grid.

    Returns
    -------
    A : (X, Y, Z) float64, dA of each voxel; voxel centre c gets, for each sample,
    ``w exp(-dt^2 / 2) 0.5 [erf((b - dn) / (sqrt 2 s)) + erf((b + dn) / (sqrt 2 s))]`` with
    ``dt^2 = (c - x)^T Pt (c - x) <= kappa^2``, ``dn = axis . (c - x)``, ``|dn| <= b + kappa s``.
    """
    shape = tuple(int(s) for s in shape)
    grids = np.zeros((N_CHUNKS,) + shape, np.float64)
    _splat_axis(np.ascontiguousarray(x_world), np.ascontiguousarray(Pt), np.ascontiguousarray(half),
                np.ascontiguousarray(w), np.ascontiguousarray(axis), np.ascontiguousarray(s_axis),
                np.ascontiguousarray(b), float(kappa), float(voxel_size), np.asarray(lo, np.int64), grids)
    out = grids[0]
    for c in range(1, N_CHUNKS):
        out += grids[c]
    return out

