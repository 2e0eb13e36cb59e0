"""Replica loader (hand-written binary PLY), PLY round trips, procedural scenes and their trajectories."""

import json
import struct

import numpy as np
import pytest

from panovocc_cli.classes import EVAL8, OPEN4
from panovocc_cli.io.ply import read_ply
from panovocc_cli.datasets.replica import read_replica_scene, write_replica_scene
from panovocc_cli.datasets.home import generate_scene
from panovocc_cli.datasets.synth import SynthConfig, run_synth
from panovocc_cli.datasets.trajectory import CAM_Z, CLEARANCE, MAX_TILT_DEG
from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.poses import read_poses


def _replica_ply(path, with_object_id=True):
    """Two quads written byte by byte exactly as Replica's mesh_semantic.ply lays them out."""
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1)]
    quads = [((0, 1, 2, 3), 7), ((0, 1, 5, 4), 3)]
    head = ["ply", "format binary_little_endian 1.0", "comment made by hand", f"element vertex {len(verts)}"]
    head += [f"property float {k}" for k in ("x", "y", "z", "nx", "ny", "nz")]
    head += [f"property uchar {k}" for k in ("red", "green", "blue")]
    head += [f"element face {len(quads)}", "property list uchar int vertex_indices"]
    if with_object_id:
        head.append("property int object_id")
    head.append("end_header")
    body = b""
    for k, v in enumerate(verts):
        body += struct.pack("<6f3B", *v, 0.0, 0.0, 1.0, 10 * k, 20, 30)
    for idx, obj in quads:
        body += struct.pack("<B4i", 4, *idx) + (struct.pack("<i", obj) if with_object_id else b"")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(("\n".join(head) + "\n").encode() + body)


def _info(path):
    info = {"classes": [{"id": 1, "name": "floor"}, {"id": 5, "name": "tv-screen"}, {"id": 9, "name": "lamp"}],
            "objects": [{"id": 3, "class_id": 9, "class_name": "lamp"}],
            "id_to_label": [0, 0, 0, 9, 0, 0, 0, 5]}
    path.write_text(json.dumps(info))


def test_replica_loader_reads_real_layout_and_maps_classes(tmp_path):
    _replica_ply(tmp_path / "room" / "habitat" / "mesh_semantic.ply")
    _info(tmp_path / "room" / "habitat" / "info_semantic.json")
    s = read_replica_scene(tmp_path / "room")
    assert s.class_names == ["unlabeled", "floor", "tv", "lighting"]
    assert s.faces.shape == (4, 3) and s.faces.dtype == np.int32
    assert s.face_object.tolist() == [7, 7, 3, 3]
    assert [s.class_names[c] for c in s.face_class] == ["tv", "tv", "lighting", "lighting"]
    assert s.vertex_colors[3].tolist() == [30, 20, 30]
    assert np.allclose(s.triangle_areas().sum(), 2.0)
    # quads split keeping the winding: the floor quad faces +z
    p = s.vertices[s.faces[0]]
    assert np.cross(p[1] - p[0], p[2] - p[0])[2] > 0


def test_replica_without_object_id_is_an_error(tmp_path):
    _replica_ply(tmp_path / "room" / "habitat" / "mesh_semantic.ply", with_object_id=False)
    _info(tmp_path / "room" / "habitat" / "info_semantic.json")
    with pytest.raises(PanovoccError, match="mesh_semantic.ply.*object_id"):
        read_replica_scene(tmp_path / "room")


def test_replica_write_read_roundtrip_with_mixed_polygons(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    write_replica_scene(tmp_path / "s", v, np.array([[0, 1, 2, 3]]), np.array([0]), np.full((4, 3), 9, np.uint8),
                        ["tv-screen"])
    s = read_replica_scene(tmp_path / "s")
    assert s.class_names == ["unlabeled", "tv"] and s.face_class.tolist() == [1, 1]
    # a PLY with a triangle and a quad (variable list lengths) and the 'vertex_index' spelling
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nelement face 2\nproperty list uchar int vertex_index\nproperty int object_id\nend_header\n")
    body = b"".join(struct.pack("<3f", *p) for p in v)
    body += struct.pack("<B3ii", 3, 0, 1, 2, 4) + struct.pack("<B4ii", 4, 0, 1, 2, 3, 5)
    (tmp_path / "m.ply").write_bytes(head.encode() + body)
    m = read_ply(tmp_path / "m.ply")
    assert [f.shape for f in m.faces] == [(1, 3), (1, 4)] and m.face["object_id"].tolist() == [4, 5]


def test_nice_slam_trajectory_read(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    (tmp_path / "traj.txt").write_text(" ".join(f"{x:.6e}" for x in T.ravel()) + "\n" +
                                       " ".join(f"{x:.6e}" for x in T.ravel()) + "\n")
    P = read_poses(tmp_path / "traj.txt")
    assert P.shape == (2, 4, 4) and np.allclose(P[1, :3, 3], [1, 2, 3])


@pytest.fixture(scope="module")
def synth_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    run_synth(SynthConfig(out=root / "a", seed=3, frames=40))
    run_synth(SynthConfig(out=root / "b", seed=3, frames=40))
    return root


def test_synth_has_every_benchmark_class_and_is_deterministic(synth_scene):
    a, b = synth_scene / "a", synth_scene / "b"
    assert (a / "habitat/mesh_semantic.ply").read_bytes() == (b / "habitat/mesh_semantic.ply").read_bytes()
    assert (a / "traj.txt").read_bytes() == (b / "traj.txt").read_bytes()
    s = read_replica_scene(a)
    present = {s.class_names[c] for c in s.class_ids_present()}
    assert set(EVAL8) | set(OPEN4) <= present
    assert {"pillow", "cabinet", "plant"} <= present
    # colour varies within an object (texture-like), not one flat colour per object
    wall = s.class_names.index("wall")
    cols = s.vertex_colors[s.faces[s.face_class == wall]].reshape(-1, 3)
    assert len(np.unique(cols, axis=0)) > 20


def test_synth_trajectory_limits_and_clearance(synth_scene):
    import open3d as o3d

    lines = (synth_scene / "a" / "traj.txt").read_text().splitlines()
    assert len(lines) == 40 and all(len(l.split()) == 16 for l in lines)
    T = read_poses(synth_scene / "a" / "traj.txt")
    floor = read_replica_scene(synth_scene / "a").vertices[:, 2].min()  # the home is moved by a seeded offset
    assert 0.0 <= floor < 1.0
    z = T[:, 2, 3] - floor
    assert z.min() >= CAM_Z[0] and z.max() <= CAM_Z[1]
    pitch = np.degrees(np.arcsin(T[:, 2, 2]))  # camera z (forward) above the horizon
    roll = np.degrees(np.arcsin(T[:, 2, 0]))  # camera x (right) off the horizon
    assert np.abs(pitch).max() <= MAX_TILT_DEG and np.abs(roll).max() <= MAX_TILT_DEG
    steps = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 3 * np.median(steps)  # smooth, evenly spaced
    s = read_replica_scene(synth_scene / "a")
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(s.vertices.astype(np.float32)), o3d.core.Tensor(s.faces.astype(np.uint32)))
    d = rs.compute_distance(o3d.core.Tensor(T[:, :3, 3].astype(np.float32))).numpy()
    assert d.min() >= CLEARANCE - 0.01
    # every room is visited: rooms from the generator (same seed)
    g = generate_scene(3, frames=40)
    for x0, x1, y0, y1 in g["rooms"]:
        inside = (T[:, 0, 3] > x0) & (T[:, 0, 3] < x1) & (T[:, 1, 3] > y0) & (T[:, 1, 3] < y1)
        assert inside.any()
    assert np.array_equal(g["T_world_cam"], T)


@pytest.mark.parametrize("rooms", [1, 4])
def test_synth_room_counts(rooms):
    g = generate_scene(seed=1, rooms=rooms, frames=20)
    assert len(g["rooms"]) == rooms and g["T_world_cam"].shape == (20, 4, 4)


def test_synth_offset_is_uniform_in_millimetres_ties_included():
    from panovocc_cli.datasets.layout import lattice_offset

    off = np.array([lattice_offset(s) for s in range(4000)])  # (4000, 3) metres
    mm = np.round(off * 1000.0)
    assert np.allclose(off * 1000.0, mm) and mm.min() >= 0 and mm.max() <= 999
    k = (mm % 80).astype(int)  # millimetres above a face of the 8 cm lattice
    assert (k == 0).mean() > 0.5 / 80  # exact ties are drawn (1 in 80 expected): no clearance rule
    near = np.minimum(k, 80 - k) <= 3  # within 3 mm of a face
    assert 0.06 < near.mean() < 0.12  # 7 / 80 = 8.75 % expected
    counts = np.bincount(k.ravel(), minlength=80)
    assert counts.min() > 0.6 * counts.mean() and counts.max() < 1.4 * counts.mean()


def test_synth_explicit_offset_moves_the_same_home():
    a = generate_scene(seed=1, rooms=1, frames=20, offset=(0.0, 0.0, 0.0))
    b = generate_scene(seed=1, rooms=1, frames=20, offset=(0.25, -0.5, 0.002))
    assert a["floor_z"] == 0.0 and b["floor_z"] == 0.002
    np.testing.assert_allclose(b["vertices"] - a["vertices"], np.broadcast_to([0.25, -0.5, 0.002], a["vertices"].shape),
                               atol=1e-12)
    np.testing.assert_allclose(b["T_world_cam"][:, :3, 3] - a["T_world_cam"][:, :3, 3],
                               np.broadcast_to([0.25, -0.5, 0.002], (20, 3)), atol=1e-12)
    assert np.array_equal(a["quads"], b["quads"])


@pytest.mark.parametrize("text", ["1,2", "a,b,c", "0,0,nan", "1,2,3,4"])
def test_synth_bad_offset(text):
    from panovocc_cli.datasets.synth import parse_offset

    with pytest.raises(PanovoccError, match="--offset"):
        parse_offset(text)
    assert parse_offset("0.1, -2,3e-3") == (0.1, -2.0, 0.003)


def test_synth_bad_rooms():
    with pytest.raises(PanovoccError, match="rooms"):
        generate_scene(seed=0, rooms=9)
