"""Observation-level coverage (the paper's Fig. 5): how much of the ground truth a trajectory sees.

``Cov(s) = |union_i V_i^s| / |V_occ^GT|`` where ``V_i^s`` is the set of ground-truth occupied voxels
**directly observed** at camera location ``i`` under setting ``s``: the full panorama, or a single
forward-looking perspective camera at the same pose (the camera z axis, 90 degrees horizontal field
of view by default).

"Directly observed" is decided the way the ground truth itself is built (ReplicaOcc aggregates the
depth observations of a sequence into voxels): every valid depth pixel is lifted to its world point,
and the ground-truth occupied voxel that contains the point is observed. A point closer than
``tol_m`` to a voxel face also observes the neighbour across that face, so surfaces lying exactly on
lattice planes (and millimetre depth quantisation) do not flip between voxels. Only the measured
(first) surface is lifted, so occluded voxels are never counted, and unlike projecting voxel centres
into the image this does not miss walls seen at grazing angles.

The perspective camera is the part of the panorama inside its frustum: ERP pixels whose ray ``d``
(camera frame) has ``d_z > 0``, ``|d_x| / d_z <= tan(hfov / 2)`` and ``|d_y| / d_z <= tan(vfov / 2)``.
The default vertical field of view comes from the Replica/NICE-SLAM camera's aspect (1200 x 680).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import COVERAGE_TOL_M
from ..errors import PanovoccError
from ..geometry.erp import ray_directions
from ..grid import EMPTY, UNKNOWN, Grid

REPLICA_ASPECT = 1200.0 / 680.0  # NICE-SLAM Replica camera, fx = fy = 600: 90 x 59.0 degrees
DEFAULT_TOL_M = COVERAGE_TOL_M


def vertical_fov(hfov: float, aspect: float = REPLICA_ASPECT) -> float:
    """Vertical field of view (radians) of a pinhole camera of horizontal FOV ``hfov`` (radians) and aspect W/H."""
    return 2.0 * math.atan(math.tan(hfov / 2.0) / aspect)


def perspective_mask(width: int, height: int, hfov: float, vfov: float) -> np.ndarray:
    """ERP pixels a forward-looking pinhole camera at the same pose sees.

    Parameters
    ----------
    width, height : ERP size (W = 2 H)
    hfov, vfov : radians, full horizontal / vertical field of view, each in (0, pi)

    Returns
    -------
    mask : (H, W) bool
    """
    if not (0 < hfov < math.pi and 0 < vfov < math.pi):
        raise PanovoccError(f"fields of view must be in (0, 180) degrees, got {math.degrees(hfov):g} x "
                            f"{math.degrees(vfov):g}")
    d = ray_directions(width, height)
    z = d[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return (z > 1e-9) & (np.abs(d[..., 0]) <= math.tan(hfov / 2) * z) & (np.abs(d[..., 1]) <= math.tan(vfov / 2) * z)


def occupied_mask(gt: Grid) -> np.ndarray:
    """Ground-truth occupied voxels, (X, Y, Z) bool: label not in {0, 255}."""
    return (gt.labels != EMPTY) & (gt.labels != UNKNOWN)


def observed_voxels(points_world: np.ndarray, gt: Grid, occupied_flat: np.ndarray, tol_m: float) -> np.ndarray:
    """Flat indices (into ``gt.labels``) of the occupied voxels that observed points fall in.

    Parameters
    ----------
    points_world : (n, 3) float64, metres, world frame
    gt : Grid
    occupied_flat : (X*Y*Z,) bool, :func:`occupied_mask` flattened
    tol_m : metres (< voxel_size / 2): a point this close to a face also observes the voxel across it

    Returns
    -------
    flat : (m,) int64, may repeat
    """
    h = gt.voxel_size
    if not 0 <= tol_m < h / 2:
        raise PanovoccError(f"coverage tolerance must be in [0, voxel_size/2), got {tol_m} m")
    q = points_world / h
    base = np.floor(q)
    frac = (q - base) * h
    alt = np.where(frac < tol_m, -1, np.where(frac > h - tol_m, 1, 0)).astype(np.int64)
    base = base.astype(np.int64) - gt.index0
    shape = np.asarray(gt.labels.shape, dtype=np.int64)
    out = []
    for s in range(8):
        sel = np.array([(s >> a) & 1 for a in range(3)], dtype=bool)
        if sel.any():
            keep = np.all(alt[:, sel] != 0, axis=1)
            idx = base[keep] + alt[keep] * sel
        else:
            idx = base
        inside = np.all((idx >= 0) & (idx < shape), axis=1)
        idx = idx[inside]
        flat = (idx[:, 0] * shape[1] + idx[:, 1]) * shape[2] + idx[:, 2]
        out.append(flat[occupied_flat[flat]])
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


@dataclass
class CoverageTracker:
    """Cumulative coverage of one ground truth under the panoramic and perspective settings.

    Feed frames in trajectory order with :meth:`add`; each call returns the coverage so far.
    """

    gt: Grid
    width: int
    height: int
    hfov: float = math.radians(90.0)
    vfov: float | None = None
    tol_m: float = DEFAULT_TOL_M

    def __post_init__(self):
        self.occupied = occupied_mask(self.gt).reshape(-1)
        self.total = int(self.occupied.sum())
        if self.total == 0:
            raise PanovoccError("the ground truth has no occupied voxels: coverage is undefined")
        if self.vfov is None:
            self.vfov = vertical_fov(self.hfov)
        self.rays = ray_directions(self.width, self.height)
        self.persp = perspective_mask(self.width, self.height, self.hfov, self.vfov)
        self.seen = {"panoramic": np.zeros(self.occupied.size, dtype=bool),
                     "perspective": np.zeros(self.occupied.size, dtype=bool)}

    def add(self, depth: np.ndarray, T_world_cam: np.ndarray) -> dict[str, float]:
        """Add one frame.

        Parameters
        ----------
        depth : (H, W) float, metres, radial, 0 = invalid
        T_world_cam : (4, 4) float64

        Returns
        -------
        {"panoramic": fraction, "perspective": fraction} of GT occupied voxels observed so far, in [0, 1]
        """
        if depth.shape != (self.height, self.width):
            raise PanovoccError(f"depth is {depth.shape}, expected {(self.height, self.width)}")
        valid = depth > 0
        for name, m in (("panoramic", valid), ("perspective", valid & self.persp)):
            pts_cam = self.rays[m] * depth[m, None].astype(np.float64)
            pts = pts_cam @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
            self.seen[name][observed_voxels(pts, self.gt, self.occupied, self.tol_m)] = True
        return self.fractions()

    def fractions(self) -> dict[str, float]:
        """Coverage so far, fraction in [0, 1] per setting."""
        return {k: np.count_nonzero(v) / self.total for k, v in self.seen.items()}


def frame_schedule(n: int, every: int) -> list[int]:
    """Frames 0, K, 2K, ... and always the last one (so the final value covers the whole sequence)."""
    if every < 1:
        raise PanovoccError(f"--every must be >= 1, got {every}")
    if n <= 0:
        raise PanovoccError("the sequence has no frames")
    fr = list(range(0, n, every))
    if fr[-1] != n - 1:
        fr.append(n - 1)
    return fr
