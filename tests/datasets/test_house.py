"""``synth --house``: six to eight furnished rooms off a corridor, a long trajectory through every one of them."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from panovocc_cli.classes import EVAL8, OPEN4, canonical_name
from panovocc_cli.datasets.house import HOUSE_ROOMS, generate_house
from panovocc_cli.datasets.layout import WALL_T
from panovocc_cli.datasets.trajectory import CAM_Z, CLEARANCE, MAX_TILT_DEG
from panovocc_cli.errors import PanovoccError

SEED, FRAMES = 2, 80


@pytest.fixture(scope="module")
def house():
    return generate_house(SEED, frames=FRAMES)


def test_house_layout_rooms_corridor_and_furniture(house):
    rooms = house["rooms"]
    assert house["room_kinds"][0] == "corridor" and HOUSE_ROOMS[0] <= len(rooms) - 1 <= HOUSE_ROOMS[1]
    kinds = house["room_kinds"][1:]
    assert {"living", "dining", "bedroom", "office"} <= set(kinds) and kinds.count("bedroom") >= 2
    cx0, cx1, cy0, cy1 = rooms[0]
    for x0, x1, y0, y1 in rooms[1:]:  # every room lies along the corridor, one wall between them
        assert np.isclose(y1 + WALL_T, cy0) or np.isclose(y0 - WALL_T, cy1)
        assert cx0 - 1e-9 <= x0 < x1 <= cx1 + 1e-9
    names = {canonical_name(c) for c in house["object_classes"]}
    assert set(EVAL8) | set(OPEN4) <= names
    assert {"pillow", "cabinet", "nightstand", "plant", "shelf", "book", "rug", "cushion"} <= names


def test_house_trajectory_visits_every_room_within_limits(house):
    import open3d as o3d

    from panovocc_cli.datasets.scene import split_polygons

    T = house["T_world_cam"]
    assert T.shape == (FRAMES, 4, 4)
    z = T[:, 2, 3] - house["floor_z"]
    assert z.min() >= CAM_Z[0] and z.max() <= CAM_Z[1]
    pitch, roll = np.degrees(np.arcsin(T[:, 2, 2])), np.degrees(np.arcsin(T[:, 2, 0]))
    assert np.abs(pitch).max() <= MAX_TILT_DEG and np.abs(roll).max() <= MAX_TILT_DEG
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    assert steps.sum() > 40.0 and steps.max() < 3 * np.median(steps)  # long, evenly spaced
    for x0, x1, y0, y1 in house["rooms"]:
        assert ((T[:, 0, 3] > x0) & (T[:, 0, 3] < x1) & (T[:, 1, 3] > y0) & (T[:, 1, 3] < y1)).any()
    rs = o3d.t.geometry.RaycastingScene()
    faces = split_polygons(house["quads"])
    rs.add_triangles(o3d.core.Tensor(house["vertices"].astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    d = rs.compute_distance(o3d.core.Tensor(T[:, :3, 3].astype(np.float32))).numpy()
    assert d.min() >= CLEARANCE - 0.01


def test_synth_house_command_writes_the_same_house(house, tmp_path, capsys):
    import json

    from panovocc_cli.cli import main
    from panovocc_cli.io.poses import read_poses

    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["synth", "--house", "--seed", str(SEED), "--frames", str(FRAMES), os.fspath(tmp_path / "h")])
    out = capsys.readouterr().out
    assert e.value.code in (0, None) and f"{len(house['rooms']) - 1} rooms and a corridor" in out
    assert np.array_equal(read_poses(tmp_path / "h" / "traj.txt"), house["T_world_cam"])
    cfg = json.loads((tmp_path / "h" / "config.json").read_text())
    assert cfg["house"] is True and cfg["frames"] == FRAMES


def test_house_bad_rooms():
    with pytest.raises(PanovoccError, match="--rooms with --house"):
        generate_house(0, rooms=5)
