"""The ray-aligned kernel lift (the paper's Sigma; extents ``box`` / ``centre`` and the ``point`` ablation).

Each valid strided pixel p (stride s) with radial depth r is lifted to ``x = R (r d) + t`` and
modelled as a Gaussian aligned with its spherical viewing geometry::

    sigma = [r |cos phi| dtheta, r dphi, alpha r + beta]      (longitude, latitude, ray)
    dtheta = 2 pi s / W,  dphi = pi s / H
    Sigma = E diag(sigma^2) E^T

with E the (longitude, latitude, ray) directions in the world frame and the weight
``omega = c_norm w_lat(phi) w_range(r)``, ``w_lat = 1 - (1 - w_pole) sin^2 phi``,
``w_range = 1 / (1 + r / r_half)``. A numpy transcription of the same maths, used to test this compiled
one, lives in tests/psvf_reference.py.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...geometry.erp import cam_frame, trig_tables

SIGMA_MIN = 1e-4  # metres; floor of a kernel axis (the longitude axis vanishes at the poles)


def strided_pixels(width: int, height: int, stride: int):
    """Rows and columns (int64) of the strided sample grid: ``s // 2, s // 2 + s, ...`` on each axis."""
    rows = np.arange(stride // 2, height, stride, dtype=np.int64)
    cols = np.arange(stride // 2, width, stride, dtype=np.int64)
    return rows, cols


@nb.njit(cache=True)
def _lift(d, rows, cols, sphi, cphi, sth, cth, R, t, dth, dph, alpha, beta, min_range, max_range, w_pole, r_half,
          c_norm):
    """Kernels (x, Sigma^-1, half-extents, weights) of the strided depths ``d`` (rows / cols of the image;
    sphi .. cth from :func:`~panovocc_cli.geometry.erp.trig_tables`)."""
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
        sp, cp = sphi[rows[a]], cphi[rows[a]]
        for b in range(nc):
            r = np.float64(d[a, b])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            cam_frame(sp, cp, sth[cols[b]], cth[cols[b]], Ec)  # camera-frame e_theta, e_phi, e_ray
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
    """Kernels of the strided valid pixels (the numpy reference of the tests computes the same values).

    Returns
    -------
    x_world : (n, 3) float64 metres; P : (n, 3, 3) float64 1/m^2 (Sigma^-1); half : (n, 3) float64
    metres (sqrt diag Sigma); w : (n,) float64 (``c_norm * w_lat * w_range``)
    """
    H, W = depth.shape
    rows, cols = strided_pixels(W, H, stride)
    d = np.ascontiguousarray(depth[np.ix_(rows, cols)])
    R = np.ascontiguousarray(T_world_cam[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(T_world_cam[:3, 3], dtype=np.float64)
    return _lift(d, rows, cols, *trig_tables(H, W), R, t, 2.0 * np.pi * stride / W, np.pi * stride / H, float(alpha), float(beta),
                 float(min_range), float(max_range), float(w_pole), float(r_half), float(c_norm))

