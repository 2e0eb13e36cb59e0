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


# --------------------------------------------------------------------------------------------------
# Surfel-aligned kernel (GeometryParams.extent = "surfel")
# --------------------------------------------------------------------------------------------------

@nb.njit(cache=True, inline="always")
def _interp1(x, xp, fp):
    """``np.interp`` of one scalar (xp increasing), without an array allocation per call."""
    n = len(xp)
    if x <= xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    j = 1
    while xp[j] < x:
        j += 1
    t = (x - xp[j - 1]) / (xp[j] - xp[j - 1])
    return fp[j - 1] + t * (fp[j] - fp[j - 1])


@nb.njit(cache=True)
def _trig_tables(H, W):
    """sin / cos of every ERP row's latitude and every column's longitude (pixel centres)."""
    dth = 2.0 * np.pi / W
    dph = np.pi / H
    sphi, cphi = np.empty(H), np.empty(H)
    for vv in range(H):
        ph = 0.5 * np.pi - (vv + 0.5) * dph
        sphi[vv], cphi[vv] = np.sin(ph), np.cos(ph)
    sth, cth = np.empty(W), np.empty(W)
    for uu in range(W):
        th = (uu + 0.5) * dth - np.pi
        sth[uu], cth[uu] = np.sin(th), np.cos(th)
    return sphi, cphi, sth, cth


@nb.njit(cache=True, parallel=True)
def _raw_residuals(depth, stride, sub, min_range, max_range, sphi, cphi, sth, cth):
    """Per strided sample (every ``sub``-th of each axis) with valid neighbours (+-stride pixels) on both
    image axes: range r, the mean over the two axes of the squared distance to the line through the
    axis' two neighbours divided by 1.5, and |cos incidence| of the plane they span; -1 where a
    neighbour is missing."""
    H, W = depth.shape
    s0 = stride // 2
    nr = (H - s0 + stride * sub - 1) // (stride * sub)
    nc = (W - s0 + stride * sub - 1) // (stride * sub)
    rr = np.full((nr, nc), -1.0)
    res2 = np.full((nr, nc), -1.0)
    cinc = np.zeros((nr, nc))
    for a in nb.prange(nr):
        v = s0 + a * stride * sub
        p = np.empty(3)
        q = np.empty((2, 2, 3))
        for b in range(nc):
            u = s0 + b * stride * sub
            r = np.float64(depth[v, u])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            rr[a, b] = r
            if v - stride < 0 or v + stride >= H:
                continue
            p[0], p[1], p[2] = r * cphi[v] * sth[u], -r * sphi[v], r * cphi[v] * cth[u]
            ok = True
            for dirn in range(2):
                for side in range(2):
                    d = -stride if side == 0 else stride
                    vq, uq = (v, (u + d) % W) if dirn == 0 else (v + d, u)
                    rq = np.float64(depth[vq, uq])
                    if not rq > 0:
                        ok = False
                    q[dirn, side, 0] = rq * cphi[vq] * sth[uq]
                    q[dirn, side, 1] = -rq * sphi[vq]
                    q[dirn, side, 2] = rq * cphi[vq] * cth[uq]
            if not ok:
                continue
            acc = 0.0
            for dirn in range(2):
                l0, l1, l2 = (q[dirn, 1, 0] - q[dirn, 0, 0], q[dirn, 1, 1] - q[dirn, 0, 1],
                              q[dirn, 1, 2] - q[dirn, 0, 2])
                e0, e1, e2 = p[0] - q[dirn, 0, 0], p[1] - q[dirn, 0, 1], p[2] - q[dirn, 0, 2]
                x0, x1, x2 = e1 * l2 - e2 * l1, e2 * l0 - e0 * l2, e0 * l1 - e1 * l0
                acc += (x0 * x0 + x1 * x1 + x2 * x2) / max(l0 * l0 + l1 * l1 + l2 * l2, 1e-18)
            res2[a, b] = acc / 3.0  # mean over the 2 axes, / 1.5
            a0, a1, a2 = q[0, 1, 0] - q[0, 0, 0], q[0, 1, 1] - q[0, 0, 1], q[0, 1, 2] - q[0, 0, 2]
            b0, b1, b2 = q[1, 1, 0] - q[1, 0, 0], q[1, 1, 1] - q[1, 0, 1], q[1, 1, 2] - q[1, 0, 2]
            n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
            nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            if nn > 0:
                cinc[a, b] = abs(n0 * p[0] + n1 * p[1] + n2 * p[2]) / (nn * r)
    return rr, res2, cinc


@nb.njit(cache=True, parallel=True)
def _block_depths(depth, stride, min_range, max_range, fit_r, fit_s, k_res, res_abs, sel_rel):
    """Each strided sample's depth denoised over its s x s footprint, and the readings used.

    The footprint's valid pixels within ``sel_rel r + 4 sigma`` of the sample pixel's depth r (other
    objects left out) are fitted by least squares with a plane in pixel offsets, ``r' = c0 + c1 du + c2 dv``
    (du, dv from the sample pixel); where the fit's residual RMS is within ``k_res sigma + res_abs``
    (sigma the frame's radial noise at r: ``fit_r``, ``fit_s``) the sample's depth is c0 and its count
    the pixels fitted; elsewhere (a crease, an edge, fewer than 6 pixels) the raw depth and 1.
    Depth 0 and count 0 where the sample pixel is invalid. One pass: the residual sum of squares is
    ``sum e^2 - c . b`` of the normal equations, on depths taken relative to r."""
    H, W = depth.shape
    s0 = stride // 2
    nr = (H - s0 + stride - 1) // stride
    nc = (W - s0 + stride - 1) // stride
    rs = np.zeros((nr, nc))
    cnt = np.zeros((nr, nc), np.int64)
    for a in nb.prange(nr):
        v = s0 + a * stride
        for b in range(nc):
            u = s0 + b * stride
            r = np.float64(depth[v, u])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            rs[a, b] = r
            cnt[a, b] = 1
            sig = _interp1(r, fit_r, fit_s)
            tol = sel_rel * r + 4.0 * sig
            s00 = s01 = s02 = s11 = s12 = s22 = b0 = b1 = b2 = ee = 0.0
            m = 0
            for vv in range(v - s0, min(v - s0 + stride, H)):
                dv = np.float64(vv - v)
                for uu in range(u - s0, min(u - s0 + stride, W)):
                    e = np.float64(depth[vv, uu]) - r
                    if depth[vv, uu] > 0 and abs(e) <= tol:
                        du = np.float64(uu - u)
                        s00 += 1.0
                        s01 += du
                        s02 += dv
                        s11 += du * du
                        s12 += du * dv
                        s22 += dv * dv
                        b0 += e
                        b1 += e * du
                        b2 += e * dv
                        ee += e * e
                        m += 1
            if m < 6:
                continue
            det = (s00 * (s11 * s22 - s12 * s12) - s01 * (s01 * s22 - s12 * s02) + s02 * (s01 * s12 - s11 * s02))
            if abs(det) < 1e-9:
                continue
            c0 = (b0 * (s11 * s22 - s12 * s12) - s01 * (b1 * s22 - s12 * b2) + s02 * (b1 * s12 - s11 * b2)) / det
            c1 = (s00 * (b1 * s22 - s12 * b2) - b0 * (s01 * s22 - s12 * s02) + s02 * (s01 * b2 - b1 * s02)) / det
            c2 = (s00 * (s11 * b2 - b1 * s12) - s01 * (s01 * b2 - b1 * s02) + b0 * (s01 * s12 - s11 * s02)) / det
            ss = max(ee - (c0 * b0 + c1 * b1 + c2 * b2), 0.0)
            if np.sqrt(ss / (m - 3)) <= k_res * sig + res_abs and r + c0 > 0:
                rs[a, b] = r + c0
                cnt[a, b] = m
    return rs, cnt


@nb.njit(cache=True, parallel=True)
def _lift_surfel(depth, stride, R, t, alpha, beta, min_range, max_range, w_pole, r_half, c_norm, h, kappa,
                 n_floor, c_min, disc_k, fit, tol_abs, fit_r, fit_s, radial_fit, block, rs, bcnt, sphi, cphi, sth, cth):
    """Surfel kernels of the strided valid pixels (see :func:`lift_surfels`); sphi .. cth from
    :func:`_trig_tables`."""
    H, W = depth.shape
    dth = 2.0 * np.pi / W
    dph = np.pi / H
    s0 = stride // 2
    rows = np.arange(s0, H, stride)
    cols = np.arange(s0, W, stride)
    # per-row offsets into the outputs (rows run in parallel; the order is the serial one)
    start = np.zeros(len(rows) + 1, np.int64)
    for a in range(len(rows)):
        c = 0
        for u in cols:
            r = depth[rows[a], u]
            if r > 0 and r >= min_range and r <= max_range:
                c += 1
        start[a + 1] = start[a] + c
    n = start[-1]
    ncols = len(cols)
    x = np.empty((n, 3))
    Pt = np.empty((n, 3, 3))  # every entry is written below
    half = np.empty((n, 3))
    w = np.empty(n)
    ax = np.empty((n, 3))
    sa = np.empty(n)
    bb = np.empty(n)
    surf = np.zeros(n, np.uint8)
    k = stride  # normal from the neighbouring samples (+-stride pixels): a baseline robust to depth noise
    for a in nb.prange(len(rows)):
        v = rows[a]
        m = start[a]
        Ec = np.empty((3, 3))
        E = np.empty((3, 3))
        nrm = np.zeros(3)
        used = np.zeros((4, 3))
        tang = np.zeros((2, 3))
        q0 = np.zeros(3)
        q1 = np.zeros(3)
        t1 = np.zeros(3)
        t2 = np.zeros(3)
        w1 = np.zeros(3)
        sp, cp = sphi[v], cphi[v]
        for bi in range(ncols):
            u = cols[bi]
            r = np.float64(depth[v, u])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            mself = 1.0
            if block:  # the footprint-denoised depth
                mself = np.float64(bcnt[a, bi])
                r = rs[a, bi]
            st, ct = sth[u], cth[u]
            Ec[0, 0], Ec[1, 0], Ec[2, 0] = ct, 0.0, -st
            Ec[0, 1], Ec[1, 1], Ec[2, 1] = -sp * st, -cp, -sp * ct
            Ec[0, 2], Ec[1, 2], Ec[2, 2] = cp * st, -sp, cp * ct
            for i in range(3):
                for j in range(3):
                    E[i, j] = R[i, 0] * Ec[0, j] + R[i, 1] * Ec[1, j] + R[i, 2] * Ec[2, j]
            s_th = max(r * abs(cp) * dth * stride, SIGMA_MIN)
            s_ph = max(r * dph * stride, SIGMA_MIN)
            sr_prior = max(alpha * r + beta, SIGMA_MIN)
            sr = max(_interp1(r, fit_r, fit_s), SIGMA_MIN) if radial_fit else sr_prior
            pc0, pc1, pc2 = r * Ec[0, 2], r * Ec[1, 2], r * Ec[2, 2]
            for i in range(3):
                x[m, i] = R[i, 0] * pc0 + R[i, 1] * pc1 + R[i, 2] * pc2 + t[i]
            w[m] = c_norm * (1.0 - (1.0 - w_pole) * sp * sp) / (1.0 + r / r_half)
            # ---- local surface normal from the neighbouring samples (camera frame) ----
            # per image direction: the central difference where the depth is smooth (second difference
            # within tol), else the one-sided difference to the valid neighbour nearer in depth
            tol = disc_k * sr_prior + tol_abs
            nused = 0
            msum = mself
            nfit = mself  # depth readings averaged in the surfel's position
            ok = True
            for dirn in range(2):
                vv0, uu0, vv1, uu1 = v, (u - k) % W, v, (u + k) % W  # longitude: left, right
                if dirn == 1:
                    vv0, uu0, vv1, uu1 = v - k, u, v + k, u  # latitude: up, down
                r0 = depth[vv0, uu0] if 0 <= vv0 < H else np.float32(0.0)
                r1 = depth[vv1, uu1] if 0 <= vv1 < H else np.float32(0.0)
                use0 = r0 > 0
                use1 = r1 > 0
                # block neighbours: the samples a row / column of samples away
                ai = np.int64(a)
                ba0, bb0, ba1, bb1 = ai, (bi - 1) % ncols, ai, (bi + 1) % ncols
                if dirn == 1:
                    ba0, bb0, ba1, bb1 = ai - 1, bi, ai + 1, bi
                m0 = m1 = 1.0
                if block:
                    m0 = np.float64(bcnt[ba0, bb0]) if 0 <= ba0 < len(rows) else 0.0
                    m1 = np.float64(bcnt[ba1, bb1]) if 0 <= ba1 < len(rows) else 0.0
                    r0 = rs[ba0, bb0] if m0 > 0 else 0.0
                    r1 = rs[ba1, bb1] if m1 > 0 else 0.0
                    use0 = r0 > 0
                    use1 = r1 > 0
                if not (use0 or use1):
                    ok = False
                    break
                q0[0], q0[1], q0[2] = pc0, pc1, pc2
                q1[0], q1[1], q1[2] = pc0, pc1, pc2
                for side in range(2):
                    if (use0 if side == 0 else use1):
                        vq, uq, rq = (vv0, uu0, r0) if side == 0 else (vv1, uu1, r1)
                        pq0 = rq * cphi[vq] * sth[uq]
                        pq1 = -rq * sphi[vq]
                        pq2 = rq * cphi[vq] * cth[uq]
                        msum += m0 if side == 0 else m1
                        if side == 0:
                            q0[0], q0[1], q0[2] = pq0, pq1, pq2
                        else:
                            q1[0], q1[1], q1[2] = pq0, pq1, pq2
                        used[nused, 0], used[nused, 1], used[nused, 2] = pq0, pq1, pq2
                        nused += 1
                if use0 and use1:
                    # smooth surface: the sample lies within tol of the line through its two neighbours
                    l0, l1, l2 = q1[0] - q0[0], q1[1] - q0[1], q1[2] - q0[2]
                    e0, e1, e2 = pc0 - q0[0], pc1 - q0[1], pc2 - q0[2]
                    x0, x1, x2 = e1 * l2 - e2 * l1, e2 * l0 - e0 * l2, e0 * l1 - e1 * l0
                    if x0 * x0 + x1 * x1 + x2 * x2 > (tol * tol) * (l0 * l0 + l1 * l1 + l2 * l2):
                        ok = False  # a depth edge or a corner: the ray-aligned kernel
                        break
                for i in range(3):
                    tang[dirn, i] = q1[i] - q0[i]
            if ok:
                a0, a1, a2 = tang[0, 0], tang[0, 1], tang[0, 2]
                b0, b1, b2 = tang[1, 0], tang[1, 1], tang[1, 2]
                nc0, nc1, nc2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
                nn = np.sqrt(nc0 * nc0 + nc1 * nc1 + nc2 * nc2)
                if nn <= 0.0:
                    ok = False
                else:
                    for i in range(3):
                        nrm[i] = (R[i, 0] * nc0 + R[i, 1] * nc1 + R[i, 2] * nc2) / nn
                    if fit:
                        # centre the surfel on the plane through the centroid of the sample and the
                        # neighbours used: move x along n by the centroid's offset
                        off = 0.0
                        for q in range(nused):
                            off += (nc0 * (used[q, 0] - pc0) + nc1 * (used[q, 1] - pc1) + nc2 * (used[q, 2] - pc2)) / nn
                        off /= nused + 1.0
                        for i in range(3):
                            x[m, i] += off * nrm[i]
                        nfit = msum
            if ok:
                d0, d1, d2 = E[0, 2], E[1, 2], E[2, 2]
                cosi = nrm[0] * d0 + nrm[1] * d1 + nrm[2] * d2
                if cosi > 0:
                    nrm[0], nrm[1], nrm[2] = -nrm[0], -nrm[1], -nrm[2]
                    cosi = -cosi
                c = abs(cosi)
                # in-plane direction of the ray t1, and t2 = n x t1 (perpendicular to the ray too)
                u0, u1, u2 = d0 + c * nrm[0], d1 + c * nrm[1], d2 + c * nrm[2]  # d - (n.d) n
                un = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
                if un < 1e-9:
                    t1[0], t1[1], t1[2] = E[0, 0], E[1, 0], E[2, 0]
                else:
                    t1[0], t1[1], t1[2] = u0 / un, u1 / un, u2 / un
                t2[0] = nrm[1] * t1[2] - nrm[2] * t1[1]
                t2[1] = nrm[2] * t1[0] - nrm[0] * t1[2]
                t2[2] = nrm[0] * t1[1] - nrm[1] * t1[0]
                # w1 = t2 x d: the direction perpendicular to the ray whose footprint stretches onto t1
                w1[0], w1[1], w1[2] = t2[1] * d2 - t2[2] * d1, t2[2] * d0 - t2[0] * d2, t2[0] * d1 - t2[1] * d0
                g1t = w1[0] * E[0, 0] + w1[1] * E[1, 0] + w1[2] * E[2, 0]
                g1p = w1[0] * E[0, 1] + w1[1] * E[1, 1] + w1[2] * E[2, 1]
                g2t = t2[0] * E[0, 0] + t2[1] * E[1, 0] + t2[2] * E[2, 0]
                g2p = t2[0] * E[0, 1] + t2[1] * E[1, 1] + t2[2] * E[2, 1]
                vt, vp = s_th * s_th, s_ph * s_ph
                cs = max(c, c_min)
                q11 = (vt * g1t * g1t + vp * g1p * g1p) / (cs * cs)
                q12 = (vt * g1t * g2t + vp * g1p * g2p) / cs
                q22 = vt * g2t * g2t + vp * g2p * g2p
                det = q11 * q22 - q12 * q12
                i11, i12, i22 = q22 / det, -q12 / det, q11 / det
                sn = sr * c / np.sqrt(nfit) + n_floor
                b = 0.5 * h * (abs(nrm[0]) + abs(nrm[1]) + abs(nrm[2]))
                for i in range(3):
                    ax[m, i] = nrm[i]
                    for j in range(3):
                        Pt[m, i, j] = (i11 * t1[i] * t1[j] + i12 * (t1[i] * t2[j] + t2[i] * t1[j])
                                       + i22 * t2[i] * t2[j])
                    cov_ii = q11 * t1[i] * t1[i] + 2.0 * q12 * t1[i] * t2[i] + q22 * t2[i] * t2[i]
                    half[m, i] = kappa * np.sqrt(cov_ii) + (b + kappa * sn) * abs(nrm[i])
                sa[m] = sn
                bb[m] = b
                surf[m] = 1
            else:
                # ray-aligned fallback (the "box" kernel): tangential Gaussian, chord probability along the ray
                vt, vp = s_th * s_th, s_ph * s_ph
                b = 0.5 * h / max(abs(E[0, 2]), abs(E[1, 2]), abs(E[2, 2]))
                for i in range(3):
                    ax[m, i] = E[i, 2]
                    for j in range(3):
                        Pt[m, i, j] = E[i, 0] * E[j, 0] / vt + E[i, 1] * E[j, 1] / vp
                    half[m, i] = kappa * np.sqrt(E[i, 0] ** 2 * vt + E[i, 1] ** 2 * vp) + (b + kappa * sr) * abs(E[i, 2])
                sa[m] = sr
                bb[m] = b
            m += 1
    return x, Pt, half, w, ax, sa, bb, surf


def lift_surfels(depth: np.ndarray, T_world_cam: np.ndarray, stride: int, alpha: float, beta: float,
                 min_range: float, max_range: float, w_pole: float, r_half: float, c_norm: float,
                 voxel_size: float, kappa: float, n_floor: float, c_min: float, disc_k: float,
                 fit: bool = True, tol_abs: float = 0.0, radial_fit: bool = False, block: bool = False,
                 block_k: float = 2.0, block_abs: float = 0.0005, block_sel: float = 0.05):
    """Surfel-aligned kernels of the strided valid pixels (``GeometryParams.extent = "surfel"``).

    The local surface normal n of each sample comes from its neighbouring samples (+-stride pixels,
    longitude wraps): per image axis the central difference, or the one-sided difference where one
    neighbour is invalid or outside the image. The kernel is a Gaussian within the surface plane whose
    covariance is the ERP pixel footprint (``r |cos phi| dtheta``, ``r dphi``, dtheta, dphi at the
    stride) projected along the ray onto the plane (stretched by ``1 / max(|cos i|, c_min)`` along the
    ray's in-plane direction, i = incidence), times the probability that the plane, displaced along n
    with scale ``s_n = sigma_r |cos i| / sqrt(m) + n_floor``, passes through the voxel's box
    (half-support ``b = (h / 2) |n|_1`` along n); ``sigma_r`` is the radial depth noise at the sample's
    range: ``alpha r + beta``, or with ``radial_fit`` the noise fitted to this frame's own depth
    (:func:`radial_noise_fit`). A sample farther than ``disc_k (alpha r + beta) + tol_abs`` from the
    line through its two neighbours (per image axis) marks a depth edge or a corner; there, and where
    both neighbours of an axis are invalid, the sample keeps the ray-aligned ``box`` kernel (axis = ray,
    b = the voxel's chord half-length, scale sigma_r).

    With ``block`` each sample stands for its whole s x s footprint: its depth is the value at the
    sample pixel of a plane fitted by least squares to the footprint's pixels on its surface
    (:func:`_block_depths`; accepted where the fit's residual is within ``block_k sigma_r + block_abs``,
    else the raw depth), normals come from the neighbours' fitted depths, and ``m`` is the number of
    pixels fitted: the surfel's offset averages ~s^2 readings instead of one. With ``fit`` the surfel
    is also centred on the plane through the sample and the neighbours used (moved along n by their
    centroid's offset; m counts every reading in that fit). Defaults: block on, fit off.

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid; T_world_cam : (4, 4) float64

    Returns
    -------
    x_world : (n, 3) float64 metres; Pt : (n, 3, 3) float64 1/m^2, tangential inverse covariance
    (rank 2, zero along the axis); half : (n, 3) float64 metres, half-extents of the kernel's support
    on each world axis; w : (n,) float64; axis : (n, 3) float64 unit (normal or ray), world;
    s_axis : (n,) float64 metres; b : (n,) float64 metres; surfel : (n,) uint8, 1 where the normal was used
    """
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    R = np.ascontiguousarray(T_world_cam[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(T_world_cam[:3, 3], dtype=np.float64)
    H, W = depth.shape
    tables = _trig_tables(H, W)
    fit_r, fit_s = np.zeros(1), np.full(1, SIGMA_FLOOR)
    if radial_fit or block:
        if radial_fit:
            rr, res2, cinc = _raw_residuals(depth, int(stride), FIT_SUB, float(min_range), float(max_range), *tables)
            fit_r, fit_s = radial_noise_fit(rr.ravel(), res2.ravel(), cinc.ravel(), min_range, max_range)
        else:  # the block tolerance from the noise model alpha r + beta
            fit_r = np.array([0.0, max_range])
            fit_s = np.array([beta, alpha * max_range + beta])
    if block:
        rs, bcnt = _block_depths(depth, int(stride), float(min_range), float(max_range), fit_r, fit_s,
                                 float(block_k), float(block_abs), float(block_sel))
    else:
        rs, bcnt = np.zeros((1, 1)), np.zeros((1, 1), np.int64)
    return _lift_surfel(depth, int(stride), R, t, float(alpha), float(beta), float(min_range), float(max_range),
                        float(w_pole), float(r_half), float(c_norm), float(voxel_size), float(kappa),
                        float(n_floor), float(c_min), float(disc_k), bool(fit), float(tol_abs), fit_r, fit_s,
                        bool(radial_fit), bool(block), rs, bcnt, *tables)


SIGMA_FLOOR = 3e-4  # metres; floor of a fitted radial noise (the millimetre depth PNG's quantisation)
FIT_BIN = 0.5  # metres; range bins of the radial noise fit
FIT_MIN_SAMPLES = 50  # a range bin needs this many smooth samples to be fitted
FIT_SUB = 2  # the fit uses every FIT_SUB-th strided sample of each image axis
FIT_QUANTILE = 0.25  # robust scale: this quantile of the normalised squared residuals ...
FIT_Q_EXP = -np.log(1.0 - FIT_QUANTILE)  # ... over the same quantile of chi^2_2 / 2 (an Exp(1))


@nb.njit(cache=True)
def _binned_quantiles(r, res2, cinc, c_min, edges, q, min_count):
    """Per range bin [edges[i], edges[i + 1]) with at least ``min_count`` samples (res2 >= 0, cinc >=
    c_min): the bin centre, the q-quantile (lower) of ``res2 / cinc^2`` and the count."""
    nb_ = len(edges) - 1
    counts = np.zeros(nb_, np.int64)
    idx = np.full(len(r), -1, np.int64)
    for i in range(len(r)):
        if res2[i] >= 0 and cinc[i] >= c_min and edges[0] <= r[i] < edges[nb_]:
            k = min(int((r[i] - edges[0]) / (edges[1] - edges[0])), nb_ - 1)
            idx[i] = k
            counts[k] += 1
    start = np.zeros(nb_ + 1, np.int64)
    for k in range(nb_):
        start[k + 1] = start[k] + counts[k]
    vals = np.empty(start[nb_])
    fill = start[:-1].copy()
    for i in range(len(r)):
        k = idx[i]
        if k >= 0:
            vals[fill[k]] = res2[i] / (cinc[i] * cinc[i])
            fill[k] += 1
    m = 0
    for k in range(nb_):
        if counts[k] >= min_count:
            m += 1
    centres = np.empty(m)
    qs = np.empty(m)
    cn = np.empty(m, np.int64)
    j = 0
    for k in range(nb_):
        if counts[k] >= min_count:
            kth = int(q * (counts[k] - 1))  # the kth smallest: a selection, not a sort
            centres[j] = 0.5 * (edges[k] + edges[k + 1])
            qs[j] = np.partition(vals[start[k]:start[k + 1]], kth)[kth]
            cn[j] = counts[k]
            j += 1
    return centres, qs, cn


def _isotonic(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-decreasing fit of y (pool adjacent violators)."""
    vals, wts, lens = [], [], []
    for yi, wi in zip(y, w):
        vals.append(float(yi))
        wts.append(float(wi))
        lens.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            v2, w2, l2 = vals.pop(), wts.pop(), lens.pop()
            vals[-1] = (vals[-1] * wts[-1] + v2 * w2) / (wts[-1] + w2)
            wts[-1] += w2
            lens[-1] += l2
    return np.repeat(vals, lens)


def radial_noise_fit(r: np.ndarray, res2: np.ndarray, cinc: np.ndarray, min_range: float,
                     max_range: float, c_min: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Radial depth noise as a function of range, fitted to one frame's own depth.

    On a smooth surface a sample's distance to the line through its two neighbours is
    ``(e_0 - (e_- + e_+) / 2) cos i`` for radial errors ``e`` along nearly parallel rays, of variance
    ``1.5 sigma_r^2 cos^2 i`` (``res2`` arrives divided by 1.5 and averaged over the two image axes, so
    ``res2 / (sigma_r^2 cos^2 i)`` is chi^2_2 / 2, an Exp(1)). Per range bin of ``FIT_BIN`` metres with
    at least ``FIT_MIN_SAMPLES`` samples (|cos i| >= c_min), ``sigma_r^2`` is the ``FIT_QUANTILE``
    quantile of ``res2 / cos^2 i`` over the same quantile of Exp(1): a low quantile, because depth
    edges, creases and curvature only ever add residual. The bins' values are then made
    non-decreasing in range (weighted by their sample counts; sensor noise grows with range) and
    floored at ``SIGMA_FLOOR``.

    Parameters
    ----------
    r : (n,) float64 metres; res2 : (n,) float64 m^2, squared residual (< 0 = none); cinc : (n,) float64

    Returns
    -------
    ranges : (k,) float64 metres, bin centres; sigma : (k,) float64 metres (k >= 1; use ``np.interp``)
    """
    edges = np.arange(min_range, max_range + FIT_BIN, FIT_BIN)
    centres, var, counts = _binned_quantiles(np.ascontiguousarray(r, np.float64), np.ascontiguousarray(res2, np.float64),
                                             np.ascontiguousarray(cinc, np.float64), float(c_min), edges,
                                             FIT_QUANTILE, FIT_MIN_SAMPLES)
    centres, var, counts = list(centres), list(var / FIT_Q_EXP), list(counts)
    if not centres:
        return np.zeros(1), np.full(1, SIGMA_FLOOR)
    sig = np.maximum(np.sqrt(_isotonic(np.array(var), np.array(counts))), SIGMA_FLOOR)
    return np.array(centres), sig


def surfels_for(depth: np.ndarray, T_world_cam: np.ndarray, p, c_norm: float):
    """:func:`lift_surfels` with the parameters of a :class:`~.params.GeometryParams` ``p``."""
    return lift_surfels(depth, T_world_cam, p.stride, p.alpha, p.beta, p.min_range, p.max_range, p.w_pole,
                        p.r_half, c_norm, p.voxel_size, p.kappa, p.n_floor, p.c_min, p.disc_k, p.surfel_fit,
                        p.edge_abs, p.radial == "fit", p.block, p.block_k, p.block_abs, p.block_sel)


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
