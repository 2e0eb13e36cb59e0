"""Multi-view consensus occupancy of the lifted ground truth (``gt --from-sequence``; docs/gt.md).

An offline builder has every frame at once, so it does not decide a voxel from the frames seen so far:
it first gathers where every frame puts each surface, takes the consensus, and only then asks every ray
whether it agrees. Written from the ERP geometry and the lattice alone (no code of the mapper: the
benchmark must not be built by the method it ranks). On the global lattice of voxel size h:

1. **Surface positions along the normal (pass 1, every frame).** Each valid depth pixel is lifted to the
   world (``T_world_cam`` · ray · radial depth) and given the dominant axis ``a`` of its surface normal
   (the cross product of the image tangents ``NORMAL_STEP`` pixels either side, one-sided across a depth
   jump). The point falls in the *column* of voxels along ``a`` through its other two voxel indices, at
   a position counted in ``FINE`` bins a voxel (integer counts, and the points' offsets in fixed point:
   sums that do not depend on the frames' order), separately for the points seen from below and from above
   along the column (the camera centre's side of the point).
2. **The consensus (robust statistics per column).** Along every column the counts are smoothed by a
   triangle one voxel either side; a bin is a *surface mode* when it is the largest within one voxel
   either side (the first of a plateau) and at least ``min_points`` points lie within one voxel of it.
   The surface's position is the mean of those points (a trimmed mean: the window is the mode ± one
   voxel, so one frame's outliers and the noise tails farther off do not move it), and the surface voxel
   is the one that position falls in (a position on a voxel face goes to the voxel above it, as the mesh
   ground truth does). One column gives one voxel per surface, however thick the noise spreads the points.
2b. **What the surface spans besides that voxel.** A surface that is not square to its axis, or a thin slab,
   crosses more than one voxel of its column (a door leaf 4 cm thick across a voxel face, a pleated
   curtain, a tilted leaf), and the mesh truth counts every voxel a surface passes through. Towards each
   of the four lateral neighbour columns the surface reaches half-way to that column's nearest mode within
   one voxel of its own position (a side with none mirrors the opposite side; none either way: flat that
   way); the reaches of the two lateral axes add up (the footprint's corners). A mode whose points seen
   from above lie higher than those seen from below is a slab seen from both sides: it spans from its lower
   face's position to its upper face's. The voxels the span reaches into by more than ``SPAN_MARGIN``
   voxels (0: any depth at all; swept on seeds 10 and 11, docs/gt.md), other than the mode's own (at most
   ``SPAN_MAX`` either side), are *span voxels* of that mode.
3. **Every ray's verdict (pass 2, every frame).** A point *supports* the surface whose consensus position
   is nearest along that surface's axis within ``tol(r) = surface_tol + surface_tol_r2 r²`` (r its range,
   metres): range noise grows with range. A ray (one every ``max(1, W // 512)`` pixels on both axes) is
   walked from the camera centre to its point's voxel; every voxel it crosses is *seen*; a surface voxel
   it crosses *sees through* when the ray crosses that surface's plane inside the voxel and its point lies
   more than ``tol(r)`` behind the plane. A surface voxel is *occupied* when at least ``min_frames``
   frames support it and the supporting frames are at least ``min_hit_ratio`` of the frames supporting or
   seeing through it: free space carved by every ray overrides a mode that noise or one frame made. The
   span voxels of an occupied mode voxel are occupied with it.
4. **Labels.** The annotated frames vote (one vote per frame per voxel, split over its pixels' classes)
   twice: each pixel in the surface voxel its point supports, so a noisy point still votes where its
   surface is, and in the voxel the point itself lies in; a span voxel (not a mode voxel itself) also takes
   the support votes of the mode voxels that span it. The mesh truth's class is the largest *area* inside a
   voxel, and by pixels a surface seen square outvotes one seen at a grazing angle (a wall against the
   ceiling at their edge): so a voxel first takes the class whose supporting points, over all the annotated
   frames, cover the most of its *area cells* (each point's cell: the surface's axis and the point's
   ``AREA_SPLIT`` x ``AREA_SPLIT`` sub-square of the voxel along the two lateral axes; a set union, order
   free), the summed vote deciding between equal covers and where no class covers any; then the
   nearest-label transfer within ``label_radius`` (:func:`.lifted.transfer_labels`), which takes the
   nearest labelled voxels on the voxel's own consensus surface first (a hidden wall patch behind a
   cabinet stays wall).

Every frame contributes to the same integer sums whatever the order, so the trajectory run backwards
gives the same grid, byte for byte.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..config import GT_BOUNDARY_EPS
from ..errors import PanovoccError
from ..geometry.erp import cam_point, trig_tables
from ..grid import Grid
from .lifted import carve_stride, frame_votes, label_grid

FINE = 4  # position bins a voxel along a column
NORMAL_STEP = 2  # pixels either side for the image tangents of a point's normal
STRONG = 0.8  # a tangent pair's normal counts for its axis when |n_a| / |n| is at least this
JUMP_REL = 0.25  # a neighbour farther than this fraction of the range is across a depth jump
OFFSET_UNITS = 1 << 20  # fixed-point units of a point's offset within its bin (rounded)
WINDOW = FINE - 1  # bins either side of a mode whose points give its position (the trimmed mean)
NMS = FINE - 1  # a mode is the largest density within this many bins either side
DIP = 0.5  # two modes are one surface unless the density between them dips below this fraction of the smaller
POINT_MASS = 4096  # fixed-point mass of one point in the smoothed density
KERNEL_R2 = 1.5  # a point's triangle: half-width max(h / 2, KERNEL_R2 surface_tol_r2 r^2)
SPAN_MAX = 1  # a surface's span reaches at most this many voxels either side of its mode's voxel (2b)
AREA_SPLIT = 2  # a voxel face's area cells per lateral axis (labels: the class covering the most cells, 4)
AREA_CELLS = 3 * AREA_SPLIT * AREA_SPLIT  # area cells of a voxel: its three axes' surfaces
SPAN_MARGIN = 0.0  # voxels: a span counts a neighbouring voxel when it reaches more than this far into it (2b)
# (3 axes x FINE bins x (2 sides x (int32 count + int64 offset) + int64 density)) + 3 float64 surface positions
# + 3 x 2 float64 positions of the two sides (while settling) + 6 int32 counts/stamps + bools
BYTES_PER_VOXEL = 3 * FINE * 32 + 3 * 8 + 3 * 2 * 8 + 6 * 4 + 2


@nb.njit(cache=True)
def _world_points(depth, T, max_range, P, ok):
    """World point of every pixel into ``P`` (H, W, 3) and validity into ``ok`` (H, W)."""
    H, W = depth.shape
    sphi, cphi, sth, cth = trig_tables(H, W)
    for v in range(H):
        for u in range(W):
            r = depth[v, u]
            good = r > 0.0 and np.isfinite(r) and not (max_range > 0.0 and r > max_range)
            ok[v, u] = good
            if not good:
                continue
            x, y, z = cam_point(r, sphi[v], cphi[v], sth[u], cth[u])
            for a in range(3):
                P[v, u, a] = T[a, 0] * x + T[a, 1] * y + T[a, 2] * z + T[a, 3]


@nb.njit(cache=True, inline="always")
def _side(P, ok, depth, v, u, v1, u1, sign, out):
    """One-sided tangent ``sign * (P[v1, u1] - P[v, u])``; False across a depth jump or an invalid pixel."""
    r = depth[v, u]
    if (v1 == v and u1 == u) or not ok[v1, u1] or abs(depth[v1, u1] - r) > JUMP_REL * r:
        return False
    for a in range(3):
        out[a] = sign * (P[v1, u1, a] - P[v, u, a])
    return True


@nb.njit(cache=True, inline="always")
def _dominant(tu, tv):
    """Dominant axis of the normal ``tu x tv`` and its share ``|n_a| / |n|`` (-1, 0 when degenerate)."""
    nx = tu[1] * tv[2] - tu[2] * tv[1]
    ny = tu[2] * tv[0] - tu[0] * tv[2]
    nz = tu[0] * tv[1] - tu[1] * tv[0]
    ax, ay, az = abs(nx), abs(ny), abs(nz)
    n = np.sqrt(nx * nx + ny * ny + nz * nz)
    if n <= 0.0:
        return -1, 0.0
    if ax >= ay and ax >= az:
        return 0, ax / n
    if ay >= az:
        return 1, ay / n
    return 2, az / n


@nb.njit(cache=True)
def _normal_axes(P, ok, depth, step, axis):
    """Dominant axes of each pixel's surface normal into ``axis`` (H, W) int8, a bit mask (bit a: axis a;
    0: none): the axis of the normal of each pair of one-sided tangents (``step`` pixels along the row
    either side x along the column either side) that does not cross a depth jump, where that normal is
    within 37 degrees of the axis (``STRONG``; else only the most dominant pair's axis). One bit on a
    smooth surface; near a crease (an edge, a corner) the pairs straddling it add the other surface's axis, and
    the point goes into both columns: a surface that passes through a voxel by less than ``step`` pixels
    still has points in its column."""
    H, W = depth.shape
    tu = np.empty((2, 3))
    tv = np.empty((2, 3))
    gu = np.empty(2, np.bool_)
    gv = np.empty(2, np.bool_)
    for v in range(H):
        for u in range(W):
            axis[v, u] = 0
            if not ok[v, u]:
                continue
            gu[0] = _side(P, ok, depth, v, u, v, (u + step) % W, 1.0, tu[0])
            gu[1] = _side(P, ok, depth, v, u, v, (u - step) % W, -1.0, tu[1])
            gv[0] = _side(P, ok, depth, v, u, min(v + step, H - 1), u, 1.0, tv[0])
            gv[1] = _side(P, ok, depth, v, u, max(v - step, 0), u, -1.0, tv[1])
            mask = 0
            best, best_share = -1, 0.0
            for i in range(2):
                for j in range(2):
                    if gu[i] and gv[j]:
                        d, share = _dominant(tu[i], tv[j])
                        if d >= 0 and share >= STRONG:
                            mask |= 1 << d
                        if d >= 0 and share > best_share:
                            best, best_share = d, share
            if mask == 0 and best >= 0:
                mask = 1 << best
            axis[v, u] = mask


@nb.njit(cache=True, inline="always")
def _deposit(cnt, off, den, q, side, loc, n_bins, stride, f, fb, half):
    """One point at fine position ``f`` (bin ``fb``, local ``loc``) of a column whose bin ``loc`` is ``q``,
    seen from ``side`` (1: the camera above it along the column, 0: below)."""
    cnt[side, q] += 1
    off[side, q] += int((f - fb) * OFFSET_UNITS + 0.5)
    m = (half + 1) * (half + 1)
    for j in range(-half, half + 1):
        b = loc + j
        if 0 <= b < n_bins:
            den[q + j * stride] += (POINT_MASS * (half + 1 - abs(j))) // m


@nb.njit(cache=True)
def _density_kernel(P, ok, axis, depth, o, h, i0, shape, k2, cnt0, off0, den0, cnt1, off1, den1, cnt2, off2, den2):
    """Pass 1: each point with a normal axis counted in its column's fine bin and spread over the bins of
    its range-dependent triangle (module docstring, 1)."""
    H, W = ok.shape
    idx = np.empty(3, np.int64)
    for v in range(H):
        for u in range(W):
            mask = axis[v, u]
            if mask == 0:
                continue
            inside = True
            for b in range(3):
                idx[b] = _vox(P[v, u, b], h, i0, b)
                if idx[b] < 0 or idx[b] >= shape[b]:
                    inside = False
            if not inside:
                continue
            r = depth[v, u]
            half = max(FINE // 2, int(k2 * r * r / h * FINE + 0.5))
            half = min(half, 4 * FINE)
            for a in range(3):
                if mask & (1 << a):
                    side = 1 if o[a] > P[v, u, a] else 0  # the camera above the point along a, or below
                    _deposit_axis(P, v, u, a, side, idx, h, i0, shape, half, cnt0, off0, den0, cnt1, off1, den1,
                                  cnt2, off2, den2)


@nb.njit(cache=True, inline="always")
def _deposit_axis(P, v, u, a, side, idx, h, i0, shape, half, cnt0, off0, den0, cnt1, off1, den1, cnt2, off2, den2):
    """Point (v, u) into its column along axis ``a``."""
    f = P[v, u, a] / h * FINE
    fb = int(np.floor(f))
    loc = fb - i0[a] * FINE
    if loc < 0 or loc >= shape[a] * FINE:
        return
    n_bins = shape[a] * FINE
    if a == 0:
        q = (loc * shape[1] + idx[1]) * shape[2] + idx[2]
        _deposit(cnt0, off0, den0, q, side, loc, n_bins, shape[1] * shape[2], f, fb, half)
    elif a == 1:
        q = (idx[0] * (shape[1] * FINE) + loc) * shape[2] + idx[2]
        _deposit(cnt1, off1, den1, q, side, loc, n_bins, shape[2], f, fb, half)
    else:
        q = (idx[0] * shape[1] + idx[1]) * (shape[2] * FINE) + loc
        _deposit(cnt2, off2, den2, q, side, loc, n_bins, 1, f, fb, half)


@nb.njit(cache=True, inline="always")
def _vox(x, h, i0, b):
    """Box index along axis b of coordinate x (metres); on a voxel face (within GT_BOUNDARY_EPS): the voxel above."""
    return int(np.floor(x / h + GT_BOUNDARY_EPS)) - i0[b]


@nb.njit(cache=True, inline="always")
def _sub(x, h):
    """Sub-square (0 .. AREA_SPLIT - 1) of coordinate x within its voxel (the voxel of :func:`_vox`)."""
    t = x / h
    k = int(np.floor((t - np.floor(t + GT_BOUNDARY_EPS)) * AREA_SPLIT))
    return min(max(k, 0), AREA_SPLIT - 1)


@nb.njit(cache=True)
def _evidence_kernel(depth, P, ok, T, h, i0, shape, f, stride, tol0, tol2, S0, S1, S2, hit_frames, hit_points,
                     hit_stamp, see_frames, see_stamp, seen, pix_lin, pix_cell, pos_lin):
    """Pass 2: support, seen-through and seen voxels of one frame (module docstring, 3); ``pix_lin``
    (H, W) int64 receives the surface voxel each pixel supports (-1: none), ``pix_cell`` (H, W) int64 the
    area cell of that voxel's surface the point lies in (``(axis * AREA_SPLIT + i) * AREA_SPLIT + j``, i, j
    the point's sub-square of the voxel along the surface's two lateral axes; -1: none), ``pos_lin`` the
    voxel the point itself lies in (-1: outside the box or invalid)."""
    H, W = depth.shape
    ox, oy, oz = T[0, 3], T[1, 3], T[2, 3]
    o = np.array([ox, oy, oz])
    p = np.empty(3)
    idx = np.empty(3, np.int64)
    for v in range(H):
        for u in range(W):
            pix_lin[v, u] = -1
            pix_cell[v, u] = -1
            pos_lin[v, u] = -1
            if not ok[v, u]:
                continue
            r = depth[v, u]
            tol = tol0 + tol2 * r * r
            inside = True
            for b in range(3):
                p[b] = P[v, u, b]
                idx[b] = _vox(p[b], h, i0, b)
                if idx[b] < 0 or idx[b] >= shape[b]:
                    inside = False
            if inside:
                pos_lin[v, u] = (idx[0] * shape[1] + idx[1]) * shape[2] + idx[2]
            # support: the nearest consensus surface along its axis within tol
            best = tol
            bq = -1
            ba = -1
            for a in range(3):
                b1, b2 = (a + 1) % 3, (a + 2) % 3
                if idx[b1] < 0 or idx[b1] >= shape[b1] or idx[b2] < 0 or idx[b2] >= shape[b2]:
                    continue
                lo = max(_vox(p[a] - tol, h, i0, a), 0)
                hi = min(_vox(p[a] + tol, h, i0, a), shape[a] - 1)
                for k in range(lo, hi + 1):
                    idx2 = idx.copy()
                    idx2[a] = k
                    q = (idx2[0] * shape[1] + idx2[1]) * shape[2] + idx2[2]
                    s = S0[q] if a == 0 else (S1[q] if a == 1 else S2[q])
                    if np.isfinite(s):
                        d = abs(p[a] - s)
                        if d <= best:
                            if d < best or bq < 0 or q < bq:
                                best = d
                                bq = q
                                ba = a
            if bq >= 0:
                pix_lin[v, u] = bq
                c1 = _sub(p[(ba + 1) % 3], h)
                c2 = _sub(p[(ba + 2) % 3], h)
                pix_cell[v, u] = (ba * AREA_SPLIT + c1) * AREA_SPLIT + c2
                hit_points[bq] += 1
                if hit_stamp[bq] != f:
                    hit_stamp[bq] = f
                    hit_frames[bq] += 1
            if v % stride != 0 or u % stride != 0:
                continue
            # Amanatides-Woo walk in voxel units from the camera centre to the point's voxel (excluded)
            gx, gy, gz = ox / h, oy / h, oz / h
            px, py, pz = p[0] / h, p[1] / h, p[2] / h
            cx, cy, cz = int(np.floor(gx)), int(np.floor(gy)), int(np.floor(gz))
            ex, ey, ez = int(np.floor(px)), int(np.floor(py)), int(np.floor(pz))
            n = abs(ex - cx) + abs(ey - cy) + abs(ez - cz)
            dx, dy, dz = px - gx, py - gy, pz - gz
            sx = 1 if dx > 0 else -1
            sy = 1 if dy > 0 else -1
            sz = 1 if dz > 0 else -1
            tx = ((cx + (1 if dx > 0 else 0)) - gx) / dx if dx != 0 else np.inf
            ty = ((cy + (1 if dy > 0 else 0)) - gy) / dy if dy != 0 else np.inf
            tz = ((cz + (1 if dz > 0 else 0)) - gz) / dz if dz != 0 else np.inf
            ddx = abs(1.0 / dx) if dx != 0 else np.inf
            ddy = abs(1.0 / dy) if dy != 0 else np.inf
            ddz = abs(1.0 / dz) if dz != 0 else np.inf
            for _ in range(n):
                if cx == ex and cy == ey and cz == ez:
                    break
                lx, ly, lz = cx - i0[0], cy - i0[1], cz - i0[2]
                if 0 <= lx < shape[0] and 0 <= ly < shape[1] and 0 <= lz < shape[2]:
                    q = (lx * shape[1] + ly) * shape[2] + lz
                    seen[q] = True
                    for a in range(3):
                        s = S0[q] if a == 0 else (S1[q] if a == 1 else S2[q])
                        if not np.isfinite(s) or see_stamp[q] == f:
                            continue
                        if (o[a] - s) * (p[a] - s) >= 0.0 or abs(p[a] - s) <= tol:
                            continue  # the point is on the camera's side of the plane, or within tol of it
                        w = (s - o[a]) / (p[a] - o[a])  # where the ray crosses the plane: inside this voxel?
                        b1, b2 = (a + 1) % 3, (a + 2) % 3
                        c1 = o[b1] + w * (p[b1] - o[b1])
                        c2 = o[b2] + w * (p[b2] - o[b2])
                        l1 = lx if b1 == 0 else (ly if b1 == 1 else lz)
                        l2 = lx if b2 == 0 else (ly if b2 == 1 else lz)
                        if _vox(c1, h, i0, b1) == l1 and _vox(c2, h, i0, b2) == l2:
                            see_stamp[q] = f
                            see_frames[q] += 1
                if tx <= ty and tx <= tz:
                    cx += sx
                    tx += ddx
                elif ty <= tz:
                    cy += sy
                    ty += ddy
                else:
                    cz += sz
                    tz += ddz


@nb.njit(cache=True)
def _spans(S, F, a, i0a, shape, h, max_span, out_vox, out_owner):
    """Voxels along axis ``a`` that the surface of each mode voxel crosses besides its own (module docstring,
    2b). ``S`` (n,) the modes' positions along ``a`` (metres, NaN: none), ``F`` (n, 2) the positions of
    their points seen from below / from above (NaN: too few), ``i0a`` the box's first lattice index along
    ``a``. Towards each lateral neighbour column the surface reaches half-way to that column's nearest mode
    within one voxel of its own position (a side with none mirrors the other side; a column with neither:
    flat that way); the surface over the footprint spans the sum over the two lateral axes of each one's
    lowest and highest reach, and a slab seen from both sides at least from its lower to its upper face.
    The voxels that span reaches ``SPAN_MARGIN`` into, other than the mode's own, at most ``max_span``
    either side of it, go to ``out_vox`` with their mode voxel in ``out_owner``; returns how many."""
    n = 0
    st = (shape[1] * shape[2], shape[2], 1)
    i = np.empty(3, np.int64)
    d = np.empty(2)
    got = np.empty(2, np.bool_)
    for q in range(S.shape[0]):
        s = S[q]
        if not np.isfinite(s):
            continue
        i[0], i[1], i[2] = q // st[0], (q // st[1]) % shape[1], q % shape[2]
        lo = 0.0
        hi = 0.0
        for b in ((a + 1) % 3, (a + 2) % 3):
            for side in range(2):
                got[side] = False
                j = i[b] + (2 * side - 1)
                if j < 0 or j >= shape[b]:
                    continue
                best = h
                for k in range(max(i[a] - 1, 0), min(i[a] + 2, shape[a])):
                    t = S[q + (j - i[b]) * st[b] + (k - i[a]) * st[a]]
                    if np.isfinite(t) and abs(t - s) <= best:
                        best = abs(t - s)
                        d[side] = t - s
                        got[side] = True
            if not got[0] and not got[1]:
                continue
            if not got[0]:
                d[0] = -d[1]
            elif not got[1]:
                d[1] = -d[0]
            lb = 0.0
            hb = 0.0
            for side in range(2):
                lb = min(lb, 0.5 * d[side])
                hb = max(hb, 0.5 * d[side])
            lo += lb
            hi += hb
        if F[q, 1] > F[q, 0]:  # a slab seen from both sides: its lower face seen from below, its upper from above
            lo = min(lo, F[q, 0] - s)
            hi = max(hi, F[q, 1] - s)
        k0 = i[a]
        kl = int(np.floor((s + lo) / h + SPAN_MARGIN + GT_BOUNDARY_EPS)) - i0a
        kh = int(np.floor((s + hi) / h - SPAN_MARGIN - GT_BOUNDARY_EPS)) - i0a
        for k in range(max(kl, k0 - max_span, 0), min(kh, k0 + max_span, shape[a] - 1) + 1):
            if k != k0:
                out_vox[n] = q + (k - k0) * st[a]
                out_owner[n] = q
                n += 1
    return n


@nb.njit(cache=True)
def _row_modes(den, cnt, off, min_points, out_bin, out_pos, out_str, out_side):
    """Modes of one column's bins (module docstring, 2); returns how many were written to ``out_*``.
    ``cnt``, ``off`` (2, L): per side the points seen from; ``out_side`` (L, 2) the position of each side's
    points of the window (NaN: fewer than ``min_points``)."""
    L = den.shape[0]
    keep = np.empty(L, np.int64)
    nk = 0
    for b in range(L):
        d = den[b]
        if d <= 0:
            continue
        is_max = True
        for j in range(max(b - NMS, 0), min(b + NMS + 1, L)):
            if (j < b and den[j] >= d) or (j > b and den[j] > d):
                is_max = False
                break
        if not is_max:
            continue
        if nk > 0:  # one blob with the previous mode (no dip between them): keep the stronger
            p = keep[nk - 1]
            dip = d
            for j in range(p, b + 1):
                dip = min(dip, den[j])
            if dip >= DIP * min(d, den[p]):
                if d > den[p]:
                    keep[nk - 1] = b
                continue
        keep[nk] = b
        nk += 1
    m = 0
    for i in range(nk):
        b = keep[i]
        c = 0
        s = 0
        for side in range(2):
            cs = 0
            ss = 0
            for j in range(max(b - WINDOW, 0), min(b + WINDOW + 1, L)):
                cs += cnt[side, j]
                ss += cnt[side, j] * j * OFFSET_UNITS + off[side, j]
            out_side[m, side] = ss / (cs * float(OFFSET_UNITS)) if cs >= min_points and cs > 0 else np.nan
            c += cs
            s += ss
        if c < min_points or c == 0:
            continue
        out_bin[m] = b
        out_pos[m] = s / (c * float(OFFSET_UNITS))
        out_str[m] = den[b]
        m += 1
    return m


@nb.njit(cache=True)
def _all_modes(den, cnt, off, min_points):
    R, L = den.shape
    rows = []
    bins = []
    pos = []
    strength = []
    sides = []
    ob = np.empty(L, np.int64)
    op = np.empty(L)
    os_ = np.empty(L, np.int64)
    osd = np.empty((L, 2))
    for r in range(R):
        m = _row_modes(den[r], cnt[:, r], off[:, r], min_points, ob, op, os_, osd)
        for i in range(m):
            rows.append(r)
            bins.append(ob[i])
            pos.append(op[i])
            strength.append(os_[i])
            sides.append(osd[i, 0])
            sides.append(osd[i, 1])
    return (np.array(rows, np.int64), np.array(bins, np.int64), np.array(pos), np.array(strength, np.int64),
            np.array(sides).reshape(-1, 2))


def column_modes(cnt: np.ndarray, off: np.ndarray, den: np.ndarray, axis: int, min_points: int):
    """Surface modes of the columns of one axis (module docstring, 2).

    Parameters
    ----------
    cnt, off : (2, ...) point counts and summed fixed-point offsets per fine bin of the points seen from below
        (0) and from above (1) along ``axis``; den : smoothed density per fine bin; ``...`` shaped like the box
        with ``FINE`` bins a voxel along ``axis``
    min_points : points within the mode's window, at least

    Returns
    -------
    bins : (m, 3) int64 fine-bin index of each mode (``axis`` in bins, the others in voxels)
    pos : (m,) float64 the mode's position in fine-bin units of the box (trimmed mean of its window)
    strength : (m,) int64 smoothed density at the mode
    sides : (m, 2) float64 the position of the window's points seen from below / above alone (NaN: fewer than
        ``min_points`` of them)
    """
    sh = np.moveaxis(np.empty(den.shape, np.int8), axis, -1).shape
    rows, b, pos, strength, sides = _all_modes(
        np.ascontiguousarray(np.moveaxis(den, axis, -1)).reshape(-1, sh[-1]),
        *(np.ascontiguousarray(np.moveaxis(x, axis + 1, -1)).reshape(2, -1, sh[-1]) for x in (cnt, off)),
        int(min_points))
    other = np.stack(np.unravel_index(rows, sh[:-1]), 1) if len(rows) else np.zeros((0, 2), np.int64)
    bins = np.insert(other, axis, b, axis=1)
    return bins, pos, strength, sides


class ConsensusLift:
    """The consensus lifting on a fixed dense box of the global lattice (module docstring).

    Feed every frame to :meth:`add_density`, call :meth:`settle`, then feed every frame again (with the
    labels of the annotated ones) to :meth:`add_evidence`, and take :meth:`grid`.

    Parameters
    ----------
    index0 : (3,) int, lattice index of the box's voxel [0, 0, 0]
    shape : (3,) int, voxels per axis
    voxel_size : h, metres
    n_classes : number of label ids of the annotations (0 = unlabelled)
    max_range : metres, depth beyond it is ignored (0: keep all)
    min_points, min_frames, min_hit_ratio, surface_tol, surface_tol_r2 : the rules (module docstring)
    """

    def __init__(self, index0, shape, voxel_size: float, n_classes: int, max_range: float = 0.0, *,
                 min_points: int, min_frames: int, min_hit_ratio: float, surface_tol: float, surface_tol_r2: float):
        self.index0 = np.asarray(index0, dtype=np.int64).reshape(3)
        self.shape = tuple(int(s) for s in shape)
        self.h = float(voxel_size)
        self.n_classes = int(n_classes)
        self.max_range = float(max_range)
        self.min_points, self.min_frames = int(min_points), int(min_frames)
        self.min_hit_ratio = float(min_hit_ratio)
        self.tol0, self.tol2 = float(surface_tol), float(surface_tol_r2)
        n = int(np.prod(self.shape))
        self._cnt = [np.zeros((2, n * FINE), np.int32) for _ in range(3)]
        self._off = [np.zeros((2, n * FINE), np.int64) for _ in range(3)]
        self._den = [np.zeros(n * FINE, np.int64) for _ in range(3)]
        self.surface: list[np.ndarray] | None = None
        self.hit_frames = np.zeros(n, np.int32)
        self.hit_points = np.zeros(n, np.int32)
        self.see_frames = np.zeros(n, np.int32)
        self.seen = np.zeros(n, bool)
        self._hit_stamp = np.full(n, -1, np.int32)
        self._see_stamp = np.full(n, -1, np.int32)
        self._votes: list[tuple[np.ndarray, np.ndarray]] = []
        self._pos_votes: list[tuple[np.ndarray, np.ndarray]] = []
        self._cells: list[np.ndarray] = []
        self.frames = 0
        self.evidence_frames = 0
        self.annotated = 0
        self.stats: dict[str, int] = {}

    def _lift(self, depth, T):
        depth = np.ascontiguousarray(depth, dtype=np.float32)
        T = np.ascontiguousarray(T, dtype=np.float64)
        H, W = depth.shape
        P = np.zeros((H, W, 3))
        ok = np.zeros((H, W), bool)
        _world_points(depth, T, self.max_range, P, ok)
        return depth, T, P, ok

    def add_density(self, depth: np.ndarray, T_world_cam: np.ndarray) -> None:
        """Pass 1: one frame's points into the columns. depth (H, W) metres radial (0 invalid), T (4, 4)."""
        if self.surface is not None:
            raise PanovoccError("add_density after settle(): the consensus is already taken")
        depth, T, P, ok = self._lift(depth, T_world_cam)
        axis = np.empty(depth.shape, np.int8)
        _normal_axes(P, ok, depth, NORMAL_STEP, axis)
        c, o, d = self._cnt, self._off, self._den
        _density_kernel(P, ok, axis, depth, T[:3, 3].copy(), self.h, self.index0, np.asarray(self.shape, np.int64),
                        self.tol2 * KERNEL_R2,
                        c[0], o[0], d[0], c[1], o[1], d[1], c[2], o[2], d[2])
        self.frames += 1

    def settle(self) -> None:
        """Take the consensus: each column's surface modes and their voxels (module docstring, 2)."""
        n = int(np.prod(self.shape))
        self.surface = []
        self.modes = 0
        faces = []
        for a in range(3):
            sh = list(self.shape)
            sh[a] *= FINE
            bins, pos, strength, sides = column_modes(self._cnt[a].reshape([2] + sh), self._off[a].reshape([2] + sh),
                                                      self._den[a].reshape(sh), a, self.min_points)
            S = np.full(n, np.nan)
            F = np.full((n, 2), np.nan)
            if len(bins):
                t = (self.index0[a] * FINE + pos) / FINE  # voxel units of the lattice
                vox = bins.copy()
                vox[:, a] = np.floor(t + GT_BOUNDARY_EPS).astype(np.int64) - self.index0[a]
                inside = (vox[:, a] >= 0) & (vox[:, a] < self.shape[a])
                vox, t, strength, sides = vox[inside], t[inside], strength[inside], sides[inside]
                lin = np.ravel_multi_index(tuple(vox.T), self.shape)
                order = np.lexsort((lin, -strength))  # two modes in one voxel: the stronger (then the first)
                lin, t, sides = lin[order], t[order], sides[order]
                _, first = np.unique(lin, return_index=True)
                S[lin[first]] = t[first] * self.h
                F[lin[first]] = (self.index0[a] * FINE + sides[first]) / FINE * self.h
                self.modes += len(first)
            self.surface.append(S)
            faces.append(F)
        vox, owner = [], []
        for a in range(3):
            m = int(np.isfinite(self.surface[a]).sum()) * 2 * SPAN_MAX
            ov, oo = np.empty(m, np.int64), np.empty(m, np.int64)
            k = _spans(self.surface[a], faces[a], a, int(self.index0[a]), np.asarray(self.shape, np.int64), self.h,
                       int(SPAN_MAX), ov, oo)
            vox.append(ov[:k])
            owner.append(oo[:k])
        self.span_vox, self.span_owner = np.concatenate(vox), np.concatenate(owner)
        self._cnt = self._off = self._den = None  # the counts are no longer needed

    def add_evidence(self, depth: np.ndarray, T_world_cam: np.ndarray, labels: np.ndarray | None = None) -> None:
        """Pass 2: one frame's support, see-through and seen voxels; ``labels`` (H, W) class ids of an
        annotated frame (0 = unlabelled) vote in the surface voxels their points support."""
        if self.surface is None:
            raise PanovoccError("add_evidence before settle(): take the consensus first")
        depth, T, P, ok = self._lift(depth, T_world_cam)
        H, W = depth.shape
        pix = np.empty((H, W), np.int64)
        cell = np.empty((H, W), np.int64)
        pos = np.empty((H, W), np.int64)
        S = self.surface
        _evidence_kernel(depth, P, ok, T, self.h, self.index0, np.asarray(self.shape, np.int64),
                         np.int32(self.evidence_frames), carve_stride(W), self.tol0, self.tol2, S[0], S[1], S[2],
                         self.hit_frames, self.hit_points, self._hit_stamp, self.see_frames, self._see_stamp,
                         self.seen, pix, cell, pos)
        self.evidence_frames += 1
        if labels is None:
            return
        lab = np.asarray(labels)
        if lab.shape != depth.shape:
            raise PanovoccError(f"labels {lab.shape} and depth {depth.shape} differ in size")
        C = self.n_classes
        self._votes.append(frame_votes(pix, lab, C))  # in the surface voxel each point supports
        self._pos_votes.append(frame_votes(pos, lab, C))  # and in the voxel it lies in
        m = (pix >= 0) & (lab > 0)
        self._cells.append(np.unique((pix[m] * C + lab[m].astype(np.int64)) * AREA_CELLS + cell[m]))
        self.annotated += 1

    def _spanned(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The confirmed mode voxels (n,) bool, and the span voxels (module docstring, 2b) they reach that
        are not confirmed mode voxels themselves, with their mode voxel."""
        if self.surface is None:
            raise PanovoccError("occupied() before settle()")
        cand = np.isfinite(self.surface[0]) | np.isfinite(self.surface[1]) | np.isfinite(self.surface[2])
        hf = self.hit_frames.astype(np.int64)
        base = cand & (hf >= self.min_frames) & (hf >= self.min_hit_ratio * (hf + self.see_frames))
        keep = base[self.span_owner] & ~base[self.span_vox]
        return base, self.span_vox[keep], self.span_owner[keep]

    def occupied(self) -> np.ndarray:
        """(n,) bool over the box: surface voxels the rays confirm, and the voxels their surfaces span
        (module docstring, 3)."""
        base, vox, _ = self._spanned()
        occ = base.copy()
        occ[vox] = True
        return occ

    def grid(self, class_names: list[str], label_radius: float) -> Grid:
        """The lifted grid: 0 seen free, 1..253 class, 254 occupied without class, 255 never observed. A span
        voxel takes the votes of the mode voxels whose surfaces span it (module docstring, 4)."""
        base, vox, owner = self._spanned()
        occ = base.copy()
        occ[vox] = True
        votes = list(self._votes)
        if votes and len(vox):
            keys = np.concatenate([k for k, _ in votes])
            w = np.concatenate([v for _, v in votes])
            order = np.argsort(keys, kind="stable")
            keys, w = keys[order], w[order]
            C = self.n_classes
            start = np.searchsorted(keys, owner * C)
            n = np.searchsorted(keys, (owner + 1) * C) - start
            rep = np.repeat(np.arange(len(owner)), n)
            at = np.repeat(start - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
            votes.append((vox[rep] * C + keys[at] % C, w[at]))
        area = None
        if self._cells:
            area = np.unique(np.unique(np.concatenate(self._cells)) // AREA_CELLS, return_counts=True)
        g, self.stats = label_grid(occ, self.seen & ~occ, votes + self._pos_votes, self.n_classes, class_names,
                                   label_radius, self.index0, self.shape, self.h, area, self.surface)
        self.stats["modes"] = self.modes
        self.stats["spanned"] = int(occ.sum() - base.sum())
        return g
