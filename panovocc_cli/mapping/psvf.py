"""Panoramic Signed Voxel Fusion (PSVF): the anisotropic surface kernel of one ERP frame.

Each valid strided pixel p (stride s) with radial depth r is lifted to ``x = R (r d) + t`` and
modelled as a Gaussian aligned with its spherical viewing geometry::

    sigma = [r |cos phi| dtheta, r dphi, alpha r + beta]      (longitude, latitude, ray)
    dtheta = 2 pi s / W,  dphi = pi s / H
    Sigma = E diag(sigma^2) E^T,  d^2(i) = (x_i - x)^T Sigma^-1 (x_i - x)
    dA_i = sum_p omega(phi, r) exp(-d^2 / 2) [d^2 <= kappa^2]

with E the (longitude, latitude, ray) directions in the world frame. The weight is
``omega = c_norm * w_lat(phi) * w_range(r)`` with ``w_lat = 1 - (1 - w_pole) sin^2 phi`` (ERP pixels
near the poles are stretched resamplings, less reliable) and ``w_range = 1 / (1 + r / r_half)``
(depth noise grows with range). ``c_norm = 1 / (2 pi)``: the kernels' tangential widths equal the
sample spacing, so the Gaussians of a surface sum to about 2 pi at a voxel centre on it, and a
well-observed surface voxel gets a per-frame support ``A / N`` near ``w_lat w_range`` (<= 1),
whatever the range or stride. The ``point`` kernel (the ablation) adds ``w_lat w_range`` to the one
voxel containing each point.

``splat(..., kernel="box")`` (the default ``GeometryParams.extent``; a documented deviation) accounts
for the voxel's extent: it keeps the tangential Gaussian and replaces the radial factor by the
probability that the ray coordinate lies in the voxel's chord through its centre,
``0.5 [erf((b - dr) / (sqrt 2 s_r)) + erf((b + dr) / (sqrt 2 s_r))]`` with ``b = h / (2 max|e_r|)``.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..geometry.erp import local_frames, pixel_to_angles

SIGMA_MIN = 1e-4  # metres; floor of a kernel axis (the longitude axis vanishes at the poles)


def strided_pixels(width: int, height: int, stride: int):
    """Rows and columns (int64) of the strided sample grid: ``s // 2, s // 2 + s, ...`` on each axis."""
    rows = np.arange(stride // 2, height, stride, dtype=np.int64)
    cols = np.arange(stride // 2, width, stride, dtype=np.int64)
    return rows, cols


def measurement_weight(phi, r, w_pole: float, r_half: float) -> np.ndarray:
    """``w_lat(phi) * w_range(r)`` (float64), phi radians latitude, r metres (see module docstring)."""
    phi = np.asarray(phi, dtype=np.float64)
    r = np.asarray(r, dtype=np.float64)
    return (1.0 - (1.0 - w_pole) * np.sin(phi) ** 2) / (1.0 + r / r_half)


def kernel_params(depth: np.ndarray, T_world_cam: np.ndarray, stride: int, alpha: float, beta: float,
                  min_range: float, max_range: float):
    """Lift the strided valid pixels of an ERP depth map and build their kernels.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid
    T_world_cam : (4, 4) float64
    stride : int, pixels

    Returns
    -------
    x_world : (n, 3) float64, metres, world frame
    E_world : (n, 3, 3) float64, columns = longitude, latitude, ray directions (world)
    sigma : (n, 3) float64, metres, kernel scales along those axes
    phi : (n,) float64 radians, r : (n,) float64 metres
    """
    H, W = depth.shape
    rows, cols = strided_pixels(W, H, stride)
    d = depth[np.ix_(rows, cols)].astype(np.float64)
    valid = (d > 0) & (d >= min_range) & (d <= max_range)
    vi, ui = np.nonzero(valid)
    r = d[vi, ui]
    theta, phi = pixel_to_angles(cols[ui], rows[vi], W, H)
    E_cam = local_frames(theta, phi)
    R = T_world_cam[:3, :3]
    E_world = np.einsum("ij,njk->nik", R, E_cam)
    x_world = r[:, None] * E_world[:, :, 2] + T_world_cam[:3, 3]
    dth = 2.0 * np.pi * stride / W
    dph = np.pi * stride / H
    sigma = np.stack([r * np.abs(np.cos(phi)) * dth, r * dph, alpha * r + beta], axis=-1)
    sigma = np.maximum(sigma, SIGMA_MIN)
    return x_world, E_world, sigma, phi, r


def kernel_inverse_cov(E_world: np.ndarray, sigma: np.ndarray):
    """Inverse covariances and bounding half-extents of the kernels.

    Returns
    -------
    P : (n, 3, 3) float64, ``Sigma^-1 = E diag(1 / sigma^2) E^T``, 1/m^2
    half : (n, 3) float64, metres, ``sqrt(diag Sigma)``; the d^2 <= kappa^2 ellipsoid lies within
        ``x +- kappa * half`` on each world axis
    """
    P = np.einsum("nik,nk,njk->nij", E_world, 1.0 / sigma ** 2, E_world)
    half = np.sqrt(np.einsum("nik,nk->ni", E_world ** 2, sigma ** 2))
    return P, half


N_CHUNKS = 2  # points are split into this many fixed chunks (deterministic whatever the thread count)


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
            i0 = max(int(np.ceil((px - kappa * half[p, 0]) / h - 0.5)) - lo[0], 0)
            i1 = min(int(np.floor((px + kappa * half[p, 0]) / h - 0.5)) - lo[0], nx - 1)
            j0 = max(int(np.ceil((py - kappa * half[p, 1]) / h - 0.5)) - lo[1], 0)
            j1 = min(int(np.floor((py + kappa * half[p, 1]) / h - 0.5)) - lo[1], ny - 1)
            k0 = max(int(np.ceil((pz - kappa * half[p, 2]) / h - 0.5)) - lo[2], 0)
            k1 = min(int(np.floor((pz + kappa * half[p, 2]) / h - 0.5)) - lo[2], nz - 1)
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
            i0 = max(int(np.ceil((px - ax) / h - 0.5)) - lo[0], 0)
            i1 = min(int(np.floor((px + ax) / h - 0.5)) - lo[0], nx - 1)
            j0 = max(int(np.ceil((py - ay) / h - 0.5)) - lo[1], 0)
            j1 = min(int(np.floor((py + ay) / h - 0.5)) - lo[1], ny - 1)
            k0 = max(int(np.ceil((pz - az) / h - 0.5)) - lo[2], 0)
            k1 = min(int(np.floor((pz + az) / h - 0.5)) - lo[2], nz - 1)
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


@nb.njit(cache=True)
def _splat_point(x, w, h, lo, grid):
    """Add each point's weight to the voxel that contains it."""
    nx, ny, nz = grid.shape
    for p in range(x.shape[0]):
        i = int(np.floor(x[p, 0] / h)) - lo[0]
        j = int(np.floor(x[p, 1] / h)) - lo[1]
        k = int(np.floor(x[p, 2] / h)) - lo[2]
        if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz:
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


@nb.njit(cache=True)
def _lift(d, theta, phi, R, t, dth, dph, alpha, beta, min_range, max_range, w_pole, r_half, c_norm):
    """Fast path of :func:`kernel_params` + :func:`kernel_inverse_cov` + weights on the strided grid."""
    nr, nc = d.shape
    n = 0
    for a in range(nr):
        for b in range(nc):
            r = d[a, b]
            if r > 0 and r >= min_range and r <= max_range:
                n += 1
    x = np.empty((n, 3))
    P = np.empty((n, 3, 3))
    half = np.empty((n, 3))
    w = np.empty(n)
    E = np.empty((3, 3))
    Ec = np.empty((3, 3))
    m = 0
    for a in range(nr):
        sp, cp = np.sin(phi[a]), np.cos(phi[a])
        for b in range(nc):
            r = np.float64(d[a, b])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            st, ct = np.sin(theta[b]), np.cos(theta[b])
            # camera-frame columns: e_theta, e_phi, e_ray (geometry.erp.local_frames)
            Ec[0, 0], Ec[1, 0], Ec[2, 0] = ct, 0.0, -st
            Ec[0, 1], Ec[1, 1], Ec[2, 1] = -sp * st, -cp, -sp * ct
            Ec[0, 2], Ec[1, 2], Ec[2, 2] = cp * st, -sp, cp * ct
            for i in range(3):
                for j in range(3):
                    E[i, j] = R[i, 0] * Ec[0, j] + R[i, 1] * Ec[1, j] + R[i, 2] * Ec[2, j]
            s0 = max(r * abs(cp) * dth, SIGMA_MIN)
            s1 = max(r * dph, SIGMA_MIN)
            s2 = max(alpha * r + beta, SIGMA_MIN)
            v0, v1, v2 = s0 * s0, s1 * s1, s2 * s2
            for i in range(3):
                x[m, i] = r * E[i, 2] + t[i]
                half[m, i] = np.sqrt(E[i, 0] ** 2 * v0 + E[i, 1] ** 2 * v1 + E[i, 2] ** 2 * v2)
                for j in range(3):
                    P[m, i, j] = E[i, 0] * E[j, 0] / v0 + E[i, 1] * E[j, 1] / v1 + E[i, 2] * E[j, 2] / v2
            w[m] = c_norm * (1.0 - (1.0 - w_pole) * sp * sp) / (1.0 + r / r_half)
            m += 1
    return x, P, half, w


def lift_kernels(depth: np.ndarray, T_world_cam: np.ndarray, stride: int, alpha: float, beta: float,
                 min_range: float, max_range: float, w_pole: float, r_half: float, c_norm: float):
    """Kernels of the strided valid pixels, compiled (same values as the numpy functions above).

    Returns
    -------
    x_world : (n, 3) float64 metres; P : (n, 3, 3) float64 1/m^2 (Sigma^-1); half : (n, 3) float64
    metres (sqrt diag Sigma); w : (n,) float64 (``c_norm * w_lat * w_range``)
    """
    H, W = depth.shape
    rows, cols = strided_pixels(W, H, stride)
    theta, _ = pixel_to_angles(cols, np.zeros_like(cols), W, H)
    _, phi = pixel_to_angles(np.zeros_like(rows), rows, W, H)
    d = np.ascontiguousarray(depth[np.ix_(rows, cols)])
    R = np.ascontiguousarray(T_world_cam[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(T_world_cam[:3, 3], dtype=np.float64)
    return _lift(d, theta, phi, R, t, 2.0 * np.pi * stride / W, np.pi * stride / H, float(alpha), float(beta),
                 float(min_range), float(max_range), float(w_pole), float(r_half), float(c_norm))
