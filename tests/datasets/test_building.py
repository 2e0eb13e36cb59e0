"""``synth --building``: floors of furnished rooms off a corridor, a dog-leg staircase, one walk through every room.

The default building is generated once (module fixture, about half a minute) and checked against the mesh
itself with Open3D's ray casting: clearance of every pose, every step of the walk free of geometry (so the
doors it goes through are open and the stairs are climbed, not flown through), the camera's height above the
surface under it, the steps' rises. A small building checks determinism and the command line.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from panovocc_cli.classes import EVAL8, OPEN4, canonical_name
from panovocc_cli.datasets.building import BUILDING_AREA, BUILDING_FLOORS, RISE_MAX, generate_building
from panovocc_cli.datasets.scene import split_polygons
from panovocc_cli.datasets.trajectory import CAM_Z, CLEARANCE, MAX_TILT_DEG
from panovocc_cli.errors import PanovoccError
from cli_helpers import run_cli

SEED = 1


@pytest.fixture(scope="module")
def building():
    return generate_building(SEED)


def _raycaster(building):
    """Open3D ray casting on the building's mesh, and the class name of each triangle."""
    import open3d as o3d

    rs = o3d.t.geometry.RaycastingScene()
    faces = split_polygons(building["quads"])  # quad k -> triangles 2k, 2k + 1
    rs.add_triangles(o3d.core.Tensor(building["vertices"].astype(np.float32)),
                     o3d.core.Tensor(faces.astype(np.uint32)))
    names = np.array([canonical_name(c) for c in building["object_classes"]])
    return rs, names[np.repeat(building["face_object"], 2)]


@pytest.fixture(scope="module")
def raycaster(building):
    return _raycaster(building)


def _cast(rs, origins, dirs):
    import open3d as o3d

    rays = np.concatenate([origins, dirs], 1).astype(np.float32)
    a = rs.cast_rays(o3d.core.Tensor(rays))
    return a["t_hit"].numpy(), a["primitive_ids"].numpy()


def _floor_of(building, z):
    """Index of the storey each height ``z`` (world metres) lies in."""
    h = building["floor_heights"]
    return np.clip(np.searchsorted(h, z, side="right") - 1, 0, len(h) - 1)


def test_default_building_size(building):
    """At least 2,500 m² of floor on several floors, and at least 5,000 poses, as issue 21 asks."""
    floors = len(building["floor_heights"])
    assert floors == BUILDING_FLOORS >= 2
    assert building["floor_area"] >= BUILDING_AREA >= 2500.0
    assert len(building["T_world_cam"]) >= 5000
    # the plan's area is the mesh's: upward floor and rug faces at the floors' heights add up to it
    v = building["vertices"]
    q = building["quads"]
    names = np.array([canonical_name(c) for c in building["object_classes"]])[building["face_object"]]
    a, b, c = v[q[:, 0]], v[q[:, 1]], v[q[:, 2]]
    n = np.cross(b - a, c - a)  # quads are planar rectangles: |n| is the area
    up = (n[:, 2] > 0) & np.isin(names, ["floor", "rug"])
    z = a[:, 2]
    on_floor = np.abs(z[:, None] - building["floor_heights"][None]).min(1) < 0.011  # rugs are 1 cm thick
    area = np.linalg.norm(n[up & on_floor], axis=1).sum()
    assert area >= 0.99 * building["floor_area"], area
    assert {canonical_name(c) for c in building["object_classes"]} >= set(EVAL8) | set(OPEN4) | {"stair",
                                                                                                   "handrail"}


def test_walk_visits_every_room_of_every_floor(building):
    T = building["T_world_cam"]
    x, y, z = T[:, 0, 3], T[:, 1, 3], T[:, 2, 3]
    level = _floor_of(building, z)
    kinds = building["room_kinds"]
    assert kinds.count("stair") == kinds.count("corridor") == len(building["floor_heights"])
    for (x0, x1, y0, y1), f, kind in zip(building["rooms"], building["room_floors"], kinds):
        if kind == "stair":  # the shaft is entered on its landing
            x1 = building["landing_edge"]
        inside = (x > x0) & (x < x1) & (y > y0) & (y < y1) & (level == f)
        assert inside.any(), (kind, f, (x0, x1, y0, y1))


def test_walk_climbs_the_stairs_floor_by_floor(building, raycaster):
    """The walk goes up one storey at a time, on the stairs: the camera's height above the surface under it
    stays the usual one (so it rises with the steps), and that surface is a step or a landing."""
    rs, cls = raycaster
    T = building["T_world_cam"]
    P = T[:, :3, 3]
    level = _floor_of(building, P[:, 2] - CAM_Z[0])
    assert level[0] == 0 and level[-1] == len(building["floor_heights"]) - 1
    assert np.all(np.diff(level) >= 0)  # never down a floor
    t, prim = _cast(rs, P, np.tile([0.0, 0.0, -1.0], (len(P), 1)))
    below = cls[prim]
    r = building["rise"]
    assert t.min() >= CAM_Z[0] - r / 2 - 1e-3 and t.max() <= CAM_Z[1] + r / 2 + 1e-3  # walking line: mid-tread
    assert set(below) <= {"floor", "rug", "stair"}
    on_stairs = below == "stair"
    stair_levels = level[on_stairs]
    for f in range(len(building["floor_heights"]) - 1):
        assert (stair_levels == f).sum() >= 20  # the two flights take dozens of poses, not a jump
    # between two floors' parts the walk is on the stairs only
    for f in range(1, len(building["floor_heights"])):
        last, first = np.nonzero(level == f - 1)[0][-1], np.nonzero(level == f)[0][0]
        assert on_stairs[last - 5:first + 5].mean() > 0.5


def test_stairs_are_steps(building, raycaster):
    """Every storey's stair is made of equal risers of at most 18 cm, treads by Blondel's rule."""
    v, q = building["vertices"], building["quads"]
    names = np.array(building["object_classes"])[building["face_object"]]
    a, b, c = v[q[:, 0]], v[q[:, 1]], v[q[:, 2]]
    n = np.cross(b - a, c - a)
    flat = (names == "stair") & (n[:, 2] > 0) & (np.abs(n[:, :2]).max(1) < 1e-9)
    H = building["storey"]
    rise = building["rise"]
    assert rise <= RISE_MAX and abs(2 * rise + building["tread"] - 0.63) < 1e-9
    for z0 in building["floor_heights"][:-1]:
        heights = np.unique(np.round(a[flat, 2][(a[flat, 2] > z0) & (a[flat, 2] < z0 + H)] - z0, 6))
        assert len(heights) == building["risers"] - 1  # treads and the half landing, one per riser
        assert np.allclose(np.diff(np.concatenate([[0.0], heights, [H]])), rise)


def test_no_pose_in_or_through_geometry(building, raycaster):
    """Clearance of every pose from walls, furniture, stairs; every step of the walk (consecutive poses) in
    free space, so doors it uses are passable and no wall is crossed."""
    _assert_walk_clear(raycaster[0], building["T_world_cam"][:, :3, 3])


def _assert_walk_clear(rs, P):
    """Every position of P (n, 3) at least the trajectory's clearance from the mesh, every step between two
    consecutive ones free of it."""
    import open3d as o3d

    d = rs.compute_distance(o3d.core.Tensor(P.astype(np.float32))).numpy()
    assert d.min() >= CLEARANCE - 0.01
    step = np.diff(P, axis=0)
    L = np.linalg.norm(step, axis=1)
    t, _ = _cast(rs, P[:-1], step / L[:, None])
    assert np.all(t > L)


def test_camera_motion_is_the_house_s(building):
    """Step length and turning comparable to the house's walk (0.20-0.23 m a pose), tilt within bounds."""
    T = building["T_world_cam"]
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    assert 0.18 <= np.median(steps) <= 0.23 and steps.max() < 1.5 * np.median(steps)
    pitch, roll = np.degrees(np.arcsin(T[:, 2, 2])), np.degrees(np.arcsin(T[:, 2, 0]))
    assert np.abs(pitch).max() <= MAX_TILT_DEG and np.abs(roll).max() <= MAX_TILT_DEG
    yaw = np.unwrap(np.arctan2(T[:, 1, 2], T[:, 0, 2]))
    assert np.median(np.degrees(np.abs(np.diff(yaw)))) < 10.0


def _small(tmp_path, capsys, name, *extra):
    code, out, err = run_cli(capsys, ["synth", tmp_path / name, "--building", "--floors", "2", "--rooms", "3",
                                      "--frames", "40", *extra])
    assert code == 0, err
    return out


def test_same_seed_same_bytes_other_seed_other_building(tmp_path, capsys):
    out = _small(tmp_path, capsys, "a", "--seed", "4")
    assert "rooms on 2 floors" in out and "40 poses" in out
    _small(tmp_path, capsys, "b", "--seed", "4")
    _small(tmp_path, capsys, "c", "--seed", "5")
    files = ("habitat/mesh_semantic.ply", "habitat/info_semantic.json", "traj.txt")
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    assert (tmp_path / "a" / files[0]).read_bytes() != (tmp_path / "c" / files[0]).read_bytes()
    assert (tmp_path / "a" / files[2]).read_bytes() != (tmp_path / "c" / files[2]).read_bytes()
    cfg = json.loads((tmp_path / "a" / "config.json").read_text())
    assert cfg["building"] is True and cfg["floors"] == 2 and cfg["rooms"] == 3 and cfg["frames"] == 40


def test_building_options_refused(tmp_path, capsys):
    for args, msg in ((["--building", "--house"], "--house and --building"), (["--floors", "3"], "--floors only"),
                      (["--building", "--rooms", "1"], "--rooms with --building"), (["--building", "--floors", "9"],
                                                                                   "--floors")):
        code, _, err = run_cli(capsys, ["synth", tmp_path / "x", *args])
        assert code == 2 and msg in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "x").exists()
    with pytest.raises(PanovoccError, match="--floors"):
        generate_building(0, floors=1)


@pytest.mark.slow
def test_building_end_to_end_gt_render_map_eval(tmp_path, capsys):
    """A two-floor building is a scene like any other: ground truth, rendering, mapping and scoring work on it,
    and the map holds both floors and the stairs between them."""
    from panovocc_cli.io.grid import read_grid

    _small(tmp_path, capsys, "scene", "--seed", "2")
    code, _, err = run_cli(capsys, ["gt", tmp_path / "scene", tmp_path / "gt.npz", "--quiet"])
    assert code == 0, err
    gt = read_grid(tmp_path / "gt.npz")
    assert "stair" in gt.class_names and "handrail" in gt.class_names
    assert gt.labels.shape[2] * gt.voxel_size > 2 * 2.5  # two storeys
    from panovocc_cli.evaluation.show import floor_layers, floor_plans_figure
    from panovocc_cli.io.poses import read_poses

    assert len(floor_layers(gt)) == 2  # the floor plans find both floors
    fig = floor_plans_figure(gt, read_poses(tmp_path / "scene" / "traj.txt"), width_px=600)
    titles = [ax.get_title(loc="left") for ax in fig.axes if ax.get_title(loc="left")]
    assert len(titles) == 2 and all("frames -" not in t for t in titles)  # the walk is on both
    code, _, err = run_cli(capsys, ["render", tmp_path / "scene", tmp_path / "seq", "--width", "128"])
    assert code == 0, err
    code, _, err = run_cli(capsys, ["map", tmp_path / "seq", tmp_path / "map", "--quiet"])
    assert code == 0, err
    code, out, err = run_cli(capsys, ["eval", tmp_path / "map" / "prediction.npz", tmp_path / "gt.npz", "--json"])
    assert code == 0, err
    res = json.loads(out)
    assert res["iou"] > 20.0, res["iou"]  # percent
    pred = read_grid(tmp_path / "map" / "prediction.npz")
    zs = np.nonzero(((pred.labels > 0) & (pred.labels < 255)).any(axis=(0, 1)))[0]
    assert (zs.max() - zs.min()) * pred.voxel_size > 2.5  # occupied voxels on both floors
    assert os.path.isfile(tmp_path / "seq" / "depth" / "000039.png")


@pytest.fixture(scope="module")
def descending():
    """A small two-floor building whose walk comes back down (``descend``), and the same without it."""
    return generate_building(3, floors=2, rooms=2, descend=True), generate_building(3, floors=2, rooms=2)


def test_descend_walks_back_down_to_the_entrance(descending):
    """``descend``: the same building; the walk goes up floor by floor, then down every flight on the stairs,
    ending on the ground floor where it began (the entrance), clear of geometry at every pose and step."""
    b, up_only = descending
    for k in ("vertices", "quads", "face_object", "object_classes"):
        assert np.array_equal(np.asarray(b[k]), np.asarray(up_only[k])), k
    rs, names = _raycaster(b)
    T = b["T_world_cam"]
    P = T[:, :3, 3]
    level = _floor_of(b, P[:, 2] - CAM_Z[0])
    top = int(np.argmax(level))
    assert level[top] == 1 and np.all(np.diff(level[: top + 1]) >= 0) and np.all(np.diff(level[top:]) <= 0)
    assert level[-1] == 0 and np.linalg.norm(P[-1, :2] - P[0, :2]) < 0.3  # back at the entrance
    assert len(T) > len(up_only["T_world_cam"])
    t, prim = _cast(rs, P, np.tile([0.0, 0.0, -1.0], (len(P), 1)))
    on_stairs = names[prim] == "stair"
    down = np.nonzero(np.diff(level) < 0)[0][0]  # the last pose on the upper floor before the walk goes down
    assert on_stairs[down + 1:down + 11].all() and on_stairs[top:].sum() >= 20  # down the flights
    _assert_walk_clear(rs, P)


def test_descend_needs_building(tmp_path, capsys):
    code, _, err = run_cli(capsys, ["synth", tmp_path / "x", "--descend"])
    assert code == 2 and "--descend only applies with --building" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
