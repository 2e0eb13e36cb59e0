"""Holo360D reader and ``convert holo360d``: small scenes written in the released layout (JPEG, EXR depth,
mask, a pose file with a header line), the pose forms, and the check telling a wrong convention from the right one."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from box_room import box_depth  # noqa: E402

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.io.holo360d import POSE_FORMS, R_AXES, holo_pose, read_holo_poses, read_holo_scene

W = 256
LO, HI = np.array([-2.3, -1.6, -1.4]), np.array([2.9, 2.1, 1.3])
STEMS = ["9", "10", "11", "12", "13"]  # timestamps: numeric order differs from name order


def our_poses():
    out = []
    for k, (x, y, yaw) in enumerate([(0.0, 0.0, 0.0), (0.6, 0.3, 0.8), (1.2, -0.2, 1.7), (0.5, -0.8, 2.6),
                                     (-0.6, 0.4, -2.2)]):
        T = look_at([x, y, 0.1 * k], [np.cos(yaw), np.sin(yaw), 0.05])
        out.append(T)
    return out


def holo_line(stem: str, T_ours: np.ndarray) -> str:
    """The pose line the authors' reader turns into T_ours: [[R.T, t]] @ diag(R_AXES, 1) = T_ours."""
    A = np.eye(4)
    A[:3, :3] = R_AXES.T
    Th = T_ours @ A
    R = Th[:3, :3].T
    return " ".join([f"{stem}.jpg"] + [f"{v:.12g}" for v in (*Th[:3, 3], *R.reshape(-1))])


def write_scene(root: Path, mask_dark_rows: int = 0) -> Path:
    import cv2

    from panovocc_cli.io.images import write_exr

    for d in ("rgb", "depth/mesh_depth", "depth/pointcloud_depth", "mask", "poses"):
        (root / d).mkdir(parents=True, exist_ok=True)
    lines = ["# name tx ty tz r11 r12 r13 r21 r22 r23 r31 r32 r33"]
    rng = np.random.default_rng(0)
    for s, T in zip(STEMS, our_poses()):
        d = box_depth(W, T, LO, HI)
        d[5, 7] = np.nan  # a hole as float EXR stores it
        write_exr(root / "depth" / "mesh_depth" / f"{s}.exr", d)
        write_exr(root / "depth" / "pointcloud_depth" / f"{s}.exr", d * 0.5)
        cv2.imwrite(str(root / "rgb" / f"{s}.jpg"), rng.integers(0, 255, (W // 2, W, 3), dtype=np.uint8))
        m = np.full((W // 2, W), 255, np.uint8)
        m[W // 2 - mask_dark_rows:] = 0
        cv2.imwrite(str(root / "mask" / f"{s}.jpg"), m)
        lines.append(holo_line(s, T))
    (root / "poses" / "poses.txt").write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return write_scene(tmp_path_factory.mktemp("holo") / "Indoor_001")


def run(capsys, *argv):
    from panovocc_cli.cli import main

    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([os.fspath(a) for a in argv])
    cap = capsys.readouterr()
    return int(e.value.code or 0), cap.out, cap.err


def test_pose_forms_are_distinct_and_the_authors_one_inverts_our_writer():
    T = our_poses()[2]
    t, R = (lambda p: (p[:3], np.array(p[3:]).reshape(3, 3)))([float(v) for v in holo_line("x", T).split()[1:]])
    assert np.allclose(holo_pose(t, R), T, atol=1e-9)
    mats = [holo_pose(t, R, f, a) for f in POSE_FORMS for a in ("holo", "opencv")]
    assert all(not np.allclose(a, b) for i, a in enumerate(mats) for b in mats[i + 1:])
    # the axes: the toolkit's forward ray (0, 0, 1) is Holo360D's -x, its up (0, -1, 0) is +z
    assert np.allclose(R_AXES @ [0, 0, 1], [-1, 0, 0]) and np.allclose(R_AXES @ [0, -1, 0], [0, 0, 1])


def test_read_scene_orders_stems_as_numbers_and_reports_missing(scene, tmp_path):
    s = read_holo_scene(scene)
    assert s.stems == STEMS and not s.skipped
    import shutil

    other = tmp_path / "s"
    shutil.copytree(scene, other)
    (other / "depth" / "mesh_depth" / "11.exr").unlink()
    s = read_holo_scene(other)
    assert s.stems == ["9", "10", "12", "13"] and s.skipped == ["11: no depth"]


def test_convert_gives_our_poses_and_depth(scene, tmp_path, capsys):
    from panovocc_cli.io.sequence import Sequence

    rc, out, err = run(capsys, "convert", "holo360d", scene, tmp_path / "seq", "--quiet")
    assert rc == 0, err
    seq = Sequence(tmp_path / "seq")
    assert len(seq) == 5 and seq.meta.width == W
    assert np.allclose(seq.poses, np.stack(our_poses()), atol=1e-9)
    for i in (0, 3):  # the NaN hole reads as 0 (no measurement), the rest as written
        d, ref = seq.depth(i), box_depth(W, our_poses()[i], LO, HI)
        assert d[5, 7] == 0 and np.allclose(np.delete(d.ravel(), 5 * W + 7), np.delete(ref.ravel(), 5 * W + 7),
                                            atol=1e-6)
    meta = json.loads((tmp_path / "seq" / "meta.json").read_text())
    assert meta["holo360d"]["stems"] == STEMS and meta["holo360d"]["pose_form"] == "rt-c2w"
    assert (tmp_path / "seq" / "config.json").is_file()
    assert next(iter(seq.frames())).rgb.shape == (W // 2, W, 3)


def test_check_tells_the_right_convention_from_wrong_ones(scene, tmp_path, capsys):
    rc, out, err = run(capsys, "convert", "holo360d", scene, tmp_path / "a", "--check", "--quiet")
    assert rc == 0, err
    right = json.loads((tmp_path / "a" / "meta.json").read_text())["holo360d"]["check"]
    assert right["chosen"] == right["best"] == "rt-c2w/holo" and right["agreement"] > 95
    assert "agrees better" not in out
    rc, out, err = run(capsys, "convert", "holo360d", scene, tmp_path / "b", "--check", "--pose-form", "r-c2w",
                       "--quiet")
    assert rc == 0, err
    wrong = json.loads((tmp_path / "b" / "meta.json").read_text())["holo360d"]["check"]
    assert wrong["agreement"] < 60 and wrong["best"] == "rt-c2w/holo"
    assert "rerun with --pose-form rt-c2w --camera-axes holo" in out
    for form, v in right["all"].items():
        if form != "rt-c2w/holo":
            assert v < right["agreement"] - 30, form


def test_mask_and_pointcloud_depth(tmp_path, capsys):
    from panovocc_cli.io.sequence import Sequence

    sc = write_scene(tmp_path / "Indoor_002", mask_dark_rows=10)
    rc, _, err = run(capsys, "convert", "holo360d", sc, tmp_path / "m", "--depth", "pointcloud", "--quiet")
    assert rc == 0, err
    d = Sequence(tmp_path / "m").depth(2)
    assert np.all(d[-10:] == 0) and np.allclose(d[20:40], 0.5 * box_depth(W, our_poses()[2], LO, HI)[20:40],
                                                atol=1e-6)
    rc, _, err = run(capsys, "convert", "holo360d", sc, tmp_path / "n", "--no-mask", "--width", "128", "--quiet")
    assert rc == 0, err
    s = Sequence(tmp_path / "n")
    assert s.meta.width == 128 and (s.depth(2)[-3:] > 0).all()


def test_bad_pose_file_and_layout(scene, tmp_path, capsys):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(scene, bad)
    p = bad / "poses" / "poses.txt"
    lines = p.read_text().splitlines()
    lines[3] = lines[3].rsplit(" ", 1)[0]
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(PanovoccError, match="line 4"):
        read_holo_poses(bad / "poses")
    rc, _, err = run(capsys, "convert", "holo360d", bad, tmp_path / "out")
    assert rc == 2 and "poses.txt" in err and "line 4" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()
    shutil.rmtree(bad / "rgb")
    rc, _, err = run(capsys, "convert", "holo360d", bad, tmp_path / "out")
    assert rc == 2 and "rgb/" in err and not (tmp_path / "out").exists()
    rc, _, err = run(capsys, "convert", "holo360d", scene, tmp_path / "o2", "--pose-form", "xyz")
    assert rc == 2 and "--pose-form" in err


def test_convert_refuses_a_non_rigid_pose_and_a_width_beyond_memory(scene, tmp_path, capsys):
    """A pose line whose R is not a rotation (scaled by 2) is refused on one line naming the file, line and
    frame (map would refuse the sequence later); --width 100000 is refused by its memory estimate before any
    frame is converted (it was killed for memory, leaving its staging folder). Nothing is left behind."""
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(scene, bad)
    p = bad / "poses" / "poses.txt"
    lines = p.read_text().splitlines()
    parts = lines[3].split()
    lines[3] = " ".join(parts[:4] + [f"{2 * float(v):.12g}" for v in parts[4:]])
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(PanovoccError, match="line 4 .frame 11.: not rigid"):
        read_holo_poses(bad / "poses")
    rc, _, err = run(capsys, "convert", "holo360d", bad, tmp_path / "out", "--quiet")
    assert rc == 2 and "poses.txt: line 4 (frame 11): not rigid" in err and len(err.strip().splitlines()) == 1, err
    rc, _, err = run(capsys, "convert", "holo360d", scene, tmp_path / "out", "--width", "100000", "--quiet")
    assert rc == 2 and "--width 100000" in err and "GiB of memory" in err and len(err.strip().splitlines()) == 1, err
    assert sorted(x.name for x in tmp_path.iterdir()) == ["bad"]
