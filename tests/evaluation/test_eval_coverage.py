"""Coverage (Fig. 5) on a box room whose depth is known in closed form."""

import math

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.evaluation.coverage import CoverageTracker, frame_schedule, perspective_mask, vertical_fov
from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.grid import Grid

H_VOX = 0.08
N = (20, 20, 15)  # room interior in voxels: [0, 1.6] x [0, 1.6] x [0, 1.2] metres


def box_room_gt() -> Grid:
    """GT: the wall voxels just outside the room's six faces (no edge/corner voxels), class 'wall'."""
    nx, ny, nz = N
    lab = np.zeros((nx + 2, ny + 2, nz + 2), dtype=np.uint8)
    lab[0, 1:-1, 1:-1] = lab[-1, 1:-1, 1:-1] = 1
    lab[1:-1, 0, 1:-1] = lab[1:-1, -1, 1:-1] = 1
    lab[1:-1, 1:-1, 0] = lab[1:-1, 1:-1, -1] = 1
    lab[0, 0, 0] = 255  # unknown corner: not occupied, ignored
    return Grid(lab, origin=np.full(3, -0.5 * H_VOX), voxel_size=H_VOX, class_names=["empty", "wall"])


def box_depth(T_world_cam: np.ndarray, width: int) -> np.ndarray:
    """Radial depth (H, W) seen from inside the box [0, L] (closed form: nearest plane along each ray)."""
    L = np.asarray(N) * H_VOX
    d = ray_directions(width) @ T_world_cam[:3, :3].T
    p = T_world_cam[:3, 3]
    with np.errstate(divide="ignore"):
        t = np.where(d > 0, (L - p) / d, np.where(d < 0, -p / d, np.inf))
    return t.min(axis=-1).astype(np.float32)


def trajectory():
    return [look_at([0.5 + 0.2 * i, 0.6 + 0.1 * i, 0.6], [math.cos(0.7 * i), math.sin(0.7 * i), 0.0])
            for i in range(4)]


def test_full_panorama_sees_every_wall_voxel_and_perspective_less():
    gt = box_room_gt()
    tr = CoverageTracker(gt, 256, 128, hfov=math.radians(90))
    pano, persp = [], []
    for T in trajectory():
        c = tr.add(box_depth(T, 256), T)
        pano.append(c["panoramic"])
        persp.append(c["perspective"])
    assert tr.total == 2 * (20 * 15 + 20 * 15 + 20 * 20)
    assert pano[0] == pytest.approx(1.0)  # one panorama of a convex room sees all its walls
    assert all(a >= b for a, b in zip(pano, persp))
    assert np.all(np.diff(persp) >= 0) and np.all(np.diff(pano) >= 0)
    assert 0.05 < persp[0] < 0.5 and persp[-1] > persp[0]


def test_perspective_mask_fraction_matches_solid_angle():
    w, h = 512, 256
    hfov, vfov = math.radians(90), vertical_fov(math.radians(90), 1200 / 680)
    assert math.degrees(vfov) == pytest.approx(59.0, abs=0.1)
    m = perspective_mask(w, h, hfov, vfov)
    # solid angle of the frustum, area-weighted pixel count (cos latitude)
    lat = np.pi / 2 - (np.arange(h) + 0.5) * np.pi / h
    omega = (m * np.cos(lat)[:, None]).sum() * (2 * np.pi / w) * (np.pi / h)
    a, b = math.tan(hfov / 2), math.tan(vfov / 2)
    exact = 4 * math.asin(a * b / math.sqrt((1 + a * a) * (1 + b * b)))
    assert omega == pytest.approx(exact, rel=0.02)
    assert m[h // 2, w // 2] and not m[h // 2, 0]  # looks along +z, not backwards


def test_occluded_voxels_are_not_observed():
    gt = box_room_gt()
    lab = gt.labels.copy()
    lab[-2, 5:15, 5:10] = 1  # a slab just in front of the +x wall hides the wall voxels behind it
    g2 = Grid(lab, gt.origin, gt.voxel_size, gt.class_names)
    T = look_at([0.8, 0.8, 0.6], [1.0, 0.0, 0.0])
    depth = box_depth(T, 256)
    L = np.asarray(N) * H_VOX
    d = ray_directions(256) @ T[:3, :3].T
    pts = T[:3, 3] + d * depth[..., None]
    slab = (pts[..., 0] > L[0] - 1e-6) & (pts[..., 1] > 5 * H_VOX) & (pts[..., 1] < 15 * H_VOX) \
        & (pts[..., 2] > 5 * H_VOX) & (pts[..., 2] < 10 * H_VOX)
    depth = np.where(slab, depth * ((L[0] - H_VOX - T[0, 3]) / (L[0] - T[0, 3])), depth).astype(np.float32)
    tr = CoverageTracker(g2, 256, 128, tol_m=0.01)
    tr.add(depth, T)
    seen = tr.seen["panoramic"].reshape(lab.shape)
    assert seen[-2, 6:14, 6:9].all()  # the slab is seen
    assert not seen[-1, 7:13, 7:8].any()  # the wall behind it is not


def test_schedule_and_errors():
    assert frame_schedule(10, 4) == [0, 4, 8, 9]
    assert frame_schedule(3, 1) == [0, 1, 2]
    with pytest.raises(PanovoccError):
        frame_schedule(5, 0)
    empty = Grid(np.zeros((3, 3, 3), np.uint8), np.full(3, 0.04), 0.08, ["empty"])
    with pytest.raises(PanovoccError, match="no occupied"):
        CoverageTracker(empty, 64, 32)
