"""Per-frame contributors: pure functions from one frame (and its pose) to a sparse :class:`~.memory.Delta`.

The mapper runs the contributors on every frame and keeps their deltas as the parts of the one
:class:`~.memory.FrameDelta` it stores and adds to the memory. The geometry contributor,
:func:`geometry_delta` (A, N, F, O), is the PSVF per-frame update (:mod:`.psvf.update`);
:func:`geometry_parts` adds its surface-offset part (channel P, ``OFFSET_CHANNEL``). The semantic
contributor, :func:`semantic_delta`, starts from the frame's
:class:`~panovocc_cli.semantics.observation.SemanticObservation` (the segmenter's output, reduced once and
kept with the frame's delta, so a revision never runs the segmenter again):
:func:`panovocc_cli.semantics.evidence.frame_semantic_delta` turns it into per-voxel float sums, which
:func:`quantize_semantic_delta` turns into integer memory channels that travel through the SAME delta
mechanism as the geometry (the delta log, ``revise``, ``--resume``: the memory stays the exact integer sum
of the retained deltas).

Channels (``C`` = vocabulary size), all exact integers. Per voxel and frame, with ``S_f`` the sum of the
pixels' weights eta, ``D`` their eta-weighted mean class distribution, ``k`` the pixel count and
``n_f``, ``c_f`` the sums of their normals and colours:

==============  =====  ============================================================================
name            width  per-frame delta
==============  =====  ============================================================================
``S``           1      ``64 s`` with ``s = round(256 S_f)``: the frame's weight in 1/256 steps
``E``           C      ``s d`` with ``d`` = ``64 D`` rounded to integers summing to 64 (largest
                       remainders): ``sum_c E = S``, so ``E / S`` is the weighted mean distribution
``normal_sum``  3      ``k round(127 n_f / k)``: the mean normal in 1/127 steps, times the count
``rgb_sum``     3      ``k round(c_f / k)``: the mean colour in grey levels, times the count
``count``       1      ``k``, pixels (measurements)
``Z``           D      only with ``--features``: ``s z`` with ``z`` = the eta-weighted mean of the pixels'
                       quantised features (int8, :mod:`panovocc_cli.semantics.features`), rounded
==============  =====  ============================================================================

Each channel is a product of small per-voxel factors, which the delta log stores instead of the products
(``io.mapstore``, factored channels: about a third of the bytes of the plain sums). The rounding is a
deviation from the paper's float sums, documented in docs/semantics.md ("Semantic observation and
evidence"); a weight below 1/512 in a voxel adds no class evidence there (its colour, normal and count
still count).

Overflow: a frame adds at most ``64 * 256 * (pixels in the voxel) * s^2`` to ``S`` (a whole 2048x1024 frame in
one voxel: 2^35); the memory widens int32 to int64 as needed and refuses sums past int64.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..semantics.params import EvidenceWeights
from .memory import ChannelSpec, Delta
from .psvf.update import MAX_FRAME_VOXELS, frame_box, geometry_delta, geometry_parts, keep_freed_heap

__all__ = ["MAX_FRAME_VOXELS", "frame_box", "geometry_delta", "geometry_parts", "keep_freed_heap",
           "quantize_semantic_delta",
           "semantic_channels", "semantic_delta"]

S_STEPS = 256  # a frame's weight S_f in a voxel, in steps of 1 / S_STEPS
D_STEPS = 64  # its class distribution, in steps of 1 / D_STEPS (summing to D_STEPS)
NORMAL_STEPS = 127  # the mean normal's components, in steps of 1 / NORMAL_STEPS
S_SCALE = S_STEPS * D_STEPS  # stored S (and E) per unit of eta
DELTA_FACTORS = {"E": ("S", D_STEPS), "normal_sum": ("count", 1), "rgb_sum": ("count", 1), "Z": ("S", D_STEPS)}
"""How each semantic channel of a frame's delta factors (``channel = factor * m / denominator``, m an integer
array): what the delta log stores instead of the product (:func:`panovocc_cli.io.mapstore.encode_delta`)."""


def semantic_channels(n_classes: int, feature_dim: int = 0) -> tuple[ChannelSpec, ...]:
    """Memory channels of the semantic contributor for a vocabulary of ``n_classes`` words, and the feature
    channel ``Z`` when ``feature_dim`` > 0 (all exact integers: the module docstring)."""
    return (ChannelSpec("E", n_classes, "int"), ChannelSpec("S", 1, "int"), ChannelSpec("rgb_sum", 3, "int"),
            ChannelSpec("normal_sum", 3, "int"), ChannelSpec("count", 1, "int")) \
        + ((ChannelSpec("Z", int(feature_dim), "int"),) if feature_dim else ())


def distribution_steps(D: np.ndarray, steps: int = D_STEPS) -> np.ndarray:
    """Rows of a distribution ``D`` (n, C) float (non-negative, summing to ~1) in integer steps summing to
    exactly ``steps``: each ``steps * D`` rounded down, the remaining steps to the largest remainders (ties:
    the lower class). (n, C) int64; rows of ``D`` that sum to 0 stay 0."""
    D = np.asarray(D, np.float64)
    x = D * steps
    f = np.floor(x)
    rest = (steps - f.sum(axis=1)).astype(np.int64)
    rest = np.where(D.sum(axis=1) > 0, np.clip(rest, 0, D.shape[1]), 0)
    order = np.argsort(-(x - f), axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(D.shape[1])[None, :].repeat(len(D), axis=0), axis=1)
    return f.astype(np.int64) + (rank < rest[:, None])


@nb.njit(cache=True, nogil=True)
def _weighted_steps(E, S_f, s, steps, out):
    """``out[i] = s[i] * distribution_steps(E[i] / S_f[i], steps)`` for the rows with ``s[i] > 0``, zeros for the
    others: :func:`quantize_semantic_delta`'s class evidence a row at a time, without its (n, C) temporaries
    (seven of them at the peak of a frame's semantic update). The same operations on each value as the numpy
    formulation: ``x = (E / S_f) * steps``, ``f = floor(x)``, the ``steps - sum(f)`` left over (the floors are
    integers, so their sum is exact in any order) clipped to [0, C], and one more step each to that many
    classes of the largest ``x - f``, the lower class first on ties (a stable sort's order). A row whose
    distribution sums to 0 gets none; ``E`` is non-negative (weights times probabilities), so that is a row
    without a positive entry."""
    n, C = E.shape
    x = np.empty(C, np.float64)
    r = np.empty(C, np.float64)
    taken = np.empty(C, np.bool_)
    for i in range(n):
        if s[i] <= 0:
            for c in range(C):
                out[i, c] = 0
            continue
        fsum = 0.0
        positive = False
        for c in range(C):
            d = E[i, c] / S_f[i]
            positive = positive or d > 0
            xc = d * steps
            fc = np.floor(xc)
            x[c] = fc
            r[c] = xc - fc
            fsum += fc
            taken[c] = False
        rest = np.int64(steps - fsum) if positive else 0
        rest = min(max(rest, 0), C)
        for _ in range(rest):
            best = -1
            for c in range(C):
                if not taken[c] and (best < 0 or r[c] > r[best]):
                    best = c
            taken[best] = True
        for c in range(C):
            out[i, c] = s[i] * (np.int64(x[c]) + (1 if taken[c] else 0))


def distribution_evidence(D: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Class evidence in ``E``'s form from distributions ``D`` (n, C) and stored weights ``S`` (n,) or (n, 1)
    (``64 s``): ``s * distribution_steps(D)``, rows summing to ``S`` (a relabelled map's evidence, e.g. from
    its features: :func:`panovocc_cli.semantics.features.feature_distribution`). (n, C) int64."""
    return (np.asarray(S, np.int64).reshape(-1) // D_STEPS)[:, None] * distribution_steps(D)


def quantize_semantic_delta(keys: np.ndarray, channels: dict) -> Delta:
    """Float sums of :func:`semantics.evidence.frame_semantic_delta` -> the integer :class:`Delta` of the
    module docstring's table.

    keys : (n,) int64 sorted unique; channels : E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3)
    float64, count (n,) int64 (> 0); optionally Z (n, D) float64, the sum of eta times the pixels' int8
    features
    """
    S_f = np.asarray(channels["S"], np.float64).reshape(-1)
    count = np.asarray(channels["count"], np.int64).reshape(-1, 1)
    s = np.rint(S_f * S_STEPS).astype(np.int64)
    has = s > 0
    E = np.ascontiguousarray(channels["E"], np.float64)
    e = np.empty(E.shape, np.int64)  # s * distribution_steps(E / S_f), row by row (no (n, C) temporaries)
    _weighted_steps(E, S_f, s, np.float64(D_STEPS), e)
    k = np.maximum(count, 1)
    normal = np.rint(np.asarray(channels["normal_sum"], np.float64) * NORMAL_STEPS / k).astype(np.int64)
    rgb = np.rint(np.asarray(channels["rgb_sum"], np.float64) / k).astype(np.int64)
    out = {"E": e, "S": (D_STEPS * s)[:, None], "rgb_sum": count * rgb, "normal_sum": count * normal,
           "count": count}
    if "Z" in channels:  # the weighted mean feature (within the int8 range: a mean of int8 values), times s
        Zf = np.asarray(channels["Z"], np.float64)
        z = np.zeros(Zf.shape, np.int64)
        z[has] = np.rint(Zf[has] / S_f[has, None]).astype(np.int64)
        out["Z"] = s[:, None] * np.clip(z, -127, 127)
    return Delta(keys, out, {k: v for k, v in DELTA_FACTORS.items() if k in out})


def semantic_delta(depth: np.ndarray, rgb: np.ndarray, obs, T_world_cam: np.ndarray,
                   voxel_size: float, weights: EvidenceWeights, min_range: float, max_range: float,
                   rays: np.ndarray | None = None) -> Delta:
    """One frame's quantised semantic delta from its depth, colours and semantic observation (no I/O).

    Depths outside ``[min_range, max_range]`` (metres) are ignored, as in the geometry contributor.
    ``obs`` : :class:`~panovocc_cli.semantics.observation.SemanticObservation` at the semantic stride.
    """
    from ..semantics.evidence import frame_semantic_delta

    keys, ch = frame_semantic_delta(depth, rgb, obs, T_world_cam, voxel_size, weights, rays,
                                    depth_range=(min_range, max_range))
    return quantize_semantic_delta(keys, ch)
