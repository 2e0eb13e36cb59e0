"""Stanford 2D-3D-S: a small area written here in the dataset's own layout (file names, 1/512 m depth with
65535 missing, 24-bit semantic indices into semantic_labels.json, pose JSON), read into a sequence; the
pose-convention check telling the right reading from the wrong ones; the ground truth of S3DIS annotation
files; one line with exit 2 for missing files."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from box_room import box_depth  # noqa: E402
from cli_helpers import run_cli, snapshot  # noqa: E402

from panovocc_cli.geometry.poses import look_at  # noqa: E402
from panovocc_cli.io.grid import read_grid  # noqa: E402
from panovocc_cli.io.s2d3ds import pano_pose, read_semantic_labels  # noqa: E402
from panovocc_cli.io.sequence import Sequence  # noqa: E402

W = 128
LO, HI = np.array([-2.3, -1.6, -1.4]), np.array([2.9, 2.1, 1.3])
LABELS = ["<UNK>_0_<UNK>_0_0", "wall_1_office_1_1", "chair_3_office_1_1", "ceiling_1_office_1_1",
          "beam_2_hallway_2_1", "stairs_1_hallway_2_1"]
PANOS = [("aa01", "office_1", (0.0, 0.0, 0.0, 0.0)), ("aa02", "office_1", (0.7, 0.4, 0.1, 0.9)),
         ("aa03", "office_1", (1.3, -0.3, -0.1, 1.9)), ("bb01", "hallway_2", (-0.8, 0.5, 0.2, -2.1)),
         ("bb02", "hallway_2", (-1.2, -0.2, 0.0, 2.8))]


def pose_of(x, y, z, yaw):
    return look_at([x, y, z], [np.cos(yaw), np.sin(yaw), 0.05])


def name(uuid, room, modality, ext="png"):
    return f"camera_{uuid}_{room}_frame_equirectangular_domain_{modality}.{ext}"


def index_image(idx: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB of label indices, the dataset's utils.get_color: R the most significant byte."""
    idx = np.asarray(idx, np.int64)
    return np.stack([(idx >> 16) & 255, (idx >> 8) & 255, idx & 255], axis=2).astype(np.uint8)


def write_area(root: Path, euler_ok: bool = True) -> Path:
    from scipy.spatial.transform import Rotation

    from panovocc_cli.io.images import write_png

    area = root / "area_1"
    for m in ("rgb", "depth", "semantic", "pose"):
        (area / "pano" / m).mkdir(parents=True, exist_ok=True)
    (root / "assets").mkdir(exist_ok=True)
    (root / "assets" / "semantic_labels.json").write_text(json.dumps(LABELS))
    rng = np.random.default_rng(1)
    for uuid, room, p in PANOS:
        T = pose_of(*p)
        d = box_depth(W, T, LO, HI)
        raw = np.rint(d * 512).astype(np.uint16)
        raw[3, 5:9] = 65535  # missing
        write_png(area / "pano" / "depth" / name(uuid, room, "depth"), raw)
        write_png(area / "pano" / "rgb" / name(uuid, room, "rgb"), rng.integers(0, 255, (W // 2, W, 3), dtype=np.uint8))
        idx = np.full((W // 2, W), 1)
        idx[: W // 8] = 3  # ceiling
        idx[-W // 8:] = 2  # chair
        idx[10, :4] = 4  # beam
        idx[11, :4] = 5  # stairs: a class outside the 13
        idx[12, :4] = 0x0D0D0D  # missing
        idx[13, :4] = 0  # <UNK>
        write_png(area / "pano" / "semantic" / name(uuid, room, "semantic"), index_image(idx))
        M = np.linalg.inv(T)
        R_euler = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])
        euler = Rotation.from_matrix(R_euler).as_euler("xyz") if euler_ok else rng.uniform(-3, 3, 3)
        (area / "pano" / "pose" / name(uuid, room, "pose", "json")).write_text(json.dumps({
            "camera_rt_matrix": M[:3].tolist(), "camera_location": T[:3, 3].tolist(),
            "final_camera_rotation": list(euler), "camera_k_matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
            "room": f"{room}_1", "field_of_view_rads": 1.5708}))
    return area


@pytest.fixture(scope="module")
def area(tmp_path_factory) -> Path:
    return write_area(tmp_path_factory.mktemp("s2d3ds"))


def run(capsys, *argv):
    return run_cli(capsys, list(argv))


def test_pose_forms_agree_on_a_consistent_file(area):
    from panovocc_cli.io.s2d3ds import read_pose_json

    f = next((area / "pano" / "pose").glob("*aa02*"))
    p = read_pose_json(f)
    T = pose_of(*PANOS[1][2])
    assert np.allclose(pano_pose(p, "rt"), T, atol=1e-9) and np.allclose(pano_pose(p, "euler"), T, atol=1e-9)
    turned = pano_pose(p, "rt", 90)
    # yaw 90: the panorama's centre column looks along the camera's +x
    assert np.allclose(turned[:3, 2], T[:3, 0], atol=1e-12)


def test_convert_gives_poses_depth_and_labels(area, tmp_path, capsys):
    seq = tmp_path / "seq"
    code, out, err = run(capsys, "convert", "s2d3ds", area, seq, "--quiet")
    assert code == 0, err
    assert "5 panoramas 128x64 from 2 rooms" in out
    s = Sequence(seq)
    names = s.meta.class_names
    assert names[:14] == ["unlabeled", "ceiling", "floor", "wall", "beam", "column", "window", "door", "table",
                          "chair", "sofa", "bookcase", "board", "clutter"] and names[14:] == ["stairs"]
    order = sorted(PANOS, key=lambda p: (p[1], p[0]))  # by room, then uuid
    for i, (uuid, room, p) in enumerate(order):
        T = pose_of(*p)
        assert np.allclose(s.poses[i], T, atol=1e-9)
        d = s.depth(i)
        assert d[3, 5] == 0 and abs(d[20, 20] - round(box_depth(W, T, LO, HI)[20, 20] * 512) / 512) < 1e-6
        lab = s.labels(i)
        assert lab[0, 0] == names.index("ceiling") and lab[-1, 0] == names.index("chair")
        assert lab[30, 30] == names.index("wall") and lab[10, 0] == names.index("beam")
        assert lab[11, 0] == names.index("stairs") and lab[12, 0] == 0 and lab[13, 0] == 0
    meta = json.loads((seq / "meta.json").read_text())["s2d3ds"]
    assert meta["panoramas"][0] == "bb01 hallway_2" and meta["rt_location_max_diff_m"] < 1e-9


def test_check_tells_the_right_convention_from_wrong_ones(tmp_path, capsys):
    area = write_area(tmp_path / "bad_euler", euler_ok=False)
    code, out, err = run(capsys, "convert", "s2d3ds", area, tmp_path / "seq", "--check", "--quiet")
    assert code == 0, err
    c = json.loads((tmp_path / "seq" / "meta.json").read_text())["s2d3ds"]["check"]
    assert c["chosen"] == "rt/yaw0" and c["agreement"] > 90 and c["pairs"] >= 2, c
    assert all(v < c["agreement"] - 20 for k, v in c["all"].items() if k != "rt/yaw0"), c["all"]
    # a wrong choice is named and the better one suggested
    code, out, err = run(capsys, "convert", "s2d3ds", area, tmp_path / "seq2", "--check", "--pano-yaw-deg", "90",
                         "--quiet")
    assert code == 0 and "rerun with --pose-form rt --pano-yaw-deg 0" in out


def annotations(root: Path) -> Path:
    a = root / "Area_1"
    for room, files in {"office_1": {"chair_1.txt": ["0.05 0.05 0.05 1 2 3"] * 3 + ["0.15 0.05 0.05 1 2 3"],
                                     "wall_1.txt": ["0.05 0.05 0.05 1 2 3"] * 2 + ["0.15 0.05 0.05 0 0 0",
                                                                                   "0.3 0.3 0.2 0 0 0"],
                                     "clutter_2.txt": ["0.15 0.05 0.05 9 9 9", "0.15 0.06 0.05 9 9 9", "bad\x10 line",
                                                       "0.55 0.05 0.05 185\x00187 9"]},
                        "hallway_2": {"stairs_1.txt": ["0.45 0.05 0.05 0 0 0"], "floor_1.txt": []}}.items():
        (a / room / "Annotations").mkdir(parents=True)
        for f, lines in files.items():
            (a / room / "Annotations" / f).write_text("\n".join(lines) + ("\n" if lines else ""))
    return a


def test_ground_truth_from_annotations(tmp_path, capsys):
    a = annotations(tmp_path)
    gt = tmp_path / "gt.npz"
    code, out, err = run(capsys, "convert", "s2d3ds-gt", a, gt, "--voxel-size", "0.1", "--quiet")
    assert code == 0, err
    assert "1 malformed lines skipped" in out
    g = read_grid(gt)
    assert g.class_names[:4] == ["empty", "ceiling", "floor", "wall"] and g.class_names[-1] == "stairs"
    expect = {(0, 0, 0): "chair",  # 3 chair points beat 2 wall points
              (1, 0, 0): "clutter",  # clutter 2 points, chair 1, wall 1
              (3, 3, 2): "wall",  # 0.2 / 0.1 = 2: a point on a voxel face belongs to the voxel above it
              (4, 0, 0): "stairs",
              (5, 0, 0): "clutter"}  # two colour numbers glued by a NUL byte (as in a released file): x y z kept
    i0 = g.index0
    occ = {tuple(int(v) for v in ijk + i0): g.class_names[g.labels[tuple(ijk)]]
           for ijk in np.argwhere((g.labels != 0) & (g.labels != 255))}
    assert occ == expect
    assert (g.labels == 0).sum() == g.labels.size - 5  # the rest of the points' box is empty
    assert json.loads((tmp_path / "gt.config.json").read_text())["voxel_size"] == 0.1


def test_ground_truth_ties_go_to_the_lower_class_id(tmp_path):
    from panovocc_cli.gt.s2d3ds import points_to_grid, voxel_counts

    names = ["empty", "a", "b"]
    p = np.array([[0.01, 0.01, 0.01]])
    g = points_to_grid([voxel_counts(p, 2, 0.08), voxel_counts(p, 1, 0.08)], names, 0.08)
    assert g.labels.reshape(-1).tolist() == [1]
    g = points_to_grid([voxel_counts(p, 0, 0.08)], names, 0.08)
    assert g.labels.reshape(-1).tolist() == [254]  # points of no class only


@pytest.mark.parametrize("case", ["no_pano", "no_pose_dir", "bad_pose_json", "pose_field", "depth_8bit",
                                  "no_labels_json", "gt_no_annotations", "unknown_room"])
def test_bad_inputs_one_line_exit_2_nothing_written(case, tmp_path, capsys):
    import shutil

    root = tmp_path / "data"
    area = write_area(root)
    out = tmp_path / "seq"
    args = ["convert", "s2d3ds", area, out]
    if case == "no_pano":
        shutil.rmtree(area / "pano")
    elif case == "no_pose_dir":
        shutil.rmtree(area / "pano" / "pose")
    elif case == "bad_pose_json":
        next((area / "pano" / "pose").glob("*.json")).write_text("{not json")
    elif case == "pose_field":
        f = next((area / "pano" / "pose").glob("*.json"))
        d = json.loads(f.read_text())
        del d["camera_rt_matrix"]
        f.write_text(json.dumps(d))
    elif case == "depth_8bit":
        import cv2

        f = next((area / "pano" / "depth").glob("*.png"))
        cv2.imwrite(str(f), np.zeros((W // 2, W), np.uint8))
    elif case == "no_labels_json":
        (root / "assets" / "semantic_labels.json").unlink()
    elif case == "gt_no_annotations":
        args = ["convert", "s2d3ds-gt", area, tmp_path / "gt.npz"]
        out = tmp_path / "gt.npz"
    elif case == "unknown_room":
        args += ["--rooms", "office_9"]
    before = snapshot(root)
    code, o, err = run(capsys, *args, "--quiet")
    assert code == 2, (o, err)
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err, err
    assert not out.exists() and snapshot(root) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_labels_json_reader(tmp_path):
    f = tmp_path / "semantic_labels.json"
    f.write_text(json.dumps(LABELS))
    assert read_semantic_labels(f) == LABELS


def test_output_never_holds_the_labels_json(tmp_path, capsys):
    """--labels-json is an input: an output folder that holds it is refused as such, even with --overwrite."""
    area = write_area(tmp_path / "data")
    labels = tmp_path / "data" / "assets" / "semantic_labels.json"
    before = snapshot(tmp_path)
    code, o, err = run(capsys, "convert", "s2d3ds", area, labels.parent, "--labels-json", labels, "--overwrite",
                       "--quiet")
    assert code == 2 and "the input" in err and len(err.strip().splitlines()) == 1, err
    assert snapshot(tmp_path) == before
