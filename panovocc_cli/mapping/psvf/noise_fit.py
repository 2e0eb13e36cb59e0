"""The radial noise fit: each frame's depth noise sigma_r(r), measured on its own smooth surfaces.

On every ``FIT_SUB``-th strided sample of each image axis, the distance of the sample to the line
through its two neighbours (+-s pixels) estimates the radial noise (:func:`_raw_residuals`); per range
bin a low quantile of those residuals gives sigma_r^2 (:func:`radial_noise_fit`), made non-decreasing
in range and floored at ``SIGMA_FLOOR``. :func:`interp1` reads the resulting table at a range.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ...geometry.erp import cam_point

SIGMA_FLOOR = 3e-4  # metres; floor of a fitted radial noise (the millimetre depth PNG's quantisation)

FIT_BIN = 0.5  # metres; range bins of the radial noise fit

FIT_MIN_SAMPLES = 50  # a range bin needs this many smooth samples to be fitted

FIT_SUB = 2  # the fit uses every FIT_SUB-th strided sample of each image axis

FIT_QUANTILE = 0.25  # robust scale: this quantile of the normalised squared residuals ...

FIT_Q_EXP = -np.log(1.0 - FIT_QUANTILE)  # ... over the same quantile of chi^2_2 / 2 (an Exp(1))


@nb.njit(cache=True, inline="always")
def interp1(x, xp, fp):
    """``np.interp`` of one scalar (xp increasing), without an array allocation per call."""
    n = len(xp)
    if x <= xp[0]:
        return fp[0]
    if x >= xp[n - 1]:
        return fp[n - 1]
    j = 1
    while xp[j] < x:
        j += 1
    t = (x - xp[j - 1]) / (xp[j] - xp[j - 1])
    return fp[j - 1] + t * (fp[j] - fp[j - 1])


@nb.njit(cache=True, parallel=True)
def _raw_residuals(depth, stride, sub, min_range, max_range, sphi, cphi, sth, cth):
    """Per strided sample (every ``sub``-th of each axis) with valid neighbours (+-stride pixels) on both
    image axes: range r, the mean over the two axes of the squared distance to the line through the
    axis' two neighbours divided by 1.5, and |cos incidence| of the plane they span; -1 where a
    neighbour is missing."""
    H, W = depth.shape
    s0 = stride // 2
    nr = (H - s0 + stride * sub - 1) // (stride * sub)
    nc = (W - s0 + stride * sub - 1) // (stride * sub)
    rr = np.full((nr, nc), -1.0)
    res2 = np.full((nr, nc), -1.0)
    cinc = np.zeros((nr, nc))
    for a in nb.prange(nr):
        v = s0 + a * stride * sub
        p = np.empty(3)
        q = np.empty((2, 2, 3))
        for b in range(nc):
            u = s0 + b * stride * sub
            r = np.float64(depth[v, u])
            if not (r > 0 and r >= min_range and r <= max_range):
                continue
            rr[a, b] = r
            if v - stride < 0 or v + stride >= H:
                continue
            p[0], p[1], p[2] = cam_point(r, sphi[v], cphi[v], sth[u], cth[u])
            ok = True
            for dirn in range(2):
                for side in range(2):
                    d = -stride if side == 0 else stride
                    vq, uq = (v, (u + d) % W) if dirn == 0 else (v + d, u)
                    rq = np.float64(depth[vq, uq])
                    if not rq > 0:
                        ok = False
                    q[dirn, side, 0], q[dirn, side, 1], q[dirn, side, 2] = cam_point(rq, sphi[vq], cphi[vq], sth[uq],
                                                                                   cth[uq])
            if not ok:
                continue
            acc = 0.0
            for dirn in range(2):
                l0, l1, l2 = (q[dirn, 1, 0] - q[dirn, 0, 0], q[dirn, 1, 1] - q[dirn, 0, 1],
                              q[dirn, 1, 2] - q[dirn, 0, 2])
                e0, e1, e2 = p[0] - q[dirn, 0, 0], p[1] - q[dirn, 0, 1], p[2] - q[dirn, 0, 2]
                x0, x1, x2 = e1 * l2 - e2 * l1, e2 * l0 - e0 * l2, e0 * l1 - e1 * l0
                acc += (x0 * x0 + x1 * x1 + x2 * x2) / max(l0 * l0 + l1 * l1 + l2 * l2, 1e-18)
            res2[a, b] = acc / 3.0  # mean over the 2 axes, / 1.5
            a0, a1, a2 = q[0, 1, 0] - q[0, 0, 0], q[0, 1, 1] - q[0, 0, 1], q[0, 1, 2] - q[0, 0, 2]
            b0, b1, b2 = q[1, 1, 0] - q[1, 0, 0], q[1, 1, 1] - q[1, 0, 1], q[1, 1, 2] - q[1, 0, 2]
            n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
            nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            if nn > 0:
                cinc[a, b] = abs(n0 * p[0] + n1 * p[1] + n2 * p[2]) / (nn * r)
    return rr, res2, cinc


@nb.njit(cache=True)
def _binned_quantiles(r, res2, cinc, c_min, edges, q, min_count):
    """Per range bin [edges[i], edges[i + 1]) with at least ``min_count`` samples (res2 >= 0, cinc >=
    c_min): the bin centre, the q-quantile (lower) of ``res2 / cinc^2`` and the count."""
    nb_ = len(edges) - 1
    counts = np.zeros(nb_, np.int64)
    idx = np.full(len(r), -1, np.int64)
    for i in range(len(r)):
        if res2[i] >= 0 and cinc[i] >= c_min and edges[0] <= r[i] < edges[nb_]:
            k = min(int((r[i] - edges[0]) / (edges[1] - edges[0])), nb_ - 1)
            idx[i] = k
            counts[k] += 1
    start = np.zeros(nb_ + 1, np.int64)
    for k in range(nb_):
        start[k + 1] = start[k] + counts[k]
    vals = np.empty(start[nb_])
    fill = start[:-1].copy()
    for i in range(len(r)):
        k = idx[i]
        if k >= 0:
            vals[fill[k]] = res2[i] / (cinc[i] * cinc[i])
            fill[k] += 1
    m = 0
    for k in range(nb_):
        if counts[k] >= min_count:
            m += 1
    centres = np.empty(m)
    qs = np.empty(m)
    cn = np.empty(m, np.int64)
    j = 0
    for k in range(nb_):
        if counts[k] >= min_count:
            kth = int(q * (counts[k] - 1))  # the kth smallest: a selection, not a sort
            centres[j] = 0.5 * (edges[k] + edges[k + 1])
            qs[j] = np.partition(vals[start[k]:start[k + 1]], kth)[kth]
            cn[j] = counts[k]
            j += 1
    return centres, qs, cn


def _isotonic(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-decreasing fit of y (pool adjacent violators)."""
    vals, wts, lens = [], [], []
    for yi, wi in zip(y, w):
        vals.append(float(yi))
        wts.append(float(wi))
        lens.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            v2, w2, l2 = vals.pop(), wts.pop(), lens.pop()
            vals[-1] = (vals[-1] * wts[-1] + v2 * w2) / (wts[-1] + w2)
            wts[-1] += w2
            lens[-1] += l2
    return np.repeat(vals, lens)


def radial_noise_fit(r: np.ndarray, res2: np.ndarray, cinc: np.ndarray, min_range: float,
                     max_range: float, c_min: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Radial depth noise as a function of range, fitted to one frame's own depth.

    On a smooth surface a sample's distance to the line through its two neighbours is
    ``(e_0 - (e_- + e_+) / 2) cos i`` for radial errors ``e`` along nearly parallel rays, of variance
    ``1.5 sigma_r^2 cos^2 i`` (``res2`` arrives divided by 1.5 and averaged over the two image axes, so
    ``res2 / (sigma_r^2 cos^2 i)`` is chi^2_2 / 2, an Exp(1)). Per range bin of ``FIT_BIN`` metres with
    at least ``FIT_MIN_SAMPLES`` samples (|cos i| >= c_min), ``sigma_r^2`` is the ``FIT_QUANTILE``
    quantile of ``res2 / cos^2 i`` over the same quantile of Exp(1): a low quantile, because depth
    edges, creases and curvature only ever add residual. The bins' values are then made
    non-decreasing in range (weighted by their sample counts; sensor noise grows with range) and
    floored at ``SIGMA_FLOOR``.

    Parameters
    ----------
    r : (n,) float64 metres; res2 : (n,) float64 m^2, squared residual (< 0 = none); cinc : (n,) float64

    Returns
    -------
    ranges : (k,) float64 metres, bin centres; sigma : (k,) float64 metres (k >= 1; use ``np.interp``)
    """
    edges = np.arange(min_range, max_range + FIT_BIN, FIT_BIN)
    centres, var, counts = _binned_quantiles(np.ascontiguousarray(r, np.float64), np.ascontiguousarray(res2, np.float64),
                                             np.ascontiguousarray(cinc, np.float64), float(c_min), edges,
                                             FIT_QUANTILE, FIT_MIN_SAMPLES)
    centres, var, counts = list(centres), list(var / FIT_Q_EXP), list(counts)
    if not centres:
        return np.zeros(1), np.full(1, SIGMA_FLOOR)
    sig = np.maximum(np.sqrt(_isotonic(np.array(var), np.array(counts))), SIGMA_FLOOR)
    return np.array(centres), sig

