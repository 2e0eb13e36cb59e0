"""Per-frame contributors: pure functions from one frame (and its pose) to a sparse :class:`~.memory.Delta`.

The mapper runs the contributors on every frame and keeps their deltas as the parts of the one
:class:`~.memory.FrameDelta` it stores and adds to the memory. The geometry contributor,
:func:`geometry_delta` (A, N, F, O), is the PSVF per-frame update (:mod:`.psvf.update`). The semantic
contributor, :func:`semantic_delta`, turns the segmenter's logits into the sparse per-voxel sums of
:func:`panovocc_cli.semantics.evidence.frame_semantic_delta`, quantised into memory channels that travel
through the SAME delta mechanism as the geometry (delta files, ``revise``, ``--resume``: the memory stays
the exact integer sum of the retained deltas).

Channels (``C`` = vocabulary size):

==============  =====  ======  ============================================================
name            width  kind    content
==============  =====  ======  ============================================================
``E``           C      fixed   sum of eta * p (2^-16 resolution)
``S``           1      fixed   sum of eta
``rgb_sum``     3      int     plain sum of pixel colours (0..255 integers: exact as integers)
``normal_sum``  3      fixed   plain sum of unit normals
``count``       1      int     pixels (measurements)
==============  =====  ======  ============================================================

Overflow: eta <= 1 and |p|, |n| <= 1, so a frame adds at most (pixels in the voxel) * 2^16 to an E, S
or normal_sum entry. Even a whole 2048x1024 frame falling into one voxel adds 2^37; int64 holds 2^63,
i.e. 2^26 (67 million) such frames. Rounding error: at most 2^-17 per entry per frame (the per-frame
sum is rounded once), far below a single pixel's weight.
"""

from __future__ import annotations

import numpy as np

from ..semantics.params import EvidenceWeights
from .memory import ChannelSpec, Delta, quantize
from .psvf.update import MAX_FRAME_VOXELS, frame_box, geometry_delta, keep_freed_heap

__all__ = ["MAX_FRAME_VOXELS", "frame_box", "geometry_delta", "keep_freed_heap", "quantize_semantic_delta",
           "semantic_channels", "semantic_delta"]


def semantic_channels(n_classes: int) -> tuple[ChannelSpec, ...]:
    """Memory channels of the semantic contributor for a vocabulary of ``n_classes`` words."""
    return (ChannelSpec("E", n_classes, "fixed"), ChannelSpec("S", 1, "fixed"), ChannelSpec("rgb_sum", 3, "int"),
            ChannelSpec("normal_sum", 3, "fixed"), ChannelSpec("count", 1, "int"))


def quantize_semantic_delta(keys: np.ndarray, channels: dict) -> Delta:
    """Float sums of :func:`semantics.evidence.frame_semantic_delta` -> integer :class:`Delta`.

    keys : (n,) int64 sorted unique; channels : E (n, C), S (n,), rgb_sum (n, 3), normal_sum (n, 3)
    float64, count (n,) int64
    """
    return Delta(keys, {"E": quantize(channels["E"], "fixed"), "S": quantize(channels["S"], "fixed"),
                        "rgb_sum": quantize(channels["rgb_sum"], "int"),
                        "normal_sum": quantize(channels["normal_sum"], "fixed"),
                        "count": np.asarray(channels["count"], np.int64)})


def semantic_delta(depth: np.ndarray, rgb: np.ndarray, logits: np.ndarray, T_world_cam: np.ndarray,
                   voxel_size: float, weights: EvidenceWeights, min_range: float, max_range: float,
                   rays: np.ndarray | None = None) -> Delta:
    """One frame's quantised semantic delta from its depth, colours and segmenter logits (no I/O).

    Depths outside ``[min_range, max_range]`` (metres) are ignored, as in the geometry contributor.
    """
    from ..semantics.evidence import frame_semantic_delta

    depth = np.where((depth >= min_range) & (depth <= max_range), depth, 0.0).astype(np.float32)
    keys, ch = frame_semantic_delta(depth, rgb, logits, T_world_cam, voxel_size, weights, rays)
    return quantize_semantic_delta(keys, ch)
