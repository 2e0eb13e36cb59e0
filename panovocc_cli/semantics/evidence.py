"""Per-frame semantic evidence (paper Eq. memory_semantic_delta), as pure numpy functions.

Each valid pixel p of frame t is one semantic measurement with class probabilities
``p_t(p) = softmax(logits)`` and weight ``eta = c * w_erp(phi) * w_range(r)`` (``c``: its maximum class
probability). A voxel's per-frame delta sums, over the pixels whose surface point falls in it,
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
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import PanovoccError


@dataclass(frozen=True)
class EvidenceWeights:
    """Parameters of eta = c * w_erp(phi) * w_range(r) (see the module docstring)."""

    erp_power: float = 1.0
    erp_floor: float = 0.05
    range_scale: float = 4.0  # metres


def softmax(logits: np.ndarray, axis: int = -1) -> np.ndarray:
    """Numerically stable softmax.

    Parameters
    ----------
    logits : (..., C) float

    Returns
    -------
    probs : (..., C) float32, non-negative, summing to 1 along ``axis``
    """
    x = np.asarray(logits, dtype=np.float32)
    e = np.exp(x - x.max(axis=axis, keepdims=True))
    return e / e.sum(axis=axis, keepdims=True)


def w_erp(phi, power: float = 1.0, floor: float = 0.05) -> np.ndarray:
    """Latitude weight ``clip(cos(phi) ** power, floor, 1)``; ``phi`` radians, 0 at the equator."""
    return np.clip(np.cos(np.asarray(phi, dtype=np.float64)) ** power, floor, 1.0)


def w_range(r, scale: float = 4.0) -> np.ndarray:
    """Range weight ``1 / (1 + (r / scale) ** 2)``; ``r`` metres (0 where ``r <= 0``)."""
    r = np.asarray(r, dtype=np.float64)
    return np.where(r > 0, 1.0 / (1.0 + (r / scale) ** 2), 0.0)


def measurement_weights(probs: np.ndarray, phi, r, weights: EvidenceWeights = EvidenceWeights()) -> np.ndarray:
    """Weight eta of each measurement.

    Parameters
    ----------
    probs : (..., C) float, class probabilities
    phi : (...) float, latitude in radians (broadcast against ``probs[..., 0]``, e.g. ``(H, 1)``)
    r : (...) float, range in metres (radial depth), 0 = invalid

    Returns
    -------
    eta : (...) float32 in [0, 1]
    """
    c = np.asarray(probs).max(axis=-1)
    eta = c * w_erp(phi, weights.erp_power, weights.erp_floor) * w_range(r, weights.range_scale)
    return eta.astype(np.float32)


def frame_semantic_delta(depth: np.ndarray, rgb: np.ndarray, logits: np.ndarray, T_world_cam: np.ndarray,
                         voxel_size: float, weights: EvidenceWeights = EvidenceWeights(),
                         rays: np.ndarray | None = None):
    """The whole per-frame semantic step for one ERP frame: back-project, weigh, accumulate (compiled).

    The same maths as :func:`erp_normals`, :func:`softmax`, :func:`measurement_weights` and
    :func:`semantic_frame_delta` chained, in two numba kernels: a per-pixel pass over rows in parallel
    (point, normal, class probabilities, weight, voxel key) and an accumulation in pixel order through
    a hash table (the same float64 summation order as ``np.bincount``). The float32 ``exp`` of the
    softmax is the C library's, not numpy's SIMD one (they differ by 1 ulp on ~40 % of inputs), so
    the float sums can differ from the numpy chain in the last bits; after quantisation
    (2^-16) the two agree to within one unit (tests/semantics/test_semantics_evidence.py).

    Parameters
    ----------
    depth : (H, W) float, metres, radial, 0 = invalid
    rgb : (H, W, 3) uint8
    logits : (H, W, C) float, segmenter output over the vocabulary
    T_world_cam : (4, 4) float64, camera-to-world pose
    voxel_size : float, metres
    weights : EvidenceWeights
    rays : (H, W, 3) float, optional precomputed :func:`geometry.erp.ray_directions`

    Returns
    -------
    keys, channels : as :func:`semantic_frame_delta`
    """
    from ..geometry.erp import latitudes, ray_directions
    from ..geometry.lattice import KEY_RANGE

    depth = np.ascontiguousarray(depth, dtype=np.float64)
    if depth.ndim != 2:
        raise PanovoccError(f"depth must be (H, W), got shape {depth.shape}")
    h, w = depth.shape
    if np.shape(rgb)[:2] != (h, w) or np.shape(logits)[:2] != (h, w) or np.ndim(logits) != 3:
        raise PanovoccError(f"depth {depth.shape}, rgb {np.shape(rgb)[:2]} and logits {np.shape(logits)[:2]} "
                            "must have the same size")
    if voxel_size <= 0:
        raise PanovoccError(f"voxel size must be positive, got {voxel_size}")
    if rays is None:
        rays = ray_directions(w, h)
    rays = np.ascontiguousarray(rays, dtype=np.float64)
    logits = np.ascontiguousarray(logits, dtype=np.float32)
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    T = np.asarray(T_world_cam, np.float64)
    R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])
    werp = w_erp(latitudes(h), weights.erp_power, weights.erp_floor).astype(np.float64)
    keys = np.empty(h * w, np.int64)
    if _pixel_keys(depth, rays, werp, float(weights.range_scale), R, t, float(voxel_size), int(KEY_RANGE), keys):
        raise PanovoccError(f"voxel index out of the lattice's range (|index| < {KEY_RANGE})")
    uk, start, pix = _group_pixels(keys)
    E, S, rgb_sum, normal_sum, count = _voxel_sums(depth, rays, logits, rgb, werp, float(weights.range_scale), R,
                                                   0.1, start, pix)
    if (count == 0).any():  # voxels whose every pixel had eta = 0 (float32 underflow at absurd ranges)
        keep = count > 0
        uk, E, S, rgb_sum, normal_sum, count = uk[keep], E[keep], S[keep], rgb_sum[keep], normal_sum[keep], count[keep]
    return uk, {"E": E, "S": S, "rgb_sum": rgb_sum, "normal_sum": normal_sum, "count": count}


# ---------------------------------------------------------------------------------------------
# Compiled kernels of frame_semantic_delta

_NO_KEY = np.int64(-1)  # pixel that adds nothing (packed keys are >= 0)


@nb.njit(cache=True, inline="always")
def _pairwise_sum8(a, n):
    """float32 sum of ``a[:n]`` in numpy's pairwise order for n <= 128 (so the softmax matches numpy's)."""
    if n < 8:
        r = np.float32(0.0)
        for j in range(n):
            r += a[j]
        return r
    r0, r1, r2, r3, r4, r5, r6, r7 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7]
    k = 8
    while k < n - (n % 8):
        r0 += a[k]
        r1 += a[k + 1]
        r2 += a[k + 2]
        r3 += a[k + 3]
        r4 += a[k + 4]
        r5 += a[k + 5]
        r6 += a[k + 6]
        r7 += a[k + 7]
        k += 8
    r = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while k < n:
        r += a[k]
        k += 1
    return r


@nb.njit(cache=True, inline="always")
def _neighbour_ok(depth, rays, v, u, r, max_jump):
    """Point of pixel (v, u) and whether it is valid and within ``max_jump`` relative range of ``r``."""
    d = depth[v, u]
    q0, q1, q2 = rays[v, u, 0] * d, rays[v, u, 1] * d, rays[v, u, 2] * d
    ok = np.isfinite(d) and d > 0
    if ok:
        rq = np.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        ok = abs(rq - r) <= max_jump * max(r, 1e-9)
    return q0, q1, q2, ok


@nb.njit(cache=True, parallel=True)
def _pixel_keys(depth, rays, werp, range_scale, R, t, h, key_range, keys):
    """Voxel key of every pixel with a measurement (rows in parallel), -1 elsewhere; True if an index
    falls outside the lattice's key range.

    A pixel is a measurement where its depth is finite and > 0 and ``w_erp * w_range > 0`` (then eta > 0,
    the class confidence being at least 1/C); world point ``R p + t`` as ``p @ R.T + t``.
    """
    H, W = depth.shape
    bad = np.zeros(H, np.bool_)
    off = key_range
    mask = 2 * key_range - 1
    for v in nb.prange(H):
        for u in range(W):
            d = depth[v, u]
            if not (np.isfinite(d) and d > 0 and werp[v] * (1.0 / (1.0 + (d / range_scale) ** 2)) > 0):
                keys[v * W + u] = _NO_KEY
                continue
            p0, p1, p2 = rays[v, u, 0] * d, rays[v, u, 1] * d, rays[v, u, 2] * d
            key = np.int64(0)
            for i in range(3):
                x = p0 * R[i, 0] + p1 * R[i, 1] + p2 * R[i, 2] + t[i]
                idx = np.int64(np.floor(x / h))
                if abs(idx) >= key_range:
                    bad[v] = True
                key = (key << 21) | ((idx + off) & mask)
            keys[v * W + u] = key
    return bad.any()


@nb.njit(cache=True, inline="always")
def _slot(key, bits):
    """Fibonacci hash of a voxel key onto ``bits`` bits (the product's high bits: all key bits mix in)."""
    return np.int64((np.uint64(key) * np.uint64(11400714819323198485)) >> np.uint64(64 - bits))


@nb.njit(cache=True)
def _group_pixels(keys):
    """Group pixels by voxel: sorted unique keys (n,), CSR ``start`` (n + 1,) and ``pix`` (m,) int64, the
    pixels of voxel i being ``pix[start[i]:start[i + 1]]`` in increasing (pixel) order."""
    M = keys.shape[0]
    bits = 14
    cap = 1 << bits
    table = np.full(cap, -1, np.int64)  # slot -> row (rows in order of first appearance)
    rkey = np.empty(cap // 2, np.int64)
    row = np.empty(M, np.int64)
    n = 0
    last_key = np.int64(-2)
    last_row = -1
    for p in range(M):
        k = keys[p]
        if k < 0:
            row[p] = -1
            continue
        if k != last_key:
            slot = _slot(k, bits)
            while True:
                r = table[slot]
                if r < 0 or rkey[r] == k:
                    break
                slot = (slot + 1) & (cap - 1)
            if r < 0:
                if 2 * (n + 1) > cap:  # grow: double the table, rehash
                    cap *= 2
                    bits += 1
                    table = np.full(cap, -1, np.int64)
                    rkey = np.concatenate((rkey[:n], np.empty(cap // 2 - n, np.int64)))
                    for r2 in range(n):
                        s2 = _slot(rkey[r2], bits)
                        while table[s2] >= 0:
                            s2 = (s2 + 1) & (cap - 1)
                        table[s2] = r2
                    slot = _slot(k, bits)
                    while table[slot] >= 0:
                        slot = (slot + 1) & (cap - 1)
                r = n
                table[slot] = r
                rkey[r] = k
                n += 1
            last_key = k
            last_row = r
        row[p] = last_row
    order = np.argsort(rkey[:n])
    rank = np.empty(n, np.int64)
    for i in range(n):
        rank[order[i]] = i
    start = np.zeros(n + 1, np.int64)
    for p in range(M):
        if row[p] >= 0:
            start[rank[row[p]] + 1] += 1
    for i in range(n):
        start[i + 1] += start[i]
    fill = start[:n].copy()
    pix = np.empty(start[n], np.int64)
    for p in range(M):
        if row[p] >= 0:
            i = rank[row[p]]
            pix[fill[i]] = p
            fill[i] += 1
    return rkey[:n][order], start, pix


@nb.njit(cache=True, parallel=True)
def _voxel_sums(depth, rays, logits, rgb, werp, range_scale, R, max_jump, start, pix):
    """Per-voxel sums (voxels in parallel, each over its pixels in pixel order, in float64 as
    ``np.bincount``): E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3) float64, count (n,) int64.

    Per pixel, the same expressions in the same order as the numpy chain: ``softmax`` (float32, numpy's
    pairwise sum), ``eta = float32(c w_erp w_range)``, the ``erp_normals`` normal (float64, cast to
    float32) rotated to the world frame.
    """
    H, W = depth.shape
    C = logits.shape[2]
    n = start.shape[0] - 1
    E = np.zeros((n, C), np.float64)
    S = np.zeros(n, np.float64)
    col = np.zeros((n, 3), np.float64)
    nrm = np.zeros((n, 3), np.float64)
    cnt = np.zeros(n, np.int64)
    for i in nb.prange(n):
        e = np.empty(C, np.float32)
        for q in range(start[i], start[i + 1]):
            p = pix[q]
            v = p // W
            u = p - v * W
            d = depth[v, u]
            m = logits[v, u, 0]
            for k in range(1, C):
                m = max(m, logits[v, u, k])
            for k in range(C):
                e[k] = np.exp(logits[v, u, k] - m)
            s = _pairwise_sum8(e, C)
            cmax = np.float32(0.0)
            for k in range(C):
                e[k] = e[k] / s
                cmax = max(cmax, e[k])
            wr = 1.0 / (1.0 + (d / range_scale) ** 2)
            et = np.float64(np.float32(np.float64(cmax) * werp[v] * wr))
            if not et > 0:
                continue
            for k in range(C):
                E[i, k] += et * np.float64(e[k])
            S[i] += et
            for k in range(3):
                col[i, k] += np.float64(rgb[v, u, k])
            cnt[i] += 1
            # normal: central differences, one-sided at invalid neighbours and depth jumps (erp_normals)
            p0, p1, p2 = rays[v, u, 0] * d, rays[v, u, 1] * d, rays[v, u, 2] * d
            r = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
            a0, a1, a2, okf = _neighbour_ok(depth, rays, v, (u + 1) % W, r, max_jump)
            b0, b1, b2, okb = _neighbour_ok(depth, rays, v, (u - 1) % W, r, max_jump)
            if okf and okb:
                du0, du1, du2 = a0 - b0, a1 - b1, a2 - b2
            elif okf:
                du0, du1, du2 = a0 - p0, a1 - p1, a2 - p2
            elif okb:
                du0, du1, du2 = p0 - b0, p1 - b1, p2 - b2
            else:
                du0, du1, du2 = 0.0, 0.0, 0.0
            oku = okf or okb
            okf = False
            okb = False
            a0 = a1 = a2 = b0 = b1 = b2 = 0.0
            if v + 1 < H:
                a0, a1, a2, okf = _neighbour_ok(depth, rays, v + 1, u, r, max_jump)
            if v >= 1:
                b0, b1, b2, okb = _neighbour_ok(depth, rays, v - 1, u, r, max_jump)
            if okf and okb:
                dv0, dv1, dv2 = a0 - b0, a1 - b1, a2 - b2
            elif okf:
                dv0, dv1, dv2 = a0 - p0, a1 - p1, a2 - p2
            elif okb:
                dv0, dv1, dv2 = p0 - b0, p1 - b1, p2 - b2
            else:
                dv0, dv1, dv2 = 0.0, 0.0, 0.0
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
                nrm[i, k] += f0 * R[k, 0] + f1 * R[k, 1] + f2 * R[k, 2]
    return E, S, col, nrm, cnt
