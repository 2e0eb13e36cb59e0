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

import numpy as np

from ..errors import PanovoccError
from ..geometry.lattice import pack_keys, point_to_index


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


def erp_normals(points_cam: np.ndarray, valid: np.ndarray, max_jump: float = 0.1) -> np.ndarray:
    """Unit surface normals of an ERP point map from neighbouring pixels.

    Central differences along longitude (wrapping around) and latitude, falling back to one-sided
    differences where a neighbour is invalid or across a depth jump (range differing by more than
    ``max_jump`` times the pixel's range, i.e. an occlusion edge); the normal ``d_u x d_v`` is flipped
    to face the camera (``n . p < 0``).

    Parameters
    ----------
    points_cam : (H, W, 3) float, camera-frame points (metres)
    valid : (H, W) bool, pixels with a depth measurement
    max_jump : float, relative range difference that breaks the surface

    Returns
    -------
    normals : (H, W, 3) float32, camera frame, unit length; zero where undefined (invalid pixel, or
        no valid neighbour along one of the two directions)
    """
    p = np.asarray(points_cam, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if p.ndim != 3 or p.shape[2] != 3 or valid.shape != p.shape[:2]:
        raise PanovoccError(f"points_cam must be (H, W, 3) and valid (H, W), got {p.shape} and {valid.shape}")
    r = np.linalg.norm(p, axis=-1)

    def neighbour(axis: int, step: int):
        if axis == 1:
            q, rv, vv = np.roll(p, -step, axis=1), np.roll(r, -step, axis=1), np.roll(valid, -step, axis=1)
        else:
            q, rv, vv = np.zeros_like(p), np.zeros_like(r), np.zeros_like(valid)
            if step > 0:
                q[:-step], rv[:-step], vv[:-step] = p[step:], r[step:], valid[step:]
            else:
                q[-step:], rv[-step:], vv[-step:] = p[:step], r[:step], valid[:step]
        ok = vv & valid & (np.abs(rv - r) <= max_jump * np.maximum(r, 1e-9))
        return q, ok

    def derivative(axis: int):
        qf, okf = neighbour(axis, 1)
        qb, okb = neighbour(axis, -1)
        d = np.where((okf & okb)[..., None], qf - qb, np.where(okf[..., None], qf - p, p - qb))
        return d, okf | okb

    du, oku = derivative(1)
    dv, okv = derivative(0)
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    good = oku & okv & (norm > 1e-12)
    n = np.where(good[..., None], n / np.where(good, norm, 1.0)[..., None], 0.0)
    flip = np.einsum("hwc,hwc->hw", n, p) > 0
    n[flip] *= -1.0
    return n.astype(np.float32)


def semantic_frame_delta(points_world: np.ndarray, probs: np.ndarray, eta: np.ndarray, rgb: np.ndarray,
                         normals_world: np.ndarray, voxel_size: float):
    """Sparse per-voxel semantic delta of one frame (sum over its measurements).

    Parameters
    ----------
    points_world : (M, 3) float, surface points of valid pixels, world frame, metres
    probs : (M, C) float, class probabilities
    eta : (M,) float >= 0, measurement weights
    rgb : (M, 3) uint8, pixel colours
    normals_world : (M, 3) float, unit normals in the world frame (zero = undefined)
    voxel_size : float, metres (global lattice)

    Returns
    -------
    keys : (n,) int64, sorted unique voxel keys (:func:`lattice.pack_keys` of :func:`lattice.point_to_index`)
    channels : dict of str -> array, one row per key:
        ``E`` (n, C) float64 sum of eta * p; ``S`` (n,) float64 sum of eta;
        ``rgb_sum`` (n, 3) float64 plain sum of colours (0..255); ``normal_sum`` (n, 3) float64 plain sum
        of unit normals; ``count`` (n,) int64 number of measurements
    """
    pts = np.asarray(points_world, dtype=np.float64)
    m = pts.shape[0]
    probs = np.asarray(probs)
    eta = np.asarray(eta, dtype=np.float64)
    rgb = np.asarray(rgb)
    nrm = np.asarray(normals_world, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or probs.ndim != 2 or probs.shape[0] != m or eta.shape != (m,) \
            or rgb.shape != (m, 3) or nrm.shape != (m, 3):
        raise PanovoccError(f"semantic delta inputs disagree: points {pts.shape}, probs {probs.shape}, eta "
                            f"{eta.shape}, rgb {rgb.shape}, normals {nrm.shape} (expected M rows each)")
    if voxel_size <= 0:
        raise PanovoccError(f"voxel size must be positive, got {voxel_size}")
    c = probs.shape[1]
    keys_all = pack_keys(point_to_index(pts, voxel_size))
    keys, inv = np.unique(keys_all, return_inverse=True)
    inv = inv.reshape(-1)
    n = keys.size
    idx = (inv[:, None] * c + np.arange(c)[None, :]).ravel()
    E = np.bincount(idx, weights=(eta[:, None] * probs.astype(np.float64)).ravel(), minlength=n * c).reshape(n, c)
    S = np.bincount(inv, weights=eta, minlength=n)
    rgb_sum = np.stack([np.bincount(inv, weights=rgb[:, k].astype(np.float64), minlength=n) for k in range(3)], 1)
    normal_sum = np.stack([np.bincount(inv, weights=nrm[:, k], minlength=n) for k in range(3)], 1)
    count = np.bincount(inv, minlength=n).astype(np.int64)
    return keys, {"E": E, "S": S, "rgb_sum": rgb_sum, "normal_sum": normal_sum, "count": count}


def frame_semantic_delta(depth: np.ndarray, rgb: np.ndarray, logits: np.ndarray, T_world_cam: np.ndarray,
                         voxel_size: float, weights: EvidenceWeights = EvidenceWeights(),
                         rays: np.ndarray | None = None):
    """The whole per-frame semantic step for one ERP frame: back-project, weigh, accumulate.

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

    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    if np.shape(rgb)[:2] != (h, w) or np.shape(logits)[:2] != (h, w):
        raise PanovoccError(f"depth {depth.shape}, rgb {np.shape(rgb)[:2]} and logits {np.shape(logits)[:2]} "
                            "must have the same size")
    if rays is None:
        rays = ray_directions(w, h)
    pts_cam = rays * depth[..., None]
    valid = np.isfinite(depth) & (depth > 0)
    normals = erp_normals(pts_cam, valid)
    probs = softmax(logits)
    eta = measurement_weights(probs, latitudes(h)[:, None], depth, weights)
    R, t = np.asarray(T_world_cam[:3, :3], np.float64), np.asarray(T_world_cam[:3, 3], np.float64)
    sel = valid & (eta > 0)
    pw = pts_cam[sel] @ R.T + t
    nw = normals[sel].astype(np.float64) @ R.T
    return semantic_frame_delta(pw, probs[sel], eta[sel], np.asarray(rgb)[sel], nw, voxel_size)
