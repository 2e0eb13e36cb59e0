"""Lifted ground truth (gt --from-sequence): occupancy by minimum support, free space, 255, lifted labels,
bounded nearest-label transfer, on a closed-form box room whose walls lie off the voxel faces."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from box_room import box_depth, turned_pose  # noqa: E402

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.geometry.lattice import point_to_index
from panovocc_cli.gt.lifted import LiftAccumulator, depth_bounds, parse_annotated

H = 0.08
LO, HI = np.array([-1.97, -1.43, -1.21]), np.array([1.95, 1.47, 1.57])
NAMES = ["unlabeled", "floor", "ceiling", "wall"]
W = 512


def face_labels(W, T):
    """(W/2, W) class ids of the box face each pixel sees: floor 1, ceiling 2, walls 3."""
    d = ray_directions(W) @ T[:3, :3].T
    p = T[:3, 3] + d * box_depth(W, T, LO, HI)[..., None].astype(np.float64)
    lab = np.full(p.shape[:2], 3, np.int64)
    lab[np.abs(p[..., 2] - LO[2]) < 1e-3] = 1
    lab[np.abs(p[..., 2] - HI[2]) < 1e-3] = 2
    return lab


POSES = [turned_pose(0.0, (0.0, 0.0, 0.0)), turned_pose(0.7, (0.4, -0.3, 0.1)), turned_pose(-1.1, (-0.5, 0.35, -0.1)),
         turned_pose(2.0, (0.8, 0.2, 0.05))]


def accumulate(frames, annotate=(0,), W=W):
    """LiftAccumulator over the box's bounds fed ``frames``: list of (depth, T)."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for d, T in frames:
        a, b = depth_bounds(d, T)
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
    i0 = point_to_index(lo, H)
    acc = LiftAccumulator(i0, point_to_index(hi, H) - i0 + 1, H, len(NAMES))
    for k, (d, T) in enumerate(frames):
        acc.add_frame(d, T, face_labels(d.shape[1], T) if k in annotate else None)
    return acc


def box_frames(W=W):
    return [(box_depth(W, T, LO, HI), T) for T in POSES]


def shell_index():
    """Lattice indices (set) of the voxels the box's six faces pass through; and the index box."""
    a, b = point_to_index(LO, H), point_to_index(HI, H)
    ii = np.stack(np.meshgrid(*[np.arange(a[d], b[d] + 1) for d in range(3)], indexing="ij"), -1).reshape(-1, 3)
    on = (ii == a).any(1) | (ii == b).any(1)
    return {tuple(x) for x in ii[on].tolist()}, a, b


@pytest.fixture(scope="module")
def box_acc():
    return accumulate(box_frames())


def occupied_set(g):
    ijk = np.argwhere((g.labels > 0) & (g.labels < 255)) + g.index0
    return {tuple(x) for x in ijk.tolist()}


def test_box_occupancy_is_the_shell_and_inside_is_free(box_acc):
    g = box_acc.grid(NAMES, 2, 3, 0.16, 0.2)
    shell, a, b = shell_index()
    occ = occupied_set(g)
    assert occ <= shell  # no voxel off the walls
    assert len(occ) >= 0.97 * len(shell)  # and nearly all of them (corners seen at grazing angles may miss)
    # lattice: origin is a voxel centre of the global lattice, the box's walls in the grid
    assert np.allclose(g.origin / H - 0.5, np.round(g.origin / H - 0.5))
    inner = g.labels[tuple(slice(a[d] + 1 - g.index0[d], b[d] - g.index0[d]) for d in range(3))]
    assert (inner == 0).mean() > 0.99 and not ((inner > 0) & (inner < 255)).any()
    assert g.class_names == ["empty", "floor", "ceiling", "wall"]


def test_labels_lifted_and_consolidated(box_acc):
    g = box_acc.grid(NAMES, 2, 3, 0.0, 0.2)
    shell, a, b = shell_index()
    ijk = np.argwhere((g.labels > 0) & (g.labels < 254)) + g.index0
    lab = g.labels[(g.labels > 0) & (g.labels < 254)]
    assert len(ijk) > 0.9 * len(shell)  # frame 0 sees the whole room
    faces = np.stack([ijk[:, 2] == a[2], ijk[:, 2] == b[2], (ijk[:, :2] == a[:2]).any(1) | (ijk[:, :2] == b[:2]).any(1)])
    only = faces.sum(0) == 1  # voxels on one face (edges may go either way)
    expect = np.argmax(faces, 0) + 1
    assert only.sum() > 0.8 * len(ijk)
    assert np.array_equal(lab[only], expect[only])


def test_nearest_label_transfer_is_bounded():
    frames = box_frames()
    acc = accumulate(frames, annotate=())
    T0 = frames[0][1]
    lab = face_labels(W, T0)
    lab[:, W // 2 - 60:W // 2 + 60] = 0  # a 84 degree wide band of longitude left unannotated
    acc.add_frame(frames[0][0], T0, lab)  # the same frame again, annotated
    none = acc.grid(NAMES, 2, 3, 0.0, 0.2)
    near = acc.grid(NAMES, 2, 3, 0.16, 0.2)
    far = acc.grid(NAMES, 2, 3, 10.0, 0.2)
    assert np.array_equal((none.labels > 0) & (none.labels < 255), (near.labels > 0) & (near.labels < 255))
    assert (none.labels == 254).sum() > 50
    assert (far.labels == 254).sum() == 0 and ((far.labels > 0) & (far.labels < 254)).sum() == len(occupied_set(far))
    # near: a 254 voxel has no voted voxel within 2 voxels; a transferred one has (checked by brute force)
    from scipy import ndimage

    voted = (none.labels > 0) & (none.labels < 254)
    dist = ndimage.distance_transform_edt(~voted)
    unl = none.labels == 254
    assert np.all(dist[unl & (near.labels == 254)] > 2.0)
    assert np.all(dist[unl & (near.labels < 254)] <= 2.0 + 1e-9)
    assert 0 < (unl & (near.labels < 254)).sum() < unl.sum()
    # transferred labels are those of the nearest voted voxel: walls stay walls away from the edges
    _, idx = ndimage.distance_transform_edt(~voted, return_indices=True)
    got = near.labels[unl & (near.labels < 254)]
    src = none.labels[tuple(i[unl & (near.labels < 254)] for i in idx)]
    assert (got == src).mean() > 0.95


def test_minimum_support_drops_one_frame_outliers():
    frames = box_frames()
    d0 = frames[0][0].copy()
    d0[60:70, 100:110] = 0.9  # a blob of outliers 0.9 m from the first camera, in space the others see through
    frames[0] = (d0, frames[0][1])
    acc = accumulate(frames)
    strict = acc.grid(NAMES, 2, 3, 0.16, 0.2)
    loose = acc.grid(NAMES, 1, 1, 0.16, 0.0)
    pts = ray_directions(W)[60:70, 100:110].reshape(-1, 3) * 0.9
    vox = np.unique(point_to_index(pts, H), axis=0) - strict.index0
    at = tuple(vox.T)
    assert np.all((loose.labels[at] > 0) & (loose.labels[at] < 255))
    assert np.all(strict.labels[at] == 0)  # free: other frames see through


def test_hit_ratio_drops_surface_noise_in_seen_through_space():
    """Noise that puts one frame's wall points 0.3 m in front of the wall, seen again from the same place in a
    second frame: two frames support it (min_frames passes) but four see through it."""
    frames = box_frames()
    d = frames[1][0] * np.float32(0.85)
    frames += [(d, frames[1][1]), (d.copy(), frames[1][1])]
    acc = accumulate(frames)
    shell, _, _ = shell_index()
    assert not occupied_set(acc.grid(NAMES, 2, 3, 0.16, 0.0)) <= shell
    assert occupied_set(acc.grid(NAMES, 2, 3, 0.16, 0.5)) <= shell


def test_never_observed_is_255_and_bounds_hold_the_points():
    frames = []
    for T in POSES[:2]:
        d = box_depth(W, T, LO, HI)
        d[(ray_directions(W) @ T[:3, :3].T)[..., 2] < -0.85] = 0  # nothing steeper than 58 degrees down
        frames.append((d, T))
    acc = accumulate(frames)
    g = acc.grid(NAMES, 1, 1, 0.16, 0.0)
    below = point_to_index([0.0, 0.0, LO[2] + 0.01], H) - g.index0
    assert g.labels[tuple(below)] == 255
    above = point_to_index([0.0, 0.0, 0.5], H) - g.index0
    assert g.labels[tuple(above)] == 0
    assert acc.stats["unknown"] == int((g.labels == 255).sum()) > 0


def test_deterministic_and_max_range():
    a = accumulate(box_frames()).grid(NAMES, 2, 3, 0.16, 0.2)
    b = accumulate(box_frames()).grid(NAMES, 2, 3, 0.16, 0.2)
    assert np.array_equal(a.labels, b.labels) and np.array_equal(a.origin, b.origin)
    d, T = box_frames()[0]
    lo, hi = depth_bounds(d, T, max_range=1.0)
    assert np.all(hi - lo <= 2.0 + 1e-9)


@pytest.mark.parametrize("spec,n,expect", [("every:10", 25, [0, 10, 20]), ("all", 3, [0, 1, 2]), ("none", 3, []),
                                           ("4, 1,4", 5, [1, 4]), (" Every:1 ", 2, [0, 1])])
def test_parse_annotated(spec, n, expect):
    assert parse_annotated(spec, n) == expect


@pytest.mark.parametrize("spec", ["every:0", "every:x", "1,x", "7", "-1", ","])
def test_parse_annotated_refuses(spec):
    with pytest.raises(PanovoccError, match="--annotated"):
        parse_annotated(spec, 5)
