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

from ..geometry.erp import trig_tables


@nb.njit(cache=True, inline="always", error_model="numpy")
def _atan2(y, x):
    """atan2 by a minimax polynomial (|error| < 1e-5 rad, 1/600 of a pixel at 1024 wide); deterministic.

    Written with selects, no branches, so that loops calling it vectorise (same values either way)."""
    ax, ay = abs(x), abs(y)
    mx = max(ax, ay)
    a = min(ax, ay) / mx  # NaN when x = y = 0, replaced below
    s = a * a
    r = ((((-0.0117212 * s + 0.05265332) * s - 0.11643287) * s + 0.19354346) * s - 0.33262347) * s * a + 0.99997726 * a
    r = 0.5 * np.pi - r if ay > ax else r
    r = np.pi - r if x < 0.0 else r
    r = -r if y < 0.0 else r
    return 0.0 if mx == 0.0 else r


@nb.njit(cache=True, inline="always", error_model="numpy")
def _project_cam(px, py, pz, H, W):
    """Range and containing ERP pixel (row, col) of camera-frame point p; the column wraps, the row is
    clipped. Branch-free (see :func:`_atan2`)."""
    r = np.sqrt(px * px + py * py + pz * pz)
    theta = _atan2(px, pz)
    phi = _atan2(-py, np.sqrt(px * px + pz * pz))
    col = int(np.floor((theta + np.pi) * W / (2.0 * np.pi)))  # in [0, W] since theta is in [-pi, pi]
    col = col - W if col >= W else col
    col = col + W if col < 0 else col
    row = int(np.floor((0.5 * np.pi - phi) * H / np.pi))
    row = 0 if row < 0 else row
    row = H - 1 if row >= H else row
    return r, row, col


@nb.njit(cache=True, inline="always", error_model="numpy")
def _project_offset(Rt, cx, cy, cz, H, W):
    """Range and containing ERP pixel (row, col) of the world offset c - t, rotated into the camera
    frame (p = R^T (c - t)); the column wraps, the row is clipped."""
    px = Rt[0, 0] * cx + Rt[0, 1] * cy + Rt[0, 2] * cz
    py = Rt[1, 0] * cx + Rt[1, 1] * cy + Rt[1, 2] * cz
    pz = Rt[2, 0] * cx + Rt[2, 1] * cy + Rt[2, 2] * cz
    return _project_cam(px, py, pz, H, W)


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
            # p = R^T (c - t), summed left to right as in _project_offset: (a x + b y) + c z
            s0 = r00 * cx + r01 * cy
            s1 = r10 * cx + r11 * cy
            s2 = r20 * cx + r21 * cy
            for k in range(nz):
                cz = czs[k]
                rr[k], rows[k], cols[k] = _project_cam(s0 + r02 * cz, s1 + r12 * cz, s2 + r22 * cz, H, W)
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


BLOCK = 8  # hierarchical test: voxels per block edge
TILE = 8  # pixels per tile edge of the min/max depth-threshold maps


def _pixel_thresholds(depth, Rt, h, eps_abs, eps_rel, stable_k, extent):
    """Per pixel: ``fthr`` (:func:`_free_thresholds`: a voxel at range r projecting here is carved iff
    r < fthr, and r < ro - eps) and ``othr = ro + eps`` (compared iff r <= othr); -inf = never."""
    fthr = _free_thresholds(depth, Rt, h, eps_abs, eps_rel, stable_k, extent)
    ro = depth.astype(np.float64)
    othr = np.where(depth > 0, ro + (eps_abs + eps_rel * ro), -np.inf)
    return fthr, othr


@nb.njit(cache=True, parallel=True)
def _tile_minmax(fthr, othr):
    H, W = fthr.shape
    th, tw = (H + TILE - 1) // TILE, (W + TILE - 1) // TILE
    fmin = np.full((th, tw), np.inf)
    omax = np.full((th, tw), -np.inf)
    fmax = np.full((th, tw), -np.inf)
    omin = np.full((th, tw), np.inf)
    for a in nb.prange(th):
        for row in range(a * TILE, min(H, (a + 1) * TILE)):
            for col in range(W):
                b = col // TILE
                f, o = fthr[row, col], othr[row, col]
                fmin[a, b] = min(fmin[a, b], f)
                fmax[a, b] = max(fmax[a, b], f)
                omax[a, b] = max(omax[a, b], o)
                omin[a, b] = min(omin[a, b], o)
    return fmin, omax, fmax, omin


@nb.njit(cache=True)
def _voxel_test(depth, fthr, Rt, t, h, lo, i, j, k, eps_abs, eps_rel, min_range, max_range, extent, F, O):
    H, W = depth.shape
    cx = (i + lo[0] + 0.5) * h - t[0]
    cy = (j + lo[1] + 0.5) * h - t[1]
    cz = (k + lo[2] + 0.5) * h - t[2]
    r, row, col = _project_offset(Rt, cx, cy, cz, H, W)
    if r < min_range or r > max_range:
        return
    ro = depth[row, col]
    if ro <= 0.0:
        return
    eps = eps_abs + eps_rel * ro
    if r > ro + eps:
        return
    O[i, j, k] = 1
    if extent:
        if r < ro - eps and r <= fthr[row, col]:
            F[i, j, k] = 1
    elif r < fthr[row, col]:
        F[i, j, k] = 1


@nb.njit(cache=True)
def _block_status(i0, i1, j0, j1, k0, k1, fthr, othr, fmin, omax, fmax, omin, Rt, t, h, lo, H, W, min_range, max_range):
    """0: undecided; 1: no voxel of the box [i0, i1) x [j0, j1) x [k0, k1) is compared (out of range, or
    behind every threshold over its angular footprint); 2: every voxel is carved (O = F = 1); 3: every
    voxel is compared and none carved (O = 1, F = 0)."""
    two_pi = 2.0 * np.pi
    tw = fmin.shape[1]
    cx = (0.5 * (i0 + i1 - 1) + lo[0] + 0.5) * h - t[0]
    cy = (0.5 * (j0 + j1 - 1) + lo[1] + 0.5) * h - t[1]
    cz = (0.5 * (k0 + k1 - 1) + lo[2] + 0.5) * h - t[2]
    rho = 0.5 * h * np.sqrt((i1 - i0 - 1) ** 2 + (j1 - j0 - 1) ** 2 + (k1 - k0 - 1) ** 2) + 1e-9
    rc = np.sqrt(cx * cx + cy * cy + cz * cz)
    rmin, rmax = rc - rho - 1e-9, rc + rho + 1e-9
    if rmax < min_range or rmin > max_range:
        return 1
    if rc <= 2.0 * rho:
        return 0
    px = Rt[0, 0] * cx + Rt[0, 1] * cy + Rt[0, 2] * cz
    py = Rt[1, 0] * cx + Rt[1, 1] * cy + Rt[1, 2] * cz
    pz = Rt[2, 0] * cx + Rt[2, 1] * cy + Rt[2, 2] * cz
    theta = np.arctan2(px, pz)
    phi = np.arctan2(-py, np.sqrt(px * px + pz * pz))
    delta = np.arcsin(rho / rc)
    r0 = max(int(np.floor((0.5 * np.pi - (phi + delta)) * H / np.pi)) - 1, 0)
    r1 = min(int(np.floor((0.5 * np.pi - (phi - delta)) * H / np.pi)) + 1, H - 1)
    c0, c1 = 0, W - 1
    allcols = True
    if abs(phi) + delta < 0.5 * np.pi - 1e-6:
        dlon = np.arcsin(min(1.0, np.sin(delta) / np.cos(abs(phi) + delta)))
        c0 = int(np.floor((theta - dlon + np.pi) * W / two_pi)) - 1
        c1 = int(np.floor((theta + dlon + np.pi) * W / two_pi)) + 1
        if c1 - c0 + 1 < W:
            allcols = False
    if (r1 - r0 + 1) * (W if allcols else c1 - c0 + 1) > H * W // 8:
        return 0
    fm, om, fx, on = np.inf, -np.inf, -np.inf, np.inf
    if not allcols and (r1 - r0 + 1) * (c1 - c0 + 1) <= 256:  # small footprint: exact, pixel by pixel
        for row in range(r0, r1 + 1):
            for cc in range(c0, c1 + 1):
                f, o = fthr[row, cc % W], othr[row, cc % W]
                fm, fx, om, on = min(fm, f), max(fx, f), max(om, o), min(on, o)
        return _decide(rmin, rmax, fm, om, fx, on, min_range, max_range)
    for a in range(r0 // TILE, r1 // TILE + 1):
        if allcols:
            for b in range(tw):
                fm = min(fm, fmin[a, b])
                om = max(om, omax[a, b])
                fx = max(fx, fmax[a, b])
                on = min(on, omin[a, b])
        else:
            cc = c0
            while cc <= c1:  # the tiles of the wrapped column range
                wc = cc % W
                b = wc // TILE
                fm = min(fm, fmin[a, b])
                om = max(om, omax[a, b])
                fx = max(fx, fmax[a, b])
                on = min(on, omin[a, b])
                cc += min((b + 1) * TILE, W) - wc
    return _decide(rmin, rmax, fm, om, fx, on, min_range, max_range)


@nb.njit(cache=True, inline="always")
def _decide(rmin, rmax, fm, om, fx, on, min_range, max_range):
    if rmin > om:
        return 1
    if rmin >= min_range and rmax <= max_range:
        if rmax < fm:
            return 2
        if rmin > fx and rmax <= on:
            return 3
    return 0


@nb.njit(cache=True, parallel=True)
def _carve_hier(depth, fthr, othr, fmin, omax, fmax, omin, Rt, t, h, lo, nx, ny, nz, eps_abs, eps_rel, min_range, max_range,
                extent, F, O):
    """Blocks of 8^3, then 4^3, then 2^3 voxels: a block wholly in front of the carving threshold over its
    angular footprint is carved in bulk, one wholly behind the observed surface (or out of range) is
    skipped, the rest is split; undecided 2^3 blocks are tested voxel by voxel."""
    H, W = depth.shape
    bx, by, bz = (nx + BLOCK - 1) // BLOCK, (ny + BLOCK - 1) // BLOCK, (nz + BLOCK - 1) // BLOCK
    for blk in nb.prange(bx * by * bz):
        ib, rem = blk // (by * bz), blk % (by * bz)
        jb, kb = rem // bz, rem % bz
        stack = np.empty((64, 4), np.int64)  # (i0, j0, k0, size): depth-first subdivision
        stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = ib * BLOCK, jb * BLOCK, kb * BLOCK, BLOCK
        top = 1
        while top > 0:
            top -= 1
            i0, j0, k0, sz = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
            i1, j1, k1 = min(i0 + sz, nx), min(j0 + sz, ny), min(k0 + sz, nz)
            if i0 >= nx or j0 >= ny or k0 >= nz:
                continue
            st = _block_status(i0, i1, j0, j1, k0, k1, fthr, othr, fmin, omax, fmax, omin, Rt, t, h, lo, H, W, min_range,
                               max_range)
            if st == 1:
                continue
            if st >= 2:
                f = 1 if st == 2 else 0
                for i in range(i0, i1):
                    for j in range(j0, j1):
                        for k in range(k0, k1):
                            O[i, j, k] = 1
                            F[i, j, k] = f
                continue
            if sz > 2:
                hs = sz // 2
                for q in range(8):
                    stack[top, 0] = i0 + hs * (q >> 2)
                    stack[top, 1] = j0 + hs * ((q >> 1) & 1)
                    stack[top, 2] = k0 + hs * (q & 1)
                    stack[top, 3] = hs
                    top += 1
                continue
            for i in range(i0, i1):
                for j in range(j0, j1):
                    for k in range(k0, k1):
                        _voxel_test(depth, fthr, Rt, t, h, lo, i, j, k, eps_abs, eps_rel, min_range, max_range,
                                    extent, F, O)


def carve(depth: np.ndarray, T_world_cam: np.ndarray, voxel_size: float, lo: np.ndarray, shape, eps_abs: float,
          eps_rel: float, stable_k: float, min_range: float, max_range: float, extent: bool = True,
          hierarchical: bool = False):
    """Free-space test of every voxel of a dense frame-local grid (see module docstring).

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid (full resolution, not strided)
    T_world_cam : (4, 4) float64
    lo : (3,) int64, lattice index of grid cell [0, 0, 0]; shape : (3,) int

    extent : bool, require the voxel's whole box in front of the observed local plane
    hierarchical : bool, test 8^3 blocks first (bulk-carve blocks wholly in front of the surface over
        their angular footprint, skip blocks wholly behind it); the same F, O as the exhaustive test

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
    if hierarchical:
        fthr, othr = _pixel_thresholds(depth, Rt, float(voxel_size), float(eps_abs), float(eps_rel),
                                       float(stable_k), bool(extent))
        fmin, omax, fmax, omin = _tile_minmax(fthr, othr)
        _carve_hier(depth, fthr, othr, fmin, omax, fmax, omin, Rt, t, float(voxel_size), lo, shape[0], shape[1], shape[2],
                    float(eps_abs), float(eps_rel), float(min_range), float(max_range), bool(extent), F, O)
        return F, O
    fthr = _free_thresholds(depth, Rt, float(voxel_size), float(eps_abs), float(eps_rel), float(stable_k),
                            bool(extent))
    _carve(depth, fthr, Rt, t, float(voxel_size), lo, shape[0], shape[1], shape[2], float(min_range),
           float(max_range), float(eps_abs), float(eps_rel), F, O)
    return F, O
