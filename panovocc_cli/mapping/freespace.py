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

from ..geometry.erp import cam_pixel, trig_tables


@nb.njit(cache=True, inline="always", error_model="numpy")
def _free_threshold(ro, q0, q1, q2, q3, eps_abs, eps_rel, stable_k, extent, sp, cp, st, ct, dth, dph, h, Rt):
    """A pixel's carving threshold: a voxel at range r projecting into it (and compared) is carved iff
    ``r < ro - eps`` and not ``r > fthr``. ``fthr = -inf`` where the neighbourhood (q0 left, q1 right,
    q2 up, q3 down; float32 like ro) is unstable or ro invalid; else ``ro - eps``, and with ``extent``
    minus the voxel box's half-support along the local plane's normal, ``(h / 2) |R n|_1``."""
    eps = eps_abs + eps_rel * ro
    tol = stable_k * eps
    bad = ((ro <= 0.0) | (q0 <= 0.0) | (abs(q0 - ro) > tol) | (q1 <= 0.0) | (abs(q1 - ro) > tol)
           | (q2 <= 0.0) | (abs(q2 - ro) > tol) | (q3 <= 0.0) | (abs(q3 - ro) > tol))
    v = ro - eps
    if extent:
        # local plane from the neighbour depths: n ~ d - a e_theta - b e_phi, with
        # a = (dr / r) per unit arc along longitude, b along latitude (camera frame)
        cphi = max(cp, 1e-3)
        a = (q1 - q0) / (2.0 * ro * dth * cphi)
        b = (q2 - q3) / (2.0 * ro * dph)
        nxc = cp * st - a * ct + b * sp * st
        nyc = -sp + b * cp
        nzc = cp * ct + a * st + b * sp * ct
        # world components (R = Rt^T) and the box half-support along n / cos(incidence)
        l1 = (abs(Rt[0, 0] * nxc + Rt[1, 0] * nyc + Rt[2, 0] * nzc)
              + abs(Rt[0, 1] * nxc + Rt[1, 1] * nyc + Rt[2, 1] * nzc)
              + abs(Rt[0, 2] * nxc + Rt[1, 2] * nyc + Rt[2, 2] * nzc))
        v = ro - eps - 0.5 * h * l1
    return -np.inf if bad else v


@nb.njit(cache=True, parallel=True, error_model="numpy")
def _free_thresholds(depth, Rt, h, eps_abs, eps_rel, stable_k, extent):
    """(H, W) float64 map of :func:`_free_threshold` (longitude wraps, latitude clamps). Interior
    columns run as a branch-free, vectorised loop."""
    H, W = depth.shape
    dth = 2.0 * np.pi / W
    dph = np.pi / H
    sphi, cphi, st, ct = trig_tables(H, W)
    fthr = np.empty((H, W))
    for row in nb.prange(H):
        sp, cp = sphi[row], cphi[row]
        cur, up, dn, out = depth[row], depth[max(row - 1, 0)], depth[min(row + 1, H - 1)], fthr[row]
        for col in (0, W - 1):  # the wrapping columns
            cl = col - 1 if col > 0 else W - 1
            cr = col + 1 if col < W - 1 else 0
            out[col] = _free_threshold(cur[col], cur[cl], cur[cr], up[col], dn[col], eps_abs, eps_rel, stable_k,
                                       extent, sp, cp, st[col], ct[col], dth, dph, h, Rt)
        for col in range(1, W - 1):
            out[col] = _free_threshold(cur[col], cur[col - 1], cur[col + 1], up[col], dn[col], eps_abs, eps_rel,
                                       stable_k, extent, sp, cp, st[col], ct[col], dth, dph, h, Rt)
    return fthr


@nb.njit(cache=True, parallel=True, error_model="numpy")
def _carve(depth, fthr, Rt, t, h, lo, nx, ny, nz, min_range, max_range, eps_abs, eps_rel, F, O):
    """Exhaustive test, per voxel. Each (i, j) column of nz voxels is first projected in a branch-free
    loop (vectorised by LLVM: the same IEEE operations in the same order as a scalar loop, so the same
    bits), then tested voxel by voxel against the depth and the pixel's free threshold ``fthr``."""
    H, W = depth.shape
    czs = np.empty(nz)
    for k in range(nz):
        czs[k] = (k + lo[2] + 0.5) * h - t[2]
    r00, r01, r02 = Rt[0, 0], Rt[0, 1], Rt[0, 2]
    r10, r11, r12 = Rt[1, 0], Rt[1, 1], Rt[1, 2]
    r20, r21, r22 = Rt[2, 0], Rt[2, 1], Rt[2, 2]
    for i in nb.prange(nx):
        rr = np.empty(nz)
        rows = np.empty(nz, np.int64)
        cols = np.empty(nz, np.int64)
        cx = (i + lo[0] + 0.5) * h - t[0]
        for j in range(ny):
            cy = (j + lo[1] + 0.5) * h - t[1]
            # p = R^T (c - t), summed left to right: (a x + b y) + c z
            s0 = r00 * cx + r01 * cy
            s1 = r10 * cx + r11 * cy
            s2 = r20 * cx + r21 * cy
            for k in range(nz):
                cz = czs[k]
                rr[k], rows[k], cols[k] = cam_pixel(s0 + r02 * cz, s1 + r12 * cz, s2 + r22 * cz, H, W)
            for k in range(nz):
                r = rr[k]
                if r < min_range or r > max_range:
                    continue
                row, col = rows[k], cols[k]
                ro = depth[row, col]
                if ro <= 0.0:
                    continue
                eps = eps_abs + eps_rel * ro
                if r > ro + eps:
                    continue
                O[i, j, k] = 1
                if r < ro - eps and not r > fthr[row, col]:
                    F[i, j, k] = 1


def free_thresholds(depth: np.ndarray, T_world_cam: np.ndarray, voxel_size: float, eps_abs: float, eps_rel: float,
                    stable_k: float, extent: bool = True) -> np.ndarray:
    """The frame's per-pixel carving thresholds (H, W) float64 (:func:`_free_threshold`): what :func:`carve`
    computes once per frame and passes to each part of the frame box it tests (``fthr``)."""
    Rt = np.ascontiguousarray(T_world_cam[:3, :3].T)
    return _free_thresholds(np.ascontiguousarray(depth, dtype=np.float32), Rt, float(voxel_size), float(eps_abs),
                            float(eps_rel), float(stable_k), bool(extent))


def carve(depth: np.ndarray, T_world_cam: np.ndarray, voxel_size: float, lo: np.ndarray, shape, eps_abs: float,
          eps_rel: float, stable_k: float, min_range: float, max_range: float, extent: bool = True, fthr=None):
    """Free-space test of every voxel of a dense frame-local grid (see module docstring).

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid (full resolution, not strided)
    T_world_cam : (4, 4) float64
    lo : (3,) int64, lattice index of grid cell [0, 0, 0]; shape : (3,) int

    extent : bool, require the voxel's whole box in front of the observed local plane
    fthr : (H, W) float64, the frame's :func:`free_thresholds` when the caller has them (a frame box tested a
        slab at a time); computed here otherwise

    Returns
    -------
    F, O : (X, Y, Z) uint8, 1 where the frame gives free-space evidence / a valid comparison
    """
    shape = tuple(int(s) for s in shape)
    F = np.zeros(shape, np.uint8)
    O = np.zeros(shape, np.uint8)
    Rt = np.ascontiguousarray(T_world_cam[:3, :3].T)
    t = np.ascontiguousarray(T_world_cam[:3, 3])
    depth = np.ascontiguousarray(depth, dtype=np.float32)
    lo = np.asarray(lo, np.int64)
    if fthr is None:
        fthr = free_thresholds(depth, T_world_cam, voxel_size, eps_abs, eps_rel, stable_k, extent)
    _carve(depth, fthr, Rt, t, float(voxel_size), lo, shape[0], shape[1], shape[2], float(min_range),
           float(max_range), float(eps_abs), float(eps_rel), F, O)
    return F, O
