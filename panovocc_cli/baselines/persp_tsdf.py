"""``persp-tsdf``: the twelve view sequences of a panoramic stream, each fused with Open3D's TSDF, merged.

Paradigm (a) of the paper given the panorama's full coverage (its "Perspective Baseline Adaptation"):
each panorama is cut into the twelve pinhole views of :meth:`ViewRig.twelve` (in memory, the resampling of
``panovocc views``: z-depth and labels nearest neighbour, RGB bilinear), views of one orientation form one
temporally continuous stream, each stream is fused alone (:class:`.tsdf.TsdfStream`), and the twelve
grids are merged by the paper's rule (:func:`.merge.merge_dense`: occupied by union, classes by voting).
The segmenter's output is the one ``panovocc map`` computes on the panorama (its per-pixel argmax),
resampled into each view by nearest neighbour; poses are ``T_world_cam @ T_cam_view``.

Nothing here reads or writes files: frames come in as :class:`~panovocc_cli.frame.Frame` objects.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from ..frame import Frame
from ..geometry.cameras import ViewRig
from ..grid import Grid
from .merge import merge_dense
from .tsdf import TRUNC_VOXELS, TsdfStream

def pixel_classes(frame: Frame) -> np.ndarray | None:
    """(H, W) int64 vocabulary index of each pixel (argmax of the frame's logits), or None without logits.

    Logits at the map's semantic stride s (pixels (s i, s j) only: :func:`panovocc_cli.frame.logits_stride`)
    give each pixel the class of the nearest sampled pixel (ties: the one above / to the left).
    """
    if frame.logits is None:
        return None
    from ..frame import logits_stride

    cls = np.asarray(frame.logits).argmax(axis=2).astype(np.int64)
    H, W = frame.camera.shape
    s = logits_stride((H, W), cls.shape)
    if s > 1:
        rows = np.minimum((np.arange(H) + (s - 1) // 2) // s, cls.shape[0] - 1)
        cols = np.minimum((np.arange(W) + (s - 1) // 2) // s, cls.shape[1] - 1)
        cls = cls[rows[:, None], cols[None, :]]
    return cls


def fuse_streams(frames: Iterable[Frame], rig: ViewRig, vocab: Sequence[str], voxel_size: float, *,
                 min_range: float = 0.1, max_range: float = 12.0, weight_threshold: float = 1.0,
                 trunc_voxels: float = TRUNC_VOXELS) -> list[Grid]:
    """Fuse each view of ``rig`` as its own stream over ``frames``; one grid per view, in rig order.

    Parameters
    ----------
    frames : iterable of Frame (ERP, radial depth, logits over ``vocab`` or None)
    rig : ViewRig (its views share one PinholeCamera)
    vocab : list of str, the logits' classes (grid class ids 1..C); empty = geometry only
    voxel_size : float, metres; min_range, max_range : float, metres (as the map's)
    weight_threshold : float, least TSDF weight of an occupied or free voxel; trunc_voxels : float

    Returns
    -------
    list of Grid, ``class_names = ["empty"] + vocab`` (see :meth:`.tsdf.TsdfStream.grid`)
    """
    from .views import ViewSampler

    sampler = None
    streams = [TsdfStream(v.camera, voxel_size, len(vocab), min_range=min_range, max_range=max_range,
                          weight_threshold=weight_threshold, trunc_voxels=trunc_voxels) for v in rig]
    for frame in frames:
        if sampler is None:
            sampler = ViewSampler(rig, frame.camera.width)
        cls = pixel_classes(frame) if len(vocab) else None
        rgb, z, lab = sampler.split(frame.rgb, frame.depth, cls)
        for k, view in enumerate(rig):
            streams[k].integrate(z[k], view.T_world_view(frame.T_world_cam), rgb[k],
                                 None if lab is None else lab[k])
    return [s.grid(vocab) for s in streams]


def persp_tsdf(frames: Iterable[Frame], rig: ViewRig, vocab: Sequence[str], voxel_size: float,
               **kwargs) -> tuple[Grid, list[Grid]]:
    """The merged grid of the twelve streams and the streams' own grids (:func:`fuse_streams`)."""
    grids = fuse_streams(frames, rig, vocab, voxel_size, **kwargs)
    return merge_dense(grids), grids
