"""Mesh ground truth: exact occupied voxels of known meshes, lattice alignment, the area vote."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from panovocc_cli.datasets.scene import Scene, split_polygons
from panovocc_cli.geometry.lattice import origin_to_index
from panovocc_cli.gt import voxelize_scene
from panovocc_cli.io.grid import read_grid

H = 0.08


def _box_quads(lo, hi, omit=()):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    c = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    faces = {"-z": [0, 3, 2, 1], "+z": [4, 5, 6, 7], "-y": [0, 1, 5, 4], "+y": [2, 3, 7, 6],
             "-x": [0, 4, 7, 3], "+x": [1, 2, 6, 5]}
    return [c[f] for k, f in faces.items() if k not in omit]


def _scene(parts, names=("unlabeled", "wall", "rug", "chair")):
    """parts: list of (quads list, class id)."""
    verts, faces, cls = [], [], []
    for quads, c in parts:
        for q in quads:
            base = len(verts) * 4
            verts.append(q)
            f = split_polygons(np.array([[base, base + 1, base + 2, base + 3]]))
            faces.append(f)
            cls += [c] * len(f)
    v = np.concatenate(verts)
    return Scene(v, np.concatenate(faces), np.array(cls), np.zeros(len(cls)), np.full(v.shape, 128, np.uint8),
                 list(names)).validate()


def _occupied(grid):
    ijk = np.argwhere((grid.labels > 0) & (grid.labels < 255)) + grid.index0
    return {tuple(x) for x in ijk.tolist()}


def test_box_surface_gives_exact_shell():
    g = voxelize_scene(_scene([(_box_quads((0.02, 0.02, 0.02), (0.46, 0.38, 0.30)), 1)]), H)
    expect = {(i, j, k) for i in range(6) for j in range(5) for k in range(4)
              if i in (0, 5) or j in (0, 4) or k in (0, 3)}
    assert _occupied(g) == expect and len(expect) == 96
    assert set(np.unique(g.labels)) == {0, 1}
    # lattice alignment: origin is a voxel centre of the global lattice
    assert np.allclose(g.origin / H - 0.5, np.round(g.origin / H - 0.5))
    assert origin_to_index(g.origin, H).tolist() == [0, 0, 0] and g.class_names == ["empty", "wall", "rug", "chair"]


def test_thin_slab_and_thin_leg_do_not_vanish():
    rug = _box_quads((0.10, 0.10, 0.03), (0.50, 0.30, 0.04), omit=("-z",))
    leg = _box_quads((0.17, 0.97, 0.0), (0.19, 0.99, 0.70), omit=("-z", "+z"))
    g = voxelize_scene(_scene([(rug, 2), (leg, 3)]), H)
    occ = _occupied(g)
    assert {v for v in occ if v[1] < 5} == {(i, j, 0) for i in range(1, 7) for j in range(1, 4)}
    assert {v for v in occ if v[1] >= 5} == {(2, 12, k) for k in range(9)}
    lab = {tuple(x): g.labels[tuple(x - g.index0)] for x in np.array(sorted(occ))}
    assert lab[(3, 2, 0)] == 2 and lab[(2, 12, 4)] == 3


def test_surface_on_a_voxel_face_belongs_to_the_voxel_above():
    floor = [np.array([[-0.3, -0.3, 0.0], [0.3, -0.3, 0.0], [0.3, 0.3, 0.0], [-0.3, 0.3, 0.0]])]
    g = voxelize_scene(_scene([(floor, 1)]), H)
    ks = {v[2] for v in _occupied(g)}
    assert ks == {0}
    ij = {(v[0], v[1]) for v in _occupied(g)}
    assert ij == {(i, j) for i in range(-4, 4) for j in range(-4, 4)}


def test_area_vote_picks_the_larger_surface():
    # In voxel (0,0,0): a wall patch of 0.06 x 0.06 (class 1) and a chair patch of 0.06 x 0.03 (class 3).
    wall = [np.array([[0.01, 0.02, 0.01], [0.07, 0.02, 0.01], [0.07, 0.02, 0.07], [0.01, 0.02, 0.07]])]
    chair = [np.array([[0.01, 0.05, 0.01], [0.07, 0.05, 0.01], [0.07, 0.05, 0.04], [0.01, 0.05, 0.04]])]
    g = voxelize_scene(_scene([(wall, 1), (chair, 3)]), H)
    assert g.labels.shape == (1, 1, 1) and g.labels[0, 0, 0] == 1
    chair_big = [np.array([[0.01, 0.05, 0.01], [0.07, 0.05, 0.01], [0.07, 0.05, 0.075], [0.01, 0.05, 0.075]])]
    g = voxelize_scene(_scene([(wall, 1), (chair_big, 3)]), H)
    assert g.labels[0, 0, 0] == 3
    # surface with no class only wins an otherwise empty voxel, and then as 254
    g = voxelize_scene(_scene([(wall, 0)]), H)
    assert g.labels[0, 0, 0] == 254


@pytest.mark.slow
def test_gt_cli_end_to_end(tmp_path):
    exe = str(Path(sys.executable).parent / "panovocc")
    r = subprocess.run([exe, "synth", str(tmp_path / "s"), "--seed", "2", "--rooms", "1", "--frames", "5"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([exe, "gt", str(tmp_path / "s"), str(tmp_path / "gt.npz"), "--voxel-size", "0.1"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    g = read_grid(tmp_path / "gt.npz")
    assert g.voxel_size == 0.1 and g.class_names[0] == "empty" and "tv" in g.class_names
    names = {g.class_names[i] for i in np.unique(g.labels) if 0 < i < 254}
    assert {"floor", "wall", "ceiling", "window", "chair", "bed", "sofa", "table", "door", "tv"} <= names
    (tmp_path / "bad").mkdir()
    r = subprocess.run([exe, "gt", str(tmp_path / "bad"), str(tmp_path / "g2.npz")], capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and not (tmp_path / "g2.npz").exists()
