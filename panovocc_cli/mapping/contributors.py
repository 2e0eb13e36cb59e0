"""Per-frame contributors: pure functions from one frame (and its pose) to a sparse :class:`Delta`.

The mapper runs a list of contributors on every frame and merges their deltas into the one delta it
stores and adds to the memory. The geometry contributor, :func:`geometry_delta` (A, N, F, O), is the
PSVF per-frame update (:mod:`.psvf.update`); the semantic stage plugs in a contributor of its own
channels (E, S, rgb_sum, normal_sum, count) the same way.
"""

from __future__ import annotations

from .psvf.update import MAX_FRAME_VOXELS, frame_box, geometry_delta, keep_freed_heap

__all__ = ["MAX_FRAME_VOXELS", "frame_box", "geometry_delta", "keep_freed_heap"]
