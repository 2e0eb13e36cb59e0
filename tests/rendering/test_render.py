"""Rendering: closed-form depth of a box room, labels, raycast vs pyrender, noise, the CLI end to end."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from panovocc_cli.datasets.scene import Scene, split_polygons
from panovocc_cli.geometry.erp import ray_directions
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.rendering.noise import degrade
from panovocc_cli.rendering.raycast import RaycastRenderer

LO = np.array([-2.0, -1.5, 0.0])
HI = np.array([3.0, 2.5, 2.6])
NAMES = ["unlabeled", "floor", "ceiling", "wall", "window", "table"]
EXE = str(Path(sys.executable).parent / "panovocc")


def _quad_scene(quads, classes):
    v = np.concatenate(quads)
    polys = np.arange(len(v)).reshape(-1, 4)
    tris = split_polygons(polys)
    cls = np.repeat(classes, 2)
    rng = np.random.default_rng(0)
    col = rng.integers(60, 250, size=v.shape).astype(np.uint8)
    return Scene(v, tris, cls, np.repeat(np.arange(len(quads)), 2), col, NAMES).validate()


def _box_room(with_table=False):
    (x0, y0, z0), (x1, y1, z1) = LO, HI
    q = [
        np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]]),  # floor, faces +z
        np.array([[x0, y0, z1], [x0, y1, z1], [x1, y1, z1], [x1, y0, z1]]),  # ceiling
        np.array([[x0, y0, z0], [x0, y0, z1], [x1, y0, z1], [x1, y0, z0]]),  # y0 wall
        np.array([[x0, y1, z0], [x1, y1, z0], [x1, y1, z1], [x0, y1, z1]]),  # y1 wall
        np.array([[x0, y0, z0], [x0, y1, z0], [x0, y1, z1], [x0, y0, z1]]),  # x0 wall
        np.array([[x1, y0, z0], [x1, y0, z1], [x1, y1, z1], [x1, y1, z0]]),  # x1 wall: glass
    ]
    cls = [1, 2, 3, 3, 3, 4]
    if with_table:
        a, b = np.array([1.0, -0.5, 0.0]), np.array([2.0, 0.3, 0.75])
        q += [np.array([[a[0], a[1], b[2]], [b[0], a[1], b[2]], [b[0], b[1], b[2]], [a[0], b[1], b[2]]]),
              np.array([[a[0], a[1], 0], [a[0], a[1], b[2]], [a[0], b[1], b[2]], [a[0], b[1], 0]]),
              np.array([[a[0], a[1], 0], [b[0], a[1], 0], [b[0], a[1], b[2]], [a[0], a[1], b[2]]])]
        cls += [5, 5, 5]
    return _quad_scene(q, np.array(cls))


def _closed_form_depth(T, W):
    d = ray_directions(W).reshape(-1, 3) @ T[:3, :3].T
    c = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (HI - c) / d, (LO - c) / d)
    return np.nanmin(np.where(np.isfinite(t) & (t > 0), t, np.inf), axis=1).reshape(W // 2, W)


def test_box_room_depth_is_closed_form_and_labels_are_right():
    W = 256
    T = look_at([0.4, 0.3, 1.3], [1.0, 0.3, 0.0])
    fr = RaycastRenderer(_box_room(), W).render(T)
    ref = _closed_form_depth(T, W)
    assert np.abs(fr.depth - ref).max() < 1e-3
    # after uint16 millimetre quantisation
    from panovocc_cli.io.images import depth_to_uint16

    assert np.abs(depth_to_uint16(fr.depth, 1000.0) / 1000.0 - ref).max() < 1e-3 + 5e-4
    assert (fr.labels[:10] == NAMES.index("ceiling")).all() and (fr.labels[-10:] == NAMES.index("floor")).all()
    mid = fr.labels[W // 4]
    assert set(np.unique(mid)) <= {3, 4} and (mid == 4).any()
    assert fr.rgb.std() > 5 and fr.rgb.dtype == np.uint8


@pytest.fixture(scope="module")
def both_backends():
    from panovocc_cli.rendering.pyrender_backend import PyrenderRenderer

    W = 256
    scene = _box_room(with_table=True)
    T = look_at([0.0, 0.5, 1.4], [1.0, -0.2, -0.1])
    a = RaycastRenderer(scene, W).render(T)
    pr = PyrenderRenderer(scene, W)
    b = pr.render(T)
    pr.close()
    return a, b


def test_pyrender_agrees_with_raycast(both_backends):
    from scipy import ndimage

    a, b = both_backends
    # edges: label changes or a depth jump of more than 5 % between neighbours, widened by a pixel
    jump = np.zeros(a.depth.shape, bool)
    for ax in (0, 1):
        step = np.abs(np.diff(a.depth, axis=ax)) > 0.05 * a.depth.take(range(a.depth.shape[ax] - 1), axis=ax)
        step |= np.diff(a.labels, axis=ax) != 0
        pad = [(0, 0), (0, 0)]
        pad[ax] = (0, 1)
        jump |= np.pad(step, pad)
    edge = ndimage.binary_dilation(jump, iterations=2)
    assert edge.mean() < 0.25
    m = ~edge & (a.depth > 0)
    diff = np.abs(a.depth - b.depth)[m]
    assert np.median(diff) < 0.015 and (diff < 0.05).mean() > 0.95
    assert (a.labels == b.labels)[m].mean() > 0.97
    assert b.rgb[m].mean() > 20


def test_noise_changes_depth_keeps_glass_empty_and_is_seeded():
    W = 256
    T = look_at([0.4, 0.3, 1.3], [1.0, 0.3, 0.0])
    fr = RaycastRenderer(_box_room(), W).render(T)
    inc = np.arccos(np.clip(fr.cos_incidence, 0, 1))
    glass = fr.labels == NAMES.index("window")
    d1, rgb1 = degrade(fr.depth, fr.rgb, inc, glass, seed=5, frame=0)
    d2, _ = degrade(fr.depth, fr.rgb, inc, glass, seed=5, frame=0)
    d3, _ = degrade(fr.depth, fr.rgb, inc, glass, seed=6, frame=0)
    assert np.array_equal(d1, d2) and not np.array_equal(d1, d3)
    assert (d1[glass] == 0).all() and glass.any()
    ok = (d1 > 0)
    assert 0.6 < ok.mean() < 0.99
    err = np.abs(d1 - fr.depth)[ok]
    assert 0.0005 < np.median(err) < 0.05
    # dropouts are more frequent toward the poles than at the horizon
    H = W // 2
    drop = (d1 == 0) & ~glass
    assert drop[: H // 8].mean() > drop[H // 2 - 8: H // 2 + 8].mean()


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("render")
    r = subprocess.run([EXE, "synth", str(root / "scene"), "--seed", "4", "--rooms", "2", "--frames", "6"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return root


@pytest.mark.slow
def test_render_cli_end_to_end(scene_dir):
    seq = scene_dir / "seq"
    r = subprocess.run([EXE, "render", str(scene_dir / "scene"), str(seq), "--width", "128", "--every", "2",
                        "--noise", "realistic", "--seed", "3"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    s = Sequence(seq)
    assert len(s) == 3 and s.meta.width == 128 and s.meta.height == 64
    assert s.meta.class_names[0] == "unlabeled" and "tv" in s.meta.class_names
    meta = json.loads((seq / "meta.json").read_text())
    assert meta["render"]["backend"] == "raycast" and meta["render"]["noise"] == "realistic"
    assert meta["render"]["seed"] == 3
    d, lab = s.depth(1), s.labels(1)
    assert d.shape == (64, 128) and (d > 0).mean() > 0.5 and lab.max() > 0
    win = s.meta.class_names.index("window")
    assert (d[lab == win] == 0).all()
    full = np.loadtxt(scene_dir / "scene" / "traj.txt").reshape(-1, 4, 4)
    assert np.allclose(s.poses, full[::2])
    assert list(scene_dir.glob(".seq*")) == []


@pytest.mark.parametrize("case", ["odd", "15", "nonrigid"])
def test_render_bad_input_exits_2_and_leaves_nothing(scene_dir, tmp_path, case):
    args = [EXE, "render", str(scene_dir / "scene"), str(tmp_path / "out"), "--width", "128"]
    if case == "odd":
        args[-1] = "127"
    else:
        traj = tmp_path / "traj.txt"
        T = np.eye(4)
        if case == "nonrigid":
            T[0, 0] = 2.0
        line = " ".join(str(x) for x in T.ravel()[: 15 if case == "15" else 16])
        traj.write_text(line + "\n")
        args += ["--traj", str(traj)]
    r = subprocess.run(args, capture_output=True, text=True)
    assert r.returncode == 2
    assert r.stderr.strip().startswith("error:") and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out*"))
