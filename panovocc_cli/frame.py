"""One RGB-D frame held in memory: what a sequence reader yields and what the mapper integrates.

A :class:`Frame` is data, not a file handle: readers (``io.sequence.Sequence.frame``), renderers or a SLAM
front end build it, and nothing downstream reaches back to disk for it. It lives at the package root,
next to :mod:`panovocc_cli.grid`, because both the I/O layer (which produces frames) and the mapping
layer (which consumes them) use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import PanovoccError
from .geometry.cameras import ErpCamera
from .geometry.poses import check_rigid


@dataclass
class Frame:
    """One frame.

    Attributes
    ----------
    rgb : (H, W, 3) uint8, the colours
    depth : (H, W) float32, metres, radial (distance along the pixel's ray), 0 = invalid
    T_world_cam : (4, 4) float64, camera-to-world pose (OpenCV camera axes, world +Z up)
    camera : ErpCamera, the camera model (its ``shape`` is (H, W))
    logits : (H, W, C) float32 or None, per-pixel class scores over the mapper's vocabulary (C words); or
        (ceil(H/s), ceil(W/s), C), the scores of pixels (s i, s j) at an integer stride s (a segmenter run
        at the mapper's semantic stride, :func:`logits_stride`)
    index : int or None, the frame's identity (its position in the sequence); the mapper uses it as the
        frame id when given
    features : (H, W, F) or (ceil(H/s), ceil(W/s), F) float32 or None, per-pixel embeddings of a segmenter
        that gives them (a map with ``--features`` fuses them; :mod:`panovocc_cli.semantics.features`)
    """

    rgb: np.ndarray
    depth: np.ndarray
    T_world_cam: np.ndarray
    camera: ErpCamera
    logits: np.ndarray | None = None
    index: int | None = None
    features: np.ndarray | None = None

    def __post_init__(self):
        self.T_world_cam = np.asarray(self.T_world_cam, np.float64)

    def check(self) -> "Frame":
        """Validate shapes, dtypes and the pose (a rigid transform within ``config.RIGID_TOL``:
        :func:`~panovocc_cli.geometry.poses.check_rigid`); raise :class:`PanovoccError` naming what is wrong."""
        what = f"frame {self.index}" if self.index is not None else "frame"
        if not isinstance(self.camera, ErpCamera):
            raise PanovoccError(f"{what}: camera {self.camera!r} is not supported (ERP only)")
        hw = self.camera.shape
        d = np.asarray(self.depth)
        if d.shape != hw or d.dtype != np.float32:
            raise PanovoccError(f"{what}: depth is {d.dtype} {d.shape}, expected float32 {hw}")
        c = np.asarray(self.rgb)
        if c.shape != hw + (3,) or c.dtype != np.uint8:
            raise PanovoccError(f"{what}: rgb is {c.dtype} {c.shape}, expected uint8 {hw + (3,)}")
        check_rigid(self.T_world_cam, f"{what}: T_world_cam")  # finite, orthonormal, last row [0 0 0 1]
        if self.logits is not None:
            lg = np.asarray(self.logits)
            if lg.ndim != 3 or not logits_stride(hw, lg.shape[:2]):
                raise PanovoccError(f"{what}: logits have shape {lg.shape}, expected {hw + ('C',)} "
                                    "(or that size at an integer pixel stride s: ceil(H/s), ceil(W/s))")
        return self


def logits_stride(image_hw: tuple, logits_hw: tuple) -> int:
    """The integer pixel stride s at which logits of size ``logits_hw`` sample an image of size
    ``image_hw`` (rows and columns 0, s, 2s, ...: ``ceil(H / s), ceil(W / s)``); 0 when there is none."""
    H, W = (int(x) for x in image_hw)
    h, w = (int(x) for x in logits_hw)
    if h < 1 or w < 1:
        return 0
    s = max(1, H // h)
    for cand in (s, s + 1):  # ceil(H / s) == h pins s down to these two
        if -(-H // cand) == h and -(-W // cand) == w:
            return cand
    return 0
