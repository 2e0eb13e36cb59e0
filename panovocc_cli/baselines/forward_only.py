"""``forward-only``: paradigm (a) of the paper as one perspective camera looking ahead.

Of each panorama only the forward middle view of the twelve-view rig (azimuth 0, pitch 0: the panorama's
centre column, level) is kept; the views form one perspective stream fused exactly like one stream of
``persp-tsdf`` (:func:`.persp_tsdf.fuse_streams`: Open3D TSDF, class votes on the global lattice), with the
same poses and the same segmenter output. Nothing here reads or writes files.
"""

from __future__ import annotations

from typing import Iterable, Sequence

from ..errors import PanovoccError
from ..frame import Frame
from ..geometry.cameras import ViewRig
from ..grid import Grid
from .persp_tsdf import fuse_streams


def forward_view(rig: ViewRig) -> int:
    """Index of the view of ``rig`` looking along the panorama's centre column, level (azimuth 0, pitch 0)."""
    for k, v in enumerate(rig):
        if abs(v.azimuth_rad) < 1e-12 and abs(v.pitch_rad) < 1e-12:
            return k
    raise PanovoccError("the view rig has no forward middle view (azimuth 0, pitch 0)")


def forward_only(frames: Iterable[Frame], rig: ViewRig, vocab: Sequence[str], voxel_size: float, **kwargs) -> Grid:
    """The grid of the forward middle view's stream (``kwargs``: those of :func:`.persp_tsdf.fuse_streams`)."""
    return fuse_streams(frames, ViewRig((rig[forward_view(rig)],)), vocab, voxel_size, **kwargs)[0]
