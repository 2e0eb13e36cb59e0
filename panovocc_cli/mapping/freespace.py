"""Free-space evidence of one ERP frame: the paper's projection test, on a frame-defined voxel set.

Every voxel of the frame's region (the box around the camera and its kernels, cut at ``max_range``)
is projected into the frame's full-resolution radial depth map. With ``r`` the camera-to-centre
range and ``r_obs`` the depth at the pixel containing the projection, ``eps(r) = eps_abs + eps_rel r``:

* invalid depth (0) at that pixel: no comparison, nothing recorded;
* ``r > r_obs + eps(r_obs)`` (behind the surface, occluded): nothing recorded;
* otherwise a valid comparison: ``dO = 1``; and ``dF = 1`` as well when ``r < r_obs - eps(r_obs)``
  and the depth neighbourhood is stable: the 4 neighbours of the pixel (longitude wraps) are valid and
  within ``stable_k * eps(r_obs)`` of ``r_obs``; with ``extent`` (default) the voxel's whole box must
  also lie in front of the local plane fitted from those neighbours:
  ``r < r_obs - eps - (h / 2) |R n|_1`` with ``n = d - a e_theta - b e_phi`` (a, b: depth slopes per
  radian of arc, relative to r_obs), i.e. the box's half-support along the normal over cos(incidence).

Every voxel a ray of this frame passes through (up to its surface minus eps) is projected and so
carved: this is the frame's ray traversal, done exhaustively voxel by voxel rather than by marching
strided rays, so no voxel between two rays is missed. The paper projects the memory's "active"
voxels; testing the frame's own region instead makes each frame's delta a function of that frame and
its pose alone, which the reversible update needs (re-integrating a frame after a pose revision must
give what integrating it first would have). Occluded voxels are left out of O to keep deltas small.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def _atan2(y, x):
    """atan2 by a minimax polynomial (|error| < 1e-5 rad, 1/600 of a pixel at 1024 wide); deterministic."""
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    if mx == 0.0:
        return 0.0
    a = min(ax, ay) / mx
    s = a * a
    r = ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a + 0.99997726 * a
    if ay > ax:
        r = 0.5 * np.pi - r
    if x < 0.0:
        r = np.pi - r
    if y < 0.0:
        r = -r
    return r


@nb.njit(cache=True, parallel=True)
def _carve(depth, Rt, t, h, lo, nx, ny, nz, eps_abs, eps_rel, stable_k, min_range, max_range, extent, F, O):
    H, W = depth.shape
    two_pi = 2.0 * np.pi
    dth = two_pi / W
    dph = np.pi / H
    for i in nb.prange(nx):
        cx = (i + lo[0] + 0.5) * h - t[0]
        for j in range(ny):
            cy = (j + lo[1] + 0.5) * h - t[1]
            for k in range(nz):
                cz = (k + lo[2] + 0.5) * h - t[2]
                # camera frame: p = R^T (c - t)
                px = Rt[0, 0] * cx + Rt[0, 1] * cy + Rt[0, 2] * cz
                py = Rt[1, 0] * cx + Rt[1, 1] * cy + Rt[1, 2] * cz
                pz = Rt[2, 0] * cx + Rt[2, 1] * cy + Rt[2, 2] * cz
                r = np.sqrt(px * px + py * py + pz * pz)
                if r < min_range or r > max_range:
                    continue
                theta = _atan2(px, pz)
                phi = _atan2(-py, np.sqrt(px * px + pz * pz))
                col = int(np.floor((theta + np.pi) * W / two_pi)) % W
                row = int(np.floor((0.5 * np.pi - phi) * H / np.pi))
                if row < 0:
                    row = 0
                elif row >= H:
                    row = H - 1
                ro = depth[row, col]
                if ro <= 0.0:
                    continue
                eps = eps_abs + eps_rel * ro
                if r > ro + eps:
                    continue
                O[i, j, k] = 1
                if r < ro - eps:
                    tol = stable_k * eps
                    ok = True
                    cl = col - 1 if col > 0 else W - 1
                    cr = col + 1 if col < W - 1 else 0
                    rn = (depth[row, cl], depth[row, cr], depth[max(row - 1, 0), col], depth[min(row + 1, H - 1), col])
                    for q in rn:
                        if q <= 0.0 or abs(q - ro) > tol:
                            ok = False
                    if ok and extent:
                        # local plane from the neighbour depths: n ~ d - a e_theta - b e_phi, with
                        # a = (dr / r) per unit arc along longitude, b along latitude (camera frame)
                        phi_c = 0.5 * np.pi - (row + 0.5) * dph
                        cphi = max(np.cos(phi_c), 1e-3)
                        a = (rn[1] - rn[0]) / (2.0 * ro * dth * cphi)
                        b = (rn[2] - rn[3]) / (2.0 * ro * dph)
                        th_c = (col + 0.5) * dth - np.pi
                        st, ct = np.sin(th_c), np.cos(th_c)
                        sp, cp = np.sin(phi_c), np.cos(phi_c)
                        nxc = cp * st - a * ct + b * sp * st
                        nyc = -sp + b * cp
                        nzc = cp * ct + a * st + b * sp * ct
                        # world components (R = Rt^T) and the box half-support along n / cos(incidence)
                        l1 = (abs(Rt[0, 0] * nxc + Rt[1, 0] * nyc + Rt[2, 0] * nzc)
                              + abs(Rt[0, 1] * nxc + Rt[1, 1] * nyc + Rt[2, 1] * nzc)
                              + abs(Rt[0, 2] * nxc + Rt[1, 2] * nyc + Rt[2, 2] * nzc))
                        if r > ro - eps - 0.5 * h * l1:
                            ok = False
                    if ok:
                        F[i, j, k] = 1


def carve(depth: np.ndarray, T_world_cam: np.ndarray, voxel_size: float, lo: np.ndarray, shape, eps_abs: float,
          eps_rel: float, stable_k: float, min_range: float, max_range: float, extent: bool = True):
    """Free-space test of every voxel of a dense frame-local grid (see module docstring).

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid (full resolution, not strided)
    T_world_cam : (4, 4) float64
    lo : (3,) int64, lattice index of grid cell [0, 0, 0]; shape : (3,) int

    extent : bool, require the voxel's whole box in front of the observed local plane

    Returns
    -------
    F, O : (X, Y, Z) uint8, 1 where the frame gives free-space evidence / a valid comparison
    """
    shape = tuple(int(s) for s in shape)
    F = np.zeros(shape, np.uint8)
    O = np.zeros(shape, np.uint8)
    Rt = np.ascontiguousarray(T_world_cam[:3, :3].T)
    t = np.ascontiguousarray(T_world_cam[:3, 3])
    _carve(np.ascontiguousarray(depth, dtype=np.float32), Rt, t, float(voxel_size), np.asarray(lo, np.int64),
           shape[0], shape[1], shape[2], float(eps_abs), float(eps_rel), float(stable_k), float(min_range),
           float(max_range), bool(extent), F, O)
    return F, O
