"""The per-frame update: one ERP frame (depth, pose) to its sparse geometric delta (A, N, F, O).

1. lift the strided samples to kernels (:mod:`.surfel`, or :mod:`.rays` for the ``box`` / ``centre``
   extents and the ``point`` ablation);
2. the frame box: the lattice box that holds the camera and every kernel's support;
3. splat the kernels into a dense support grid A (:mod:`.splat`);
4. free space F and valid comparisons O (:mod:`..freespace`);
5. N: the voxels that hold a measurement (with the surfel kernel, also those within ``hit_k`` s_n of
   it along the normal: a plane on a voxel face counts in both voxels; a noisy measurement within
   ``hit_amb`` s_n of a face counts in neither), or where A >= ``n_fill``;
6. extraction of the voxels with support, a measurement or a comparison, in lattice order.

Steps 3-6 run a slab of whole x-planes of the frame box at a time (:data:`SLAB_VOXELS`), so the dense grids
a frame needs are a slab's, not its box's; the delta is the same bit for bit.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...errors import PanovoccError
from ...geometry.lattice import pack_index
from ...runtime import keep_freed_heap  # noqa: F401 (applied by runtime.setup(), not at import)
from ..freespace import carve, free_thresholds
from ..memory import FIXED_SCALE, Delta
from ..params import EXTENTS, KERNELS, GeometryParams
from .rays import lift_kernels
from .splat import local_voxel, splat, splat_axis
from .surfel import surfels_for

MAX_FRAME_VOXELS = 64_000_000  # a frame's dense working box may not exceed this many voxels


_pack = nb.njit(inline="always")(pack_index)  # the lattice's key layout, compiled into _extract

@nb.njit(cache=True)
def _hit_cells(x, h, lo, nx, ny, nz):
    """The frame box's cells ((i ny + j) nz + k, int64) that contain a measurement x (metres, world); a cell
    may repeat (:func:`_mark_cells` sets the flags of a slab of the box from them)."""
    cells = np.empty(x.shape[0], np.int64)
    m = 0
    for p in range(x.shape[0]):
        i, j, k, inside = local_voxel(x, p, h, lo, (nx, ny, nz))
        if inside:
            cells[m] = (i * ny + j) * nz + k
            m += 1
    return cells[:m]


@nb.njit(cache=True)
def _hit_cells_axis(x, ax, sa, surf, n_floor, k, s_max, k_amb, h, lo, nx, ny, nz):
    """The frame box's cells (as :func:`_hit_cells`) that contain a measurement x and, for a precise surfel
    (``surf`` 1, ``s = s_axis - n_floor`` <= ``s_max``: s is the standard deviation of the fitted position
    along the normal), those of the ends of its uncertainty segment ``x +- k s axis`` (metres, world): a
    measurement that close to a voxel face counts as a view of both voxels of the face. An imprecise
    surfel (s > s_max) whose segment ``x +- k_amb s axis`` crosses a voxel face marks no voxel: its own
    noise does not say on which side of the face the surface lies, and counting it in the voxel it fell
    in makes a plane within a few s of a face occupy both voxels (each noisy frame spills into the far
    one). ``k_amb = 0`` counts every imprecise measurement where it fell."""
    cells = np.empty(3 * x.shape[0], np.int64)
    m = 0
    for p in range(x.shape[0]):
        s = max(sa[p] - n_floor, 0.0) if surf[p] != 0 else 0.0
        if s > s_max:
            if k_amb > 0.0:
                d = k_amb * s
                amb = False
                for c in range(3):
                    if np.floor((x[p, c] - d * ax[p, c]) / h) != np.floor((x[p, c] + d * ax[p, c]) / h):
                        amb = True
                if amb:
                    continue
            s = 0.0
        else:
            s = k * s
        for e in range(3):
            f = s * (e - 1)
            i = int(np.floor((x[p, 0] + f * ax[p, 0]) / h)) - lo[0]
            j = int(np.floor((x[p, 1] + f * ax[p, 1]) / h)) - lo[1]
            kk = int(np.floor((x[p, 2] + f * ax[p, 2]) / h)) - lo[2]
            if 0 <= i < nx and 0 <= j < ny and 0 <= kk < nz:
                cells[m] = (i * ny + j) * nz + kk
                m += 1
    return cells[:m]


@nb.njit(cache=True)
def _mark_cells(cells, first, hits):
    """Set ``hits`` (uint8, the frame box's x-planes ``first``.. of it) to 1 in those of ``cells`` it holds."""
    flat = hits.reshape(hits.size)
    c0 = first * hits.shape[1] * hits.shape[2]
    for c in cells:
        if c0 <= c < c0 + flat.size:
            flat[c - c0] = 1


@nb.njit(cache=True, inline="always")
def _voxel_row(a, hit, o, scale, n_fill, observe_hits):
    """A voxel's fixed-point support, its frame count (a measurement inside, or support >= n_fill), its
    observation count (a valid comparison of its centre; with ``observe_hits`` also a frame count: a frame
    that saw surface in the voxel observed it, so N <= O) and whether it enters the delta (support, a
    measurement or a valid comparison)."""
    q = np.int64(np.rint(a * scale))
    n = 1 if (hit != 0 or q >= n_fill) else 0
    oo = 1 if (o != 0 or (observe_hits and n != 0)) else 0
    return q, n, oo, o != 0 or q != 0 or n != 0


@nb.njit(cache=True, parallel=True)
def _extract(A, hits, F, O, lo, scale, n_fill, observe_hits):
    """The voxels with support, a measurement or O != 0, in lattice order: their keys (int64), A (fixed point,
    int64) and N, F, O (uint8 (cnt, 3)). Two passes over slabs of constant i (count, then fill at each slab's
    prefix offset). :func:`_delta_rows` joins the parts of a frame box into the delta's rows."""
    nx, ny, nz = A.shape
    counts = np.zeros(nx + 1, np.int64)
    for i in nb.prange(nx):
        c = 0
        for j in range(ny):
            for k in range(nz):
                if _voxel_row(A[i, j, k], hits[i, j, k], O[i, j, k], scale, n_fill, observe_hits)[3]:
                    c += 1
        counts[i + 1] = c
    for i in range(nx):
        counts[i + 1] += counts[i]
    cnt = counts[nx]
    keys = np.empty(cnt, np.int64)
    a_out = np.empty(cnt, np.int64)
    nfo = np.empty((cnt, 3), np.uint8)
    for i in nb.prange(nx):
        n = counts[i]
        for j in range(ny):
            for k in range(nz):
                a, nn, oo, keep = _voxel_row(A[i, j, k], hits[i, j, k], O[i, j, k], scale, n_fill, observe_hits)
                if keep:
                    keys[n] = _pack(i + lo[0], j + lo[1], k + lo[2])
                    a_out[n] = a
                    nfo[n, 0] = nn
                    nfo[n, 1] = F[i, j, k]
                    nfo[n, 2] = oo
                    n += 1
    return keys, a_out, nfo


@nb.njit(cache=True, parallel=True)
def _put_rows(keys, rows, o, k, a, nfo):
    """Write one :func:`_extract` part (keys ``k``, A ``a``, N F O ``nfo``) into ``keys`` and ``rows`` (n, 4)
    (int32 or int64, :func:`_delta_rows`) from row ``o`` on."""
    for r in nb.prange(k.shape[0]):
        keys[o + r] = k[r]
        rows[o + r, 0] = a[r]
        rows[o + r, 1] = nfo[r, 0]
        rows[o + r, 2] = nfo[r, 1]
        rows[o + r, 3] = nfo[r, 2]


_I32 = np.iinfo(np.int32)


def _delta_rows(parts: list) -> tuple:
    """The frame's keys (n,) int64 and rows (n, 4) (A N F O) from its box's :func:`_extract` parts, in
    order (each written once into the arrays the delta keeps: no second copy of every row). The rows are
    int32 when every A fits (N F O are 0/1 flags; A a frame's fixed-point support, at most a few units:
    always, in practice), else int64: 24 bytes a row with the key instead of 40, the largest array of a
    frame's working set (docs/mapping.md, "The house's peak, fourth pass"); the values are the same either
    way. Empties ``parts``: each part is freed once written, so the parts (19 bytes a row) and the rows
    are not all alive at once (docs/mapping.md, "The per-frame working set")."""
    n = sum(len(k) for k, _, _ in parts)
    fits = all(len(a) == 0 or (_I32.min <= int(a.min()) and int(a.max()) <= _I32.max) for _, a, _ in parts)
    keys = np.empty(n, np.int64)
    rows = np.empty((n, 4), np.int32 if fits else np.int64)
    o = 0
    parts.reverse()
    while parts:
        k, a, nfo = parts.pop()
        _put_rows(keys, rows, o, k, a, nfo)
        o += len(k)
        del k, a, nfo
    return keys, rows


@nb.njit(cache=True)
def _kernel_bounds(x, half, kappa):
    """Per-axis min of x - kappa half and max of x + kappa half over the kernels (same values as numpy)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for p in range(x.shape[0]):
        for d in range(3):
            lo[d] = min(lo[d], x[p, d] - kappa * half[p, d])
            hi[d] = max(hi[d], x[p, d] + kappa * half[p, d])
    return lo, hi


def frame_box(x_world, half, kappa, cam_pos, voxel_size: float, max_range: float):
    """Lattice box covering the camera and every kernel's bounding box, cut at max_range.

    Parameters
    ----------
    x_world : (n, 3) float64, kernel centres, metres, world frame
    half : (n, 3) float64, per-axis half extents of the kernels' support, metres
    kappa : float, factor on ``half``
    cam_pos : (3,) float64, camera centre, metres, world frame

    Returns
    -------
    lo : (3,) int64, lattice index of the box's first voxel; shape : (3,) int64, voxels per axis
    """
    h = voxel_size
    if len(x_world):
        kmin, kmax = _kernel_bounds(np.ascontiguousarray(x_world, np.float64), np.ascontiguousarray(half, np.float64),
                                    float(kappa))
        pmin = np.minimum(kmin, cam_pos)
        pmax = np.maximum(kmax, cam_pos)
    else:
        pmin = pmax = cam_pos
    pmin = np.maximum(pmin, cam_pos - max_range)
    pmax = np.minimum(pmax, cam_pos + max_range)
    lo = np.floor(pmin / h).astype(np.int64) - 1
    hi = np.floor(pmax / h).astype(np.int64) + 1
    return lo, hi - lo + 1


def geometry_delta(depth: np.ndarray, T_world_cam: np.ndarray, p: GeometryParams) -> Delta:
    """One ERP frame's geometric delta (A fixed point, N, F, O) on the global lattice (:func:`geometry_parts`
    without the surface-offset part).

    Parameters
    ----------
    depth : (H, W) float32, metres, radial, 0 = invalid
    T_world_cam : (4, 4) float64

    Returns
    -------
    Delta with channels A (fixed point, FIXED_SCALE), N (0/1: a measurement of the frame lies in the
    voxel, or, for psvf, its kernel support there is at least ``n_fill``), F (0/1), O (0/1)
    """
    return _geometry(depth, T_world_cam, p, False)[0]


def geometry_parts(depth: np.ndarray, T_world_cam: np.ndarray, p: GeometryParams) -> tuple:
    """One ERP frame's geometric delta (:func:`geometry_delta`) and, with ``p.offsets``, its surface-offset
    part (channel P over the voxels holding measurements, :func:`_offset_rows`): a tuple of one or two
    :class:`Delta`."""
    return _geometry(depth, T_world_cam, p, p.offsets)


def _geometry(depth, T_world_cam, p: GeometryParams, offsets: bool) -> tuple:
    if p.kernel not in KERNELS:
        raise PanovoccError(f"unknown kernel {p.kernel!r} (expected psvf or point)")
    c_norm = 1.0 / (2.0 * np.pi) if p.kernel == "psvf" else 1.0
    if p.extent not in EXTENTS:
        raise PanovoccError(f"unknown kernel extent {p.extent!r} (expected surfel, box or centre)")
    if p.kernel == "psvf" and p.extent == "surfel":
        x, Pt, half, w, ax, sa, bb, surf = surfels_for(depth, T_world_cam, p, c_norm)
        lo, shape = frame_box(x, half, 1.0, T_world_cam[:3, 3], p.voxel_size, p.max_range)
        _check_box(shape)
        parts = _slab_parts(lambda lo_s, shape_s: splat_axis(x, Pt, half, w, ax, sa, bb, p.kappa, p.voxel_size, lo_s,
                                                             shape_s), x, depth, T_world_cam, p, lo, shape, (ax, sa, surf))
        if offsets:
            return _rows_delta(parts), offset_delta(x, ax, T_world_cam[:3, 3], p.voxel_size)
        del x, Pt, half, w, ax, sa, bb, surf  # the surfels freed before the rows are joined (_rows_delta)
        return (_rows_delta(parts),)
    x, P, half, w = lift_kernels(depth, T_world_cam, p.stride, p.alpha, p.beta, p.min_range, p.max_range,
                                 p.w_pole, p.r_half, c_norm)
    er = sr = None
    kern = p.kernel
    box_half = half
    if p.kernel == "point":
        box_half = half = np.full_like(half, p.voxel_size)
    elif p.extent == "box":
        v = x - T_world_cam[:3, 3]
        rr = np.sqrt((v * v).sum(1))
        er = v / rr[:, None]  # ray directions (world)
        sr = p.alpha * rr + p.beta  # radial scales
        kern = "box"
        box_half = half + 0.5 * p.voxel_size * np.abs(er) / p.kappa  # the splat's reach includes the chord
    lo, shape = frame_box(x, box_half, p.kappa, T_world_cam[:3, 3], p.voxel_size, p.max_range)
    _check_box(shape)
    parts = _slab_parts(lambda lo_s, shape_s: splat(x, P, half, w, p.kappa, p.voxel_size, lo_s, shape_s, kern, er, sr),
                        x, depth, T_world_cam, p, lo, shape)
    if not offsets:
        del x, P, half, w, box_half, er, sr  # the kernels freed before the rows are joined (_rows_delta)
        return (_rows_delta(parts),)
    d = _rows_delta(parts)
    v = T_world_cam[:3, 3] - x  # these kernels have no normal: the ray, towards the camera
    return d, offset_delta(x, v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12), T_world_cam[:3, 3],
                           p.voxel_size)


OFFSET_STEPS = 254  # channel P: a mean offset's unit, 1/OFFSET_STEPS of the voxel edge (|q| <= 127: int8 per frame)
NORMAL_UNIT = 127  # channel P: a mean normal component's unit, 1/NORMAL_UNIT


@nb.njit(cache=True)
def _offset_rows(x, nrm, cam, h):
    """The frame's surface-offset rows (docs/mapping.md, step 4, channel P): per voxel holding measurements
    x ((n, 3) metres), in key order, its key and ``[1, q (3), m (3), q^2 (3)]`` int64: q the measurements'
    mean offset from the voxel's centre per axis in 1/OFFSET_STEPS of the edge h, m their mean unit normal
    ``nrm`` turned towards the camera ``cam`` in 1/NORMAL_UNIT (each rounded to the nearest integer), and
    the squares of q (summed over frames: the spread of the frames' mean positions)."""
    n = x.shape[0]
    keys = np.empty(n, np.int64)
    for p in range(n):
        keys[p] = _pack(np.int64(np.floor(x[p, 0] / h)), np.int64(np.floor(x[p, 1] / h)),
                        np.int64(np.floor(x[p, 2] / h)))
    order = np.argsort(keys, kind="mergesort")
    uk = np.empty(n, np.int64)
    rows = np.zeros((n, 10), np.int64)
    acc = np.zeros(6)
    m = 0
    cnt = 0
    for t in range(n + 1):
        if t == n or (t > 0 and keys[order[t]] != keys[order[t - 1]]):
            if cnt:
                rows[m, 0] = 1
                for c in range(3):
                    q = np.int64(np.rint(acc[c] / cnt * OFFSET_STEPS))
                    rows[m, 1 + c] = q
                    rows[m, 4 + c] = np.int64(np.rint(acc[3 + c] / cnt * NORMAL_UNIT))
                    rows[m, 7 + c] = q * q
                uk[m] = keys[order[t - 1]]
                m += 1
            acc[:] = 0.0
            cnt = 0
        if t == n:
            break
        p = order[t]
        s = 0.0
        for c in range(3):
            s += nrm[p, c] * (cam[c] - x[p, c])
        sg = 1.0 if s >= 0.0 else -1.0
        for c in range(3):
            acc[c] += x[p, c] / h - (np.floor(x[p, c] / h) + 0.5)
            acc[3 + c] += sg * nrm[p, c]
        cnt += 1
    return uk[:m], rows[:m]


def offset_delta(x, nrm, cam, voxel_size: float) -> Delta:
    """The frame's surface-offset part: channel P (:func:`_offset_rows`) of the measurements ``x`` ((n, 3)
    metres) with unit normals ``nrm`` ((n, 3)) seen from the camera centre ``cam`` ((3,) metres)."""
    keys, rows = _offset_rows(np.ascontiguousarray(x, np.float64), np.ascontiguousarray(nrm, np.float64),
                              np.ascontiguousarray(cam, np.float64), float(voxel_size))
    return Delta(keys, {"P": rows})


def _check_box(shape) -> None:
    if int(np.prod(shape)) > MAX_FRAME_VOXELS:
        raise PanovoccError(f"a frame spans {shape.tolist()} voxels (over {MAX_FRAME_VOXELS}); "
                            "lower --max-range or raise --voxel-size")


SLAB_VOXELS = 1 << 18
"""A frame box is splatted, carved and extracted a slab of whole x-planes at a time, about this many voxels
(at least one plane): the frame's dense working set (two float64 support grids, F, O and the hit flags:
19 bytes a voxel) stays bounded by the slab, not the box (docs/mapping.md, "Memory layout"). The delta is
the same bit for bit whatever the slab (each voxel's support sums the same kernels in the same order)."""


def _slab_parts(splat_box, x, depth, T_world_cam, p: GeometryParams, lo, shape, surfels=None) -> list:
    """Support, free-space test and extraction of the frame's sparse delta, a slab of the frame box (``lo``,
    ``shape``) at a time: the slabs' :func:`_extract` parts, which :func:`_rows_delta` joins into the delta
    (the caller drops its kernels in between). ``splat_box(lo_s, shape_s)`` gives the dense support grid A of a part of the box;
    its measurements x ((n, 3) metres, world: the voxels that contain one count in N; with the surfel
    kernel's ``surfels`` = (axes (n, 3), scales (n,) metres, surfel flags (n,) uint8), so do the voxels
    that contain ``x +- hit_k (s - n_floor) n`` of each surfel with s - n_floor <= hit_max; a surfel with
    s - n_floor > hit_max whose segment ``x +- hit_amb (s - n_floor) n`` crosses a face marks none)."""
    lo = np.asarray(lo, np.int64)
    nx, ny, nz = (int(s) for s in shape)
    fthr = free_thresholds(depth, T_world_cam, p.voxel_size, p.eps_abs, p.eps_rel, p.stable_k, p.carve_extent)
    n_fill = np.int64(np.ceil(p.n_fill * FIXED_SCALE)) if p.kernel == "psvf" else np.int64(1) << 62
    x = np.ascontiguousarray(x, np.float64)
    if surfels is not None and (p.hit_k > 0 or p.hit_amb > 0):
        ax, sa, surf = surfels
        cells = _hit_cells_axis(x, np.ascontiguousarray(ax, np.float64), np.ascontiguousarray(sa, np.float64),
                                np.ascontiguousarray(surf), float(p.n_floor), float(p.hit_k), float(p.hit_max),
                                float(p.hit_amb), float(p.voxel_size), lo, nx, ny, nz)
    else:
        cells = _hit_cells(x, float(p.voxel_size), lo, nx, ny, nz)
    step = max(1, SLAB_VOXELS // max(ny * nz, 1))
    parts = []
    for i0 in range(0, nx, step):
        lo_s = lo + np.array([i0, 0, 0], np.int64)
        shape_s = (min(step, nx - i0), ny, nz)
        A = splat_box(lo_s, shape_s)
        F, O = carve(depth, T_world_cam, p.voxel_size, lo_s, shape_s, p.eps_abs, p.eps_rel, p.stable_k,
                     p.min_range, p.max_range, p.carve_extent, fthr=fthr)
        hits = np.zeros(shape_s, np.uint8)
        _mark_cells(cells, i0, hits)
        parts.append(_extract(A, hits, F, O, lo_s, float(FIXED_SCALE), n_fill, bool(p.observe_hits)))
        del A, F, O, hits
    return parts


def _rows_delta(parts: list) -> Delta:
    """The geometric delta of a frame box's :func:`_slab_parts` (empties ``parts``)."""
    keys, rows = _delta_rows(parts)
    return Delta(keys, {"A": rows[:, 0:1], "N": rows[:, 1:2], "F": rows[:, 2:3], "O": rows[:, 3:4]})
