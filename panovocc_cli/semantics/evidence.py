"""Per-frame semantic evidence (paper Eq. memory_semantic_delta), compiled (numba), no I/O.

Each valid pixel p of frame t at the semantic stride is one semantic measurement: its kept observation
(:mod:`.observation`: the two most probable classes and their probabilities in 1/15 steps) gives a
distribution over the vocabulary and a confidence ``c`` (its maximum class probability), and its weight is
``eta = c * w_erp(phi) * w_range(r)``. A voxel's per-frame delta sums, over the pixels whose surface point falls in it,
``eta * p`` (channel ``E``) and ``eta`` (channel ``S``), plus the geometry statistics GSC needs:
``rgb_sum`` and ``normal_sum`` (plain, unweighted sums, so the mean colour/normal is ``sum / count``
and does not depend on the segmenter) and ``count`` (pixels). Subtracting a frame's delta undoes it
exactly, which is what ``panovocc revise`` does.

Defaults (:class:`EvidenceWeights`) and why:

* ``w_erp(phi) = clip(cos(phi) ** erp_power, erp_floor, 1)`` with ``erp_power = 1``, ``erp_floor = 0.05``:
  an ERP pixel covers a solid angle proportional to ``cos(phi)``, so rows near the poles, which ERP
  oversamples and where panoramic segmenters are least reliable, count proportionally less;
* ``w_range(r) = 1 / (1 + (r / range_scale) ** 2)`` with ``range_scale = 4 m``: far surfaces are seen
  at lower resolution and with noisier depth; 0 for ``r <= 0`` (no measurement).

The plain-numpy chain these kernels compute (``erp_normals``, ``softmax``, ``measurement_weights``,
``semantic_frame_delta``) is the tests' reference, in tests/semantics_reference.py.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..errors import PanovoccError
from ..geometry.lattice import pack_index
from .observation import Q_LEVELS
from .params import EvidenceWeights  # noqa: F401  (re-export: its public home until now)


def w_erp(phi, power: float = 1.0, floor: float = 0.05) -> np.ndarray:
    """Latitude weight ``clip(cos(phi) ** power, floor, 1)``; ``phi`` radians, 0 at the equator."""
    return np.clip(np.cos(np.asarray(phi, dtype=np.float64)) ** power, floor, 1.0)


def frame_semantic_delta(depth: np.ndarray, rgb: np.ndarray, obs, T_world_cam: np.ndarray,
                         voxel_size: float, weights: EvidenceWeights = EvidenceWeights(),
                         rays: np.ndarray | None = None, depth_range: tuple[float, float] | None = None):
    """The whole per-frame semantic step for one ERP frame: back-project, weigh, accumulate (compiled).

    Per measurement pixel (rows and columns ``0, s, 2s, ...``, ``s = weights.stride``) of the frame's
    :class:`~.observation.SemanticObservation`: its world point, its normal (the rule of the tests'
    ``erp_normals``), its weight ``eta = float32(c w_erp w_range) * s^2`` with the observation's confidence ``c``, and
    ``eta`` times its two classes' shares added to ``E``. Two numba kernels: a pass over fixed row chunks
    in parallel finding each pixel's voxel, and per-chunk sums in pixel order merged in chunk order, so
    the float sums never depend on the thread count (tests/semantics/test_semantics_evidence.py checks
    them against the numpy reference in tests/semantics_reference.py).

    Parameters
    ----------
    depth : (H, W) float, metres, radial, 0 = invalid
    rgb : (H, W, 3) uint8
    obs : SemanticObservation at the semantic stride: shape (ceil(H/s), ceil(W/s))
    T_world_cam : (4, 4) float64, camera-to-world pose
    voxel_size : float, metres
    weights : EvidenceWeights (``stride``: which pixels are measurements, and their weight stride^2)
    rays : (H, W, 3) float, optional precomputed :func:`geometry.erp.ray_directions`
    depth_range : (min, max) metres, optional: depths outside it are no measurement (applied to the
        measurement pixels only; the same values as masking the whole frame first)

    Returns
    -------
    keys : (n,) int64 sorted voxel keys (lattice.pack_keys) of the voxels with a measurement
    channels : dict of float sums over each voxel's pixels: ``E`` (n, C) sum of eta * share, ``S`` (n,) sum
        of eta, ``rgb_sum`` (n, 3), ``normal_sum`` (n, 3) (world frame), ``count`` (n,) int64 pixels
    """
    from ..geometry.erp import latitudes, ray_directions
    from ..geometry.lattice import KEY_RANGE

    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise PanovoccError(f"depth must be (H, W), got shape {depth.shape}")
    H, W = depth.shape
    s = int(weights.stride)
    if s < 1:
        raise PanovoccError(f"semantic stride must be >= 1, got {s}")
    h, w = -(-H // s), -(-W // s)  # the measurement grid: rows and columns 0, s, 2s, ...
    if np.shape(rgb)[:2] != (H, W) or tuple(obs.shape) != (h, w):
        raise PanovoccError(f"depth {depth.shape} and rgb {np.shape(rgb)[:2]} must have the same size, and the "
                            f"semantic observation {tuple(obs.shape)} the size at the semantic stride {s}: {(h, w)}")
    if voxel_size <= 0:
        raise PanovoccError(f"voxel size must be positive, got {voxel_size}")
    if rays is None:
        rays = ray_directions(W, H)
    if s > 1:
        depth, rgb, rays = depth[::s, ::s], np.asarray(rgb)[::s, ::s], np.asarray(rays)[::s, ::s]
    if depth_range is not None:  # on the measurement pixels only: a quarter of the frame at stride 2
        lo, hi = depth_range
        depth = np.where((depth >= lo) & (depth <= hi), depth, 0.0).astype(np.float32)
    depth = np.ascontiguousarray(depth, dtype=np.float64)
    # the rays and colours stay views at the stride, read by the kernels as they are (copying them cost 0.9 and
    # 0.5 ms a frame at 1024x512)
    rays = np.asarray(rays, dtype=np.float64)
    rgb = np.asarray(rgb, dtype=np.uint8)
    q = np.ascontiguousarray(obs.q, dtype=np.uint8)  # confidence and shares per pixel: _pixel_measurement
    classes = np.ascontiguousarray(obs.classes, dtype=np.uint8)
    T = np.asarray(T_world_cam, np.float64)
    R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
    werp = w_erp(latitudes(H)[::s], weights.erp_power, weights.erp_floor).astype(np.float64)
    nch = min(N_CHUNKS, h)
    lid = np.empty(h * w, np.int32)
    ckeys = np.empty(h * w, np.int64)
    nvox = np.zeros(nch, np.int64)
    if _chunk_voxels(depth, rays, werp, float(weights.range_scale), R, t, float(voxel_size), int(KEY_RANGE),
                     nch, lid, ckeys, nvox):
        raise PanovoccError(f"voxel index out of the lattice's range (|index| < {KEY_RANGE})")
    feats = obs.features if getattr(obs, "features", None) is not None else np.zeros((h, w, 0), np.int8)
    feats = np.ascontiguousarray(feats, dtype=np.int8)
    E, S, rgb_sum, normal_sum, count, Z, allkeys = _chunk_sums(depth, rays, classes, q, int(obs.n_classes),
                                                               rgb, werp, float(weights.range_scale), R, 0.1, nch,
                                                               lid, ckeys, nvox, float(s * s), feats)
    order = np.argsort(allkeys, kind="stable")  # same key: chunks stay in chunk order
    uk, E, S, rgb_sum, normal_sum, count, Z = _merge_chunks(allkeys, order, E, S, rgb_sum, normal_sum, count, Z)
    if (count == 0).any():  # voxels whose every pixel had eta = 0 (confidence 0, or float32 underflow)
        keep = count > 0
        uk, E, S, rgb_sum, normal_sum, count, Z = (uk[keep], E[keep], S[keep], rgb_sum[keep], normal_sum[keep],
                                                   count[keep], Z[keep])
    out = {"E": E, "S": S, "rgb_sum": rgb_sum, "normal_sum": normal_sum, "count": count}
    if feats.shape[2]:
        out["Z"] = Z
    return uk, out


# ---------------------------------------------------------------------------------------------
# Compiled kernels of frame_semantic_delta

_pack = nb.njit(inline="always")(pack_index)  # the lattice's key layout, compiled into the kernels

@nb.njit(cache=True, inline="always")
def _slot(key, bits):
    """Fibonacci hash of a voxel key onto ``bits`` bits (the product's high bits: all key bits mix in)."""
    return np.int64((np.uint64(key) * np.uint64(11400714819323198485)) >> np.uint64(64 - bits))


@nb.njit(cache=True, inline="always")
def _pixel_measurement(q1, q2):
    """One pixel's confidence and its two classes' shares from its levels (q1, q2), float32: ``q1 / Q_LEVELS`` and
    ``(q1, q2) / (q1 + q2)``, 0 where the sum is 0 (the observation's definition, .observation), the same bits
    as the frame arrays of tests/semantics_reference.py's ``measurement``
    (tests/semantics/test_semantics_observation.py), made where the sums read them instead of as two arrays of the frame (1.1 ms a frame at 1024x512, stride 2)."""
    f1, f2 = np.float32(q1), np.float32(q2)
    tot = f1 + f2
    if tot > 0:
        return f1 / np.float32(Q_LEVELS), f1 / tot, f2 / tot
    return f1 / np.float32(Q_LEVELS), np.float32(0.0), np.float32(0.0)


N_CHUNKS = 32  # fixed row chunks of the per-frame sums: the bytes never depend on the thread count


@nb.njit(cache=True, parallel=True)
def _chunk_voxels(depth, rays, werp, range_scale, R, t, h, key_range, nch, lid, ckeys, nvox):
    """Pass 1 of the per-frame sums, over ``nch`` fixed row chunks in parallel: each chunk's distinct voxel
    keys in order of first appearance (``ckeys[first pixel of the chunk + i]``, ``nvox[c]`` of them) and
    every pixel's index into its chunk's list (``lid``, -1: no measurement). True if an index falls
    outside the lattice's key range.

    A pixel is a measurement where its depth is finite and > 0 and ``w_erp * w_range > 0`` (then eta > 0,
    the class confidence being at least 1/C); world point ``R p + t`` as ``p @ R.T + t``. Neighbouring
    pixels mostly share a voxel, so the last key is cached before the open-addressing table is probed.
    """
    H, W = depth.shape
    rows = (H + nch - 1) // nch
    bad = np.zeros(nch, np.bool_)
    for c in nb.prange(nch):
        v0 = min(H, c * rows)
        v1 = min(H, v0 + rows)
        base = v0 * W
        bits = 12
        cap = 1 << bits
        table = np.full(cap, -1, np.int64)  # slot -> index into the chunk's key list
        n = 0
        last_key = np.int64(-2)
        last = -1
        kb = np.empty(W, np.int64)
        badr = np.zeros(W, np.bool_)
        for v in range(v0, v1):
            wv = werp[v]
            for u in range(W):  # the row's keys first: no calls, no branches out, so this vectorises
                d = depth[v, u]
                p0, p1, p2 = rays[v, u, 0] * d, rays[v, u, 1] * d, rays[v, u, 2] * d
                x0 = p0 * R[0, 0] + p1 * R[0, 1] + p2 * R[0, 2] + t[0]
                x1 = p0 * R[1, 0] + p1 * R[1, 1] + p2 * R[1, 2] + t[1]
                x2 = p0 * R[2, 0] + p1 * R[2, 1] + p2 * R[2, 2] + t[2]
                f0, f1, f2 = np.floor(x0 / h), np.floor(x1 / h), np.floor(x2 / h)
                ok = (d > 0) and (d < np.inf) and wv * (1.0 / (1.0 + (d / range_scale) ** 2)) > 0
                out = (abs(f0) >= key_range) or (abs(f1) >= key_range) or (abs(f2) >= key_range)
                badr[u] = badr[u] or (ok and out)
                i0 = np.int64(f0) if ok and not out else 0
                i1 = np.int64(f1) if ok and not out else 0
                i2 = np.int64(f2) if ok and not out else 0
                key = _pack(i0, i1, i2)
                kb[u] = key if ok else np.int64(-1)
            for u in range(W):
                key = kb[u]
                if key < 0:
                    lid[v * W + u] = -1
                    continue
                if key != last_key:
                    slot = _slot(key, bits)
                    while True:
                        r = table[slot]
                        if r < 0 or ckeys[base + r] == key:
                            break
                        slot = (slot + 1) & (cap - 1)
                    if r < 0:
                        if 2 * (n + 1) > cap:  # grow: double the table, rehash
                            cap *= 2
                            bits += 1
                            table = np.full(cap, -1, np.int64)
                            for r2 in range(n):
                                s2 = _slot(ckeys[base + r2], bits)
                                while table[s2] >= 0:
                                    s2 = (s2 + 1) & (cap - 1)
                                table[s2] = r2
                            slot = _slot(key, bits)
                            while table[slot] >= 0:
                                slot = (slot + 1) & (cap - 1)
                        r = n
                        table[slot] = r
                        ckeys[base + r] = key
                        n += 1
                    last_key = key
                    last = r
                lid[v * W + u] = last
        nvox[c] = n
        bad[c] = badr.any()
    return bad.any()


@nb.njit(cache=True, inline="always")
def _row_points(depth, rays, v, P, rr, ok):
    """Camera-frame points ``P`` (3, W + 2), ranges ``rr`` and validity ``ok`` (finite depth > 0) of image
    row ``v``; pixel u at column u + 1, columns 0 and W + 1 repeat the last and first (longitude wraps)."""
    W = depth.shape[1]
    for u in range(W):
        d = depth[v, u]
        q0, q1, q2 = rays[v, u, 0] * d, rays[v, u, 1] * d, rays[v, u, 2] * d
        P[0, u + 1] = q0
        P[1, u + 1] = q1
        P[2, u + 1] = q2
        rr[u + 1] = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        ok[u + 1] = np.isfinite(d) and d > 0
    for k in range(3):
        P[k, 0] = P[k, W]
        P[k, W + 1] = P[k, 1]
    rr[0], rr[W + 1] = rr[W], rr[1]
    ok[0], ok[W + 1] = ok[W], ok[1]


@nb.njit(cache=True, inline="always")
def _difference(okf, okb, a0, a1, a2, p0, p1, p2, b0, b1, b2):
    """Central difference ``a - b`` where both neighbours are usable, one-sided ``a - p`` or ``p - b``
    where one is, else 0 (the tangent estimate of :func:`_row_normals`)."""
    if okf and okb:
        return a0 - b0, a1 - b1, a2 - b2
    if okf:
        return a0 - p0, a1 - p1, a2 - p2
    if okb:
        return p0 - b0, p1 - b1, p2 - b2
    return 0.0, 0.0, 0.0


@nb.njit(cache=True, inline="always")
def _row_normals(pts, rng, okr, v, H, max_jump, R, nw):
    """World-frame unit normals ``nw`` (3, W) of row ``v`` as the tests' ``erp_normals`` (central differences,
    one-sided at invalid neighbours and depth jumps over ``max_jump`` relative range; 0 where undefined;
    facing the camera; cast to float32 before the rotation ``R``), from the rolling row buffers of
    :func:`_row_points` (slot ``row % 3``); branch-free along the row."""
    W = nw.shape[1]
    c, dn, up = v % 3, (v + 1) % 3, (v + 2) % 3  # (v + 2) % 3 = (v - 1) % 3
    has_dn = v + 1 < H
    has_up = v >= 1
    Pc, Pd, Pu = pts[c], pts[dn], pts[up]
    rc_, rd_, ru_ = rng[c], rng[dn], rng[up]
    oc_, od_, ou_ = okr[c], okr[dn], okr[up]
    for u in range(W):
        j = u + 1
        p0, p1, p2 = Pc[0, j], Pc[1, j], Pc[2, j]
        r = rc_[j]
        thr = max_jump * max(r, 1e-9)
        okf = oc_[j + 1] and abs(rc_[j + 1] - r) <= thr
        okb = oc_[j - 1] and abs(rc_[j - 1] - r) <= thr
        du0, du1, du2 = _difference(okf, okb, Pc[0, j + 1], Pc[1, j + 1], Pc[2, j + 1], p0, p1, p2,
                                    Pc[0, j - 1], Pc[1, j - 1], Pc[2, j - 1])
        oku = okf or okb
        okf = has_dn and od_[j] and abs(rd_[j] - r) <= thr
        okb = has_up and ou_[j] and abs(ru_[j] - r) <= thr
        dv0, dv1, dv2 = _difference(okf, okb, Pd[0, j], Pd[1, j], Pd[2, j], p0, p1, p2, Pu[0, j], Pu[1, j], Pu[2, j])
        okv = okf or okb
        n0 = du1 * dv2 - du2 * dv1
        n1 = du2 * dv0 - du0 * dv2
        n2 = du0 * dv1 - du1 * dv0
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if oku and okv and nn > 1e-12:
            n0, n1, n2 = n0 / nn, n1 / nn, n2 / nn
        else:
            n0, n1, n2 = 0.0, 0.0, 0.0
        if n0 * p0 + n1 * p1 + n2 * p2 > 0:
            n0, n1, n2 = -n0, -n1, -n2
        f0, f1, f2 = np.float64(np.float32(n0)), np.float64(np.float32(n1)), np.float64(np.float32(n2))
        for k in range(3):
            nw[k, u] = f0 * R[k, 0] + f1 * R[k, 1] + f2 * R[k, 2]


@nb.njit(cache=True, parallel=True)
def _chunk_sums(depth, rays, classes, q, C, rgb, werp, range_scale, R, max_jump, nch, lid, ckeys, nvox,
                area, feats):
    """Pass 2, over the same row chunks in parallel: each chunk's per-voxel sums over its pixels in pixel
    order (float64): E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3) float64, count (n,) int64 and the
    keys (n,), chunk after chunk (``n = nvox.sum()``; a voxel seen by several chunks has a row in each).

    Per pixel, the same expressions as the numpy reference: the observation's confidence ``conf`` and the
    shares of its classes ``classes`` from its levels ``q`` (:func:`_pixel_measurement`), ``eta = float32(conf w_erp
    w_range) * area`` (``area`` = stride^2, exactly 1 at stride 1), the ``erp_normals`` normal (float64,
    cast to float32) rotated to the world frame. ``C``: the vocabulary size (E's width). ``feats`` (h, w, D)
    int8: the observation's quantised features (D = 0: none), summed as ``Z += eta * feats`` (n, D).
    """
    H, W = depth.shape
    rows = (H + nch - 1) // nch
    off = np.zeros(nch + 1, np.int64)
    for c in range(nch):
        off[c + 1] = off[c] + nvox[c]
    tot = off[nch]
    E = np.zeros((tot, C), np.float64)
    S = np.zeros(tot, np.float64)
    col = np.zeros((tot, 3), np.float64)
    nrm = np.zeros((tot, 3), np.float64)
    cnt = np.zeros(tot, np.int64)
    D = feats.shape[2]
    Z = np.zeros((tot, D), np.float64)
    keys = np.empty(tot, np.int64)
    for c in nb.prange(nch):
        v0 = min(H, c * rows)
        v1 = min(H, v0 + rows)
        o = off[c]
        for i in range(nvox[c]):
            keys[o + i] = ckeys[v0 * W + i]
        pts = np.zeros((3, 3, W + 2), np.float64)  # rows v - 1, v, v + 1 (slot row % 3): points, padded
        rng = np.zeros((3, W + 2), np.float64)  # ... their ranges
        okr = np.zeros((3, W + 2), np.bool_)  # ... finite depth > 0
        nw = np.empty((3, W), np.float64)
        if v0 >= 1:
            _row_points(depth, rays, v0 - 1, pts[(v0 - 1) % 3], rng[(v0 - 1) % 3], okr[(v0 - 1) % 3])
        if v0 < H:
            _row_points(depth, rays, v0, pts[v0 % 3], rng[v0 % 3], okr[v0 % 3])
        for v in range(v0, v1):
            if v + 1 < H:
                _row_points(depth, rays, v + 1, pts[(v + 1) % 3], rng[(v + 1) % 3], okr[(v + 1) % 3])
            _row_normals(pts, rng, okr, v, H, max_jump, R, nw)
            for u in range(W):
                li = lid[v * W + u]
                if li < 0:
                    continue
                d = depth[v, u]
                wr = 1.0 / (1.0 + (d / range_scale) ** 2)
                conf, s0, s1 = _pixel_measurement(q[v, u, 0], q[v, u, 1])
                et = np.float64(np.float32(np.float64(conf) * werp[v] * wr)) * area
                if not et > 0:
                    continue
                i = o + li
                E[i, classes[v, u, 0]] += et * np.float64(s0)
                E[i, classes[v, u, 1]] += et * np.float64(s1)
                S[i] += et
                for k in range(3):
                    col[i, k] += np.float64(rgb[v, u, k])
                cnt[i] += 1
                for k in range(3):
                    nrm[i, k] += nw[k, u]
                for k in range(D):
                    Z[i, k] += et * np.float64(feats[v, u, k])
    return E, S, col, nrm, cnt, Z, keys


@nb.njit(cache=True)
def _merge_chunks(keys, order, E, S, col, nrm, cnt, Z):
    """Pass 3: the chunks' rows of the same voxel summed in chunk order (``order``: a stable argsort of
    ``keys``); returns sorted unique keys and their E, S, rgb_sum, normal_sum, count, Z."""
    m = keys.shape[0]
    C = E.shape[1]
    n = 0
    for j in range(m):
        if j == 0 or keys[order[j]] != keys[order[j - 1]]:
            n += 1
    uk = np.empty(n, np.int64)
    E2 = np.zeros((n, C), np.float64)
    S2 = np.zeros(n, np.float64)
    col2 = np.zeros((n, 3), np.float64)
    nrm2 = np.zeros((n, 3), np.float64)
    cnt2 = np.zeros(n, np.int64)
    D = Z.shape[1]
    Z2 = np.zeros((n, D), np.float64)
    g = -1
    for j in range(m):
        i = order[j]
        if j == 0 or keys[i] != keys[order[j - 1]]:
            g += 1
            uk[g] = keys[i]
        for k in range(C):
            E2[g, k] += E[i, k]
        S2[g] += S[i]
        for k in range(3):
            col2[g, k] += col[i, k]
            nrm2[g, k] += nrm[i, k]
        cnt2[g] += cnt[i]
        for k in range(D):
            Z2[g, k] += Z[i, k]
    return uk, E2, S2, col2, nrm2, cnt2, Z2
