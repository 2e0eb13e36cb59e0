"""The numpy reference of the per-frame semantic evidence (tests only).

:func:`softmax` and :func:`measurement_weights` (with :func:`w_range`) are the per-pixel probabilities and
weights; :func:`frame_semantic_delta_numpy` is the plain-numpy chain ``erp_normals`` -> ``softmax`` ->
``measurement_weights`` -> ``semantic_frame_delta`` that ``panovocc map`` ran before the step was
compiled (``panovocc_cli.semantics.evidence.frame_semantic_delta``); :func:`simulate_logits_numpy` is
the simulated segmenter in plain numpy (its fields, ellipses and boundary erosion as before they were
compiled, with the seeded confidence model); :func:`affinity_numpy` and :func:`transition_scipy` are GSC's
edge affinity and transition matrix as numpy and scipy made them before they were compiled
(``panovocc_cli.semantics.gsc``). The tests compare each pair.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.erp import latitudes, ray_directions
from panovocc_cli.geometry.lattice import pack_keys, point_to_index
from panovocc_cli.semantics.evidence import EvidenceWeights, w_erp
from panovocc_cli.semantics.simulated import (CONFIDENCE_MODELS, SimulatedConfig, _blob_partners, clean_logit_table,
                                              expected_labels, similarity_matrix)


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


def frame_semantic_delta_numpy(depth: np.ndarray, rgb: np.ndarray, obs, T_world_cam: np.ndarray,
                               voxel_size: float, weights: EvidenceWeights = EvidenceWeights(),
                               rays: np.ndarray | None = None):
    """The whole per-frame semantic step for one ERP frame: back-project, weigh, accumulate (numpy).

    Parameters
    ----------
    depth : (H, W) float, metres, radial, 0 = invalid
    rgb : (H, W, 3) uint8
    obs : SemanticObservation at the semantic stride (ceil(H/s), ceil(W/s))
    T_world_cam : (4, 4) float64, camera-to-world pose
    voxel_size : float, metres
    weights : EvidenceWeights
    rays : (H, W, 3) float, optional precomputed :func:`geometry.erp.ray_directions`

    Returns
    -------
    keys, channels : as :func:`semantic_frame_delta`
    """
    depth = np.asarray(depth, dtype=np.float64)
    h, w = depth.shape
    s = weights.stride  # measurements: pixels (s i, s j), each weighing s^2
    if np.shape(rgb)[:2] != (h, w) or tuple(obs.shape) != (-(-h // s), -(-w // s)):
        raise PanovoccError(f"depth {depth.shape}, rgb {np.shape(rgb)[:2]} and observation {obs.shape} disagree")
    if rays is None:
        rays = ray_directions(w, h)
    phi = latitudes(h)[::s]
    depth, rgb, rays = depth[::s, ::s], np.asarray(rgb)[::s, ::s], np.asarray(rays)[::s, ::s]
    pts_cam = rays * depth[..., None]
    valid = np.isfinite(depth) & (depth > 0)
    normals = erp_normals(pts_cam, valid)
    conf, share = measurement(obs)
    probs = np.zeros(obs.shape + (obs.n_classes,), np.float32)
    for k in (1, 0):  # (one class: both columns name class 0, the second with share 0)
        np.put_along_axis(probs, obs.classes[..., k:k + 1].astype(np.int64), share[..., k:k + 1], axis=2)
    eta = (conf.astype(np.float64) * w_erp(phi[:, None], weights.erp_power, weights.erp_floor)
           * w_range(depth, weights.range_scale)).astype(np.float32).astype(np.float64) * (s * s)
    R, t = np.asarray(T_world_cam[:3, :3], np.float64), np.asarray(T_world_cam[:3, 3], np.float64)
    sel = valid & (eta > 0)
    pw = pts_cam[sel] @ R.T + t
    nw = normals[sel].astype(np.float64) @ R.T
    return semantic_frame_delta(pw, probs[sel], eta[sel], np.asarray(rgb)[sel], nw, voxel_size)


def smooth_fields(rng: np.random.Generator, height: int, width: int, n: int, cells: int) -> np.ndarray:
    """``n`` unit-variance smooth random fields on the ERP image, periodic in longitude.

    Gaussian interpolation (std 0.6 cells) of iid normal values on a ``cells x 2 cells`` grid.

    Returns
    -------
    fields : (H, W, n) float32
    """
    gh, gw = max(1, int(cells)), max(2, 2 * int(cells))
    z = rng.standard_normal((n, gh, gw)).astype(np.float32)
    y = (np.arange(height) + 0.5) / height * gh
    x = (np.arange(width) + 0.5) / width * gw
    dv = y[:, None] - (np.arange(gh) + 0.5)[None, :]
    du = x[:, None] - (np.arange(gw) + 0.5)[None, :]
    du = (du + gw / 2.0) % gw - gw / 2.0
    av = np.exp(-0.5 * (dv / 0.6) ** 2)
    au = np.exp(-0.5 * (du / 0.6) ** 2)
    av /= np.sqrt((av ** 2).sum(axis=1, keepdims=True))
    au /= np.sqrt((au ** 2).sum(axis=1, keepdims=True))
    av, au = av.astype(np.float32), au.astype(np.float32)
    f = np.einsum("hi,nij->nhj", av, z)
    f = np.einsum("nhj,wj->hwn", f, au)
    return np.ascontiguousarray(f, dtype=np.float32)


def boundary_neighbours(labels: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Nearest different label within ``radius`` pixels along rows/columns (longitude wraps).

    Returns
    -------
    neighbour : (H, W) int64, the other region's id, or -1 where no boundary is within ``radius``
    dist : (H, W) int64, its distance in pixels (0 where none)
    """
    h, w = labels.shape
    nb = np.full((h, w), -1, dtype=np.int64)
    dist = np.zeros((h, w), dtype=np.int64)
    for d in range(1, radius + 1):
        for axis, step in ((1, d), (1, -d), (0, d), (0, -d)):
            if axis == 1:
                shifted = np.roll(labels, step, axis=1)
            else:
                shifted = np.empty_like(labels)
                if step > 0:
                    shifted[step:] = labels[:-step]
                    shifted[:step] = labels[:1]
                else:
                    shifted[:step] = labels[-step:]
                    shifted[step:] = labels[-1:]
            hit = (nb < 0) & (shifted != labels)
            nb[hit] = shifted[hit]
            dist[hit] = d
    return nb, dist


def simulate_logits_numpy(labels: np.ndarray, class_names: Sequence[str], vocab: Sequence[str], frame_index: int,
                    cfg: SimulatedConfig = SimulatedConfig()) -> np.ndarray:
    """Simulated segmenter output for one frame.

    Parameters
    ----------
    labels : (H, W) int, ground-truth ids into ``class_names`` (0 = unlabeled), ERP
    class_names : sequence of str, K names (entry 0 ``unlabeled``)
    vocab : sequence of str, C canonical names
    frame_index : int, selects the frame's noise (``default_rng([seed, frame_index])``)
    cfg : SimulatedConfig

    Returns
    -------
    logits : (H, W, C) float32
    """
    labels = np.asarray(labels, dtype=np.int64)
    if labels.ndim != 2:
        raise PanovoccError(f"ground-truth labels must be (H, W), got shape {labels.shape}")
    h, w = labels.shape
    k, c = len(class_names), len(vocab)
    if c == 0:
        raise PanovoccError("empty vocabulary")
    if labels.size and (labels.min() < 0 or labels.max() >= k):
        raise PanovoccError(f"label ids must lie in 0..{k - 1} (class_names has {k} entries)")
    table = clean_logit_table(class_names, vocab, cfg)
    logits = table[labels]  # (H, W, C)
    if cfg.noise <= 0:
        return np.ascontiguousarray(logits, dtype=np.float32)

    rng = np.random.default_rng([int(cfg.seed), int(frame_index)])
    sim = similarity_matrix(class_names, vocab)
    top = expected_labels(class_names, vocab)
    phi = latitudes(h)
    lat = (cfg.noise * (1.0 + cfg.pole_gain * np.abs(np.sin(phi)) ** cfg.pole_power)).astype(np.float32)

    # Smooth per-class fields, amplitude growing with relatedness to the ground-truth class.
    fields = smooth_fields(rng, h, w, c + 1, cfg.field_cells)
    amp = cfg.field_sigma * (cfg.field_base + cfg.field_related * sim)  # (K, C)
    amp[0, :] = cfg.field_sigma * cfg.unlabeled_noise
    logits += amp.astype(np.float32)[labels] * fields[..., :c] * lat[:, None, None]

    # Wrong-class ellipses: each ground-truth class pushed toward one confusion partner.
    n_blobs = rng.poisson(cfg.blobs * min(cfg.noise, 3.0))
    vv, uu = np.arange(h)[:, None], np.arange(w)[None, :]
    for _ in range(n_blobs):
        v0 = rng.uniform(0, h)
        u0 = rng.uniform(0, w)
        ra = rng.uniform(*cfg.blob_size) * h
        rb = rng.uniform(*cfg.blob_size) * h
        phi0 = np.pi / 2 - v0 / h * np.pi
        rb_u = min(rb / max(np.cos(phi0), 0.25), w / 2.0)
        partner = _blob_partners(rng, sim, top)
        v_lo, v_hi = max(0, int(v0 - ra)), min(h, int(v0 + ra) + 1)
        if v_hi <= v_lo:
            continue
        du = (uu - u0 + w / 2.0) % w - w / 2.0
        dv = vv[v_lo:v_hi] - v0
        r2 = (dv / ra) ** 2 + (du / rb_u) ** 2
        inside = r2 < 1.0
        if not inside.any():
            continue
        rows, cols = np.nonzero(inside)
        weight = (1.0 - r2[rows, cols]) ** 0.5
        rows = rows + v_lo
        tgt = partner[labels[rows, cols]]
        ok = tgt >= 0
        logits[rows[ok], cols[ok], tgt[ok]] += (cfg.blob_logit * cfg.noise * lat[rows[ok]] / lat.max()
                                                * weight[ok]).astype(np.float32)

    # Eroded boundaries: near a label boundary, the neighbouring region's class bleeds in.
    radius_f = cfg.boundary_deg / 180.0 * h  # the band's width in pixels of this image
    radius = max(1, int(np.floor(radius_f + 0.5)))
    nb, dist = boundary_neighbours(labels, radius)
    rows, cols = np.nonzero(nb > 0)
    if rows.size:
        tgt = top[nb[rows, cols]]
        ok = tgt >= 0
        rows, cols, tgt = rows[ok], cols[ok], tgt[ok]
        decay = np.maximum(0.0, 1.0 - (dist[rows, cols] - 0.5) / radius_f)  # pixel centre's distance
        mod = np.exp(0.4 * fields[rows, cols, c])  # log-normal, median 1: erosion varies along the edge
        logits[rows, cols, tgt] += (cfg.boundary_logit * min(cfg.noise, 3.0) * decay * mod).astype(np.float32)

    # Confidence: the seeded frame temperature of the confidence model (drawn after every other draw).
    model = CONFIDENCE_MODELS[cfg.confidence]
    T = model.temperature * float(np.exp(model.jitter * rng.standard_normal()))
    if T != 1.0:
        logits *= np.float32(1.0 / T)
    return np.ascontiguousarray(logits, dtype=np.float32)


def affinity_numpy(i, j, axis, g, nh, col, params) -> np.ndarray:
    """GSC's edge affinity ``k_g k_n k_t k_c`` (float32 inputs: ``g`` (n,), unit normals ``nh`` (n, 3), colours
    ``col`` (n, 3) with NaN unknown), one numpy temporary per operation, as ``gsc._affinity`` was written before
    2026-12-06."""
    k_g = np.exp(-np.abs(g[i] - g[j]) / np.float32(params.s_g))
    ni, nj = nh[i], nh[j]
    dot = np.einsum("mk,mk->m", ni, nj)
    has_n = (np.abs(ni).sum(1) > 0) & (np.abs(nj).sum(1) > 0)
    k_n = np.where(has_n, np.maximum(dot, 0.0) ** np.float32(params.normal_power), 1.0)
    ai, aj = ni[np.arange(i.size), axis], nj[np.arange(j.size), axis]
    k_t = np.exp(-(ai * ai + aj * aj) / np.float32(2.0 * params.s_t))
    dc = col[i] - col[j]
    d2 = np.einsum("mk,mk->m", dc, dc)
    k_c = np.where(np.isfinite(d2), np.exp(-np.nan_to_num(d2) / np.float32(2.0 * params.s_c ** 2)), 1.0)
    return (k_g * k_n * k_t * k_c).astype(np.float32)


def transition_scipy(n: int, i, j, w):
    """GSC's row-normalised transition matrix as scipy built it before 2026-12-06: (indptr, indices, data) of its
    CSR matrix and ``csr.sum(axis=1)`` as float32."""
    import scipy.sparse as sp

    keep = w > 0
    it = np.int32 if n < 2 ** 31 else np.int64
    i, j, w = i[keep].astype(it), j[keep].astype(it), w[keep].astype(np.float32)
    rows, cols, vals = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([w, w])
    deg = np.bincount(rows, weights=vals, minlength=n).astype(np.float32)
    W = sp.csr_matrix(((vals / deg[rows]).astype(np.float32), (rows, cols)), shape=(n, n))
    return W.indptr, W.indices, W.data, np.asarray(W.sum(axis=1)).ravel().astype(np.float32)


def measurement(obs) -> tuple[np.ndarray, np.ndarray]:
    """What the evidence fuses, as frame arrays (the package makes it per pixel: ``evidence._pixel_measurement``):
    per pixel the confidence and the two classes' shares.

    Returns
    -------
    confidence : (h, w) float32, ``q1 / 15`` (0: the pixel carries no evidence)
    share : (h, w, 2) float32, ``(q1, q2) / (q1 + q2)`` (0 where ``q1 + q2 = 0``)
    """
    from panovocc_cli.semantics.observation import Q_LEVELS

    q = obs.q.astype(np.float32)
    tot = q[..., 0] + q[..., 1]
    share = np.where(tot[..., None] > 0, q / np.where(tot > 0, tot, 1)[..., None], 0).astype(np.float32)
    return (q[..., 0] / np.float32(Q_LEVELS)).astype(np.float32), share
