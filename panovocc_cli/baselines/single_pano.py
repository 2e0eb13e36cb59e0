"""``single-pano``: paradigm (b) of the paper, each panorama mapped alone into a local volume, no memory.

Each frame goes into a fresh :class:`~panovocc_cli.mapping.Mapper` (the same fusion, occupancy rule and
semantic export as ``panovocc map``, the same poses and segmenter output), nothing is carried from one
frame to the next, and the frame's grid is cut to a local box on the global lattice:

* size: EmbodiedOcc's local volume, 4.8 x 4.8 x 2.88 m (60 x 60 x 36 voxels at 0.08 m), by default;
* horizontally (x, y, world axes: gravity-aligned like the ground truth) centred on the camera: the
  panoramic counterpart of EmbodiedOcc's volume in front of a perspective camera (a panorama sees all
  around); the box's first voxel is ``round(c / h - n / 2)`` for camera coordinate ``c`` and ``n`` voxels;
* vertically, ``vertical="floor"`` (default): the box stands on the floor as in EmbodiedOcc / Occ-ScanNet's
  volumes, the floor being estimated from the frame itself: the lowest voxel layer holding at least
  :data:`FLOOR_SHARE` of the frame's occupied voxels inside the box's footprint (no ground truth used),
  clamped so the camera stays inside the box; ``vertical="camera"``: centred on the camera.

The per-frame grids are scored in their own volume (the ground truth cut to the same box) and merged over
the sequence by the paper's rule (:func:`.merge.merge_dense`), which shows what a persistent memory adds.
Nothing here reads or writes files.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from ..errors import PanovoccError
from ..frame import Frame
from ..geometry.lattice import index_to_center
from ..grid import EMPTY, UNKNOWN, Grid

#: EmbodiedOcc's local volume, metres (60 x 60 x 36 voxels of 0.08 m).
EMBODIEDOCC_BOX_M = (4.8, 4.8, 2.88)
#: Least share of a frame's occupied voxels (inside the box's footprint) a layer needs to count as the floor.
FLOOR_SHARE = 0.02
VERTICAL = ("floor", "camera")


@dataclass(frozen=True)
class LocalBox:
    """A box of whole voxels on the global lattice: first voxel ``index0`` (3,) int64, ``shape`` (3,) int."""

    index0: np.ndarray
    shape: tuple

    def crop(self, grid: Grid) -> Grid:
        """``grid``'s labels inside the box (255 where ``grid`` has none), same class names."""
        out = np.full(self.shape, UNKNOWN, np.uint8)
        lo = np.maximum(self.index0, grid.index0)
        hi = np.minimum(self.index0 + np.asarray(self.shape), grid.index0 + np.asarray(grid.labels.shape))
        if np.all(hi > lo):
            dst = tuple(slice(int(a), int(b)) for a, b in zip(lo - self.index0, hi - self.index0))
            src = tuple(slice(int(a), int(b)) for a, b in zip(lo - grid.index0, hi - grid.index0))
            out[dst] = grid.labels[src]
        return Grid(out, index_to_center(self.index0, grid.voxel_size), grid.voxel_size, list(grid.class_names))


def box_voxels(size_m, voxel_size: float) -> tuple[int, int, int]:
    """Voxels per axis of a box ``size_m`` (3,) metres: ``round(size / h)``, at least 1."""
    n = tuple(max(1, int(round(float(s) / voxel_size))) for s in size_m)
    if len(n) != 3:
        raise PanovoccError(f"a local box needs 3 sizes (x, y, z metres), got {list(size_m)}")
    return n


def single_pano_memory(size_m, voxel_size: float, T_world_cam) -> tuple[tuple[int, int, int], float]:
    """Voxels per axis of one frame's box and the bytes :func:`single_pano` and the merge of its grids hold
    at once, from the box and the poses alone (before any frame is mapped).

    Every frame's uint8 grid is kept (``n`` frames x the box), and the merge (:func:`.merge.merge_dense`)
    holds three bytes a voxel over the union of the boxes: the span of the camera centres plus a box on
    each axis (two in height, where the floor may move a box down by its own height).

    Parameters
    ----------
    size_m : (3,) float, metres; voxel_size : h, metres; T_world_cam : (n, 4, 4) float64 poses

    Returns
    -------
    shape : (3,) int, voxels of one box; need : float, bytes (may be far beyond any machine, or inf)
    """
    n = box_voxels(size_m, voxel_size)
    c = np.asarray(T_world_cam, np.float64).reshape(-1, 4, 4)[:, :3, 3] / voxel_size
    span = np.ptp(c, axis=0) if len(c) else np.zeros(3)
    union = span + np.asarray(n, np.float64) * np.array([1.0, 1.0, 2.0]) + 1.0
    cells = float(np.prod(np.asarray(n, np.float64)))
    return n, cells * (len(c) + 1) + 3.0 * float(np.prod(union))


def local_box(T_world_cam: np.ndarray, grid: Grid, size_m=EMBODIEDOCC_BOX_M, vertical: str = "floor") -> LocalBox:
    """The local box of one frame (module docstring) given the frame's own grid ``grid``.

    Parameters
    ----------
    T_world_cam : (4, 4) float64; grid : Grid of the frame alone (its occupied voxels place the floor)
    size_m : (3,) float, metres; vertical : ``floor`` | ``camera``
    """
    if vertical not in VERTICAL:
        raise PanovoccError(f"vertical placement must be floor or camera, got {vertical!r}")
    h = grid.voxel_size
    n = np.asarray(box_voxels(size_m, h), np.int64)
    c = np.asarray(T_world_cam, np.float64)[:3, 3] / h
    i0 = np.round(c - n / 2.0).astype(np.int64)
    cam_k = int(np.floor(c[2]))
    if vertical == "floor":
        occ = np.argwhere((grid.labels != EMPTY) & (grid.labels != UNKNOWN)) + grid.index0
        footprint = occ[np.all((occ[:, :2] >= i0[:2]) & (occ[:, :2] < i0[:2] + n[:2]), axis=1)]
        layers, counts = np.unique(footprint[footprint[:, 2] <= cam_k, 2], return_counts=True)
        floor = layers[counts >= FLOOR_SHARE * len(footprint)]
        if len(floor):  # the lowest well-populated layer at or below the camera; the camera stays inside
            i0[2] = min(max(int(floor[0]), cam_k - int(n[2]) + 1), cam_k)
    return LocalBox(i0, tuple(int(x) for x in n))


def single_pano(frames: Iterable[Frame], config, size_m=EMBODIEDOCC_BOX_M,
                vertical: str = "floor") -> Iterator[tuple[int, LocalBox, Grid]]:
    """Map each frame alone; yield ``(frame index, its LocalBox, its grid cut to the box)`` one at a time.

    Parameters
    ----------
    frames : iterable of Frame (with logits over ``config.vocab`` for semantics)
    config : MapperConfig of every per-frame mapper (a fresh :class:`~panovocc_cli.mapping.Mapper` each)
    size_m, vertical : the local box (:func:`local_box`)
    """
    from ..mapping.mapper import Mapper

    for k, frame in enumerate(frames):
        mapper = Mapper(config)
        mapper.integrate(frame)
        grid = mapper.prediction()
        mapper.close()
        box = local_box(frame.T_world_cam, grid, size_m, vertical)
        yield (int(frame.index) if frame.index is not None else k), box, box.crop(grid)
