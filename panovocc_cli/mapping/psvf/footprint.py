"""The footprint plane fit: each strided sample's depth denoised over its s x s footprint.

A strided sample stands for the s x s pixels around it. Its depth becomes the value at the sample
pixel of a least-squares plane (in pixel offsets) through the footprint's pixels on its surface,
accepted when the fit's residual is within the frame's noise (a crease, an edge or too few pixels keep
the raw depth); the count of pixels fitted (``m``) sets the surfel's scale along its normal.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from .noise_fit import interp1

@nb.njit(cache=True, parallel=True)
def _block_depths(depth, stride, min_range, max_range, fit_r, fit_s, k_res, res_abs, sel_rel, inverse=False):
    """Each strided sample's depth denoised over its s x s footprint, and the readings used.

    The footprint's valid pixels within ``sel_rel r + 4 sigma`` of the sample pixel's depth r (other
    objects left out) are fitted by least squares with a plane in pixel offsets, ``r' = c0 + c1 du + c2 dv``
    (du, dv from the sample pixel); where the fit's residual RMS is within ``k_res sigma + res_abs``
    (sigma the frame's radial noise at r: ``fit_r``, ``fit_s``) the sample's depth is c0 and its count
    the pixels fitted; elsewhere (a crease, an edge, fewer than 6 pixels) the raw depth and 1.
    Depth 0 and count 0 where the sample pixel is invalid. One pass: the residual sum of squares is
    ``sum e^2 - c . b`` of the normal equations, on depths taken relative to r.

    With ``inverse`` the plane is fitted to inverse depth instead (``e = r (1 - r / r_pixel)``, linear
    in 1 / r_pixel and equal to ``r_pixel - r`` to first order): on a plane seen obliquely 1 / r is
    nearly linear in the pixel angles while r is convex, so a linear fit of r reads the plane up to
    ~1 mm too far at 3 m and 70 deg incidence (every fitted sample behind the surface, the same side
    of a voxel face the surface lies on), a fit of 1 / r ~0.05 mm."""
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
            sig = interp1(r, fit_r, fit_s)
            tol = sel_rel * r + 4.0 * sig
            s00 = s01 = s02 = s11 = s12 = s22 = b0 = b1 = b2 = ee = 0.0
            m = 0
            for vv in range(v - s0, min(v - s0 + stride, H)):
                dv = np.float64(vv - v)
                for uu in range(u - s0, min(u - s0 + stride, W)):
                    e = np.float64(depth[vv, uu]) - r
                    if depth[vv, uu] > 0 and abs(e) <= tol:
                        if inverse:
                            e = r - r * r / np.float64(depth[vv, uu])
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
            if np.sqrt(ss / (m - 3)) <= k_res * sig + res_abs and r + c0 > 0 and (not inverse or c0 < r):
                rs[a, b] = r * r / (r - c0) if inverse else r + c0
                cnt[a, b] = m
    return rs, cnt

