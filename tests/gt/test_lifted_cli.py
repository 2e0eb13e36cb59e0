"""``panovocc gt --from-sequence SEQ OUT`` end to end on a three-frame box-room sequence, and its bad inputs."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_lifted import HI, LO, NAMES, POSES, face_labels  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from box_room import box_depth  # noqa: E402

W = 256


def run(capsys, *argv):
    from panovocc_cli.cli import main

    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main([os.fspath(a) for a in argv])
    cap = capsys.readouterr()
    return int(e.value.code or 0), cap.out, cap.err


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses

    root = tmp_path_factory.mktemp("lift") / "seq"
    root.mkdir()
    poses = np.stack(POSES[:3])
    for i, T in enumerate(poses):
        write_frame(root, i, np.full((W // 2, W, 3), 128, np.uint8), box_depth(W, T, LO, HI), face_labels(W, T))
    write_meta(root, SequenceMeta(width=W, height=W // 2, frames=3, class_names=list(NAMES)))
    write_sequence_poses(root, poses)
    return root


def test_gt_from_sequence_writes_grid_config_and_is_deterministic(seq, tmp_path, capsys):
    from panovocc_cli.io.grid import read_grid

    rc, out, err = run(capsys, "gt", "--from-sequence", seq, tmp_path / "a.npz", "--annotated", "0,2", "--quiet")
    assert rc == 0, err
    assert "2 annotated" in out and "never observed" in out
    g = read_grid(tmp_path / "a.npz")
    occ = (g.labels > 0) & (g.labels < 255)
    assert occ.sum() > 500 and set(np.unique(g.labels[occ])) <= {1, 2, 3, 254}
    assert (g.labels == 0).sum() > 10 * occ.sum() / 2
    cfg = json.loads((tmp_path / "a.config.json").read_text())
    assert cfg["from_sequence"] == str(seq) and cfg["lift"]["annotated"] == "0,2" and cfg["scene"] is None
    rc, _, _ = run(capsys, "gt", "--from-sequence", seq, tmp_path / "b.npz", "--annotated", "0,2", "--quiet")
    assert rc == 0 and (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    rc, _, err = run(capsys, "gt", "--from-sequence", seq, tmp_path / "a.npz", "--quiet")
    assert rc == 2 and "--overwrite" in err


@pytest.mark.parametrize("args,msg", [
    (["SCENE", "OUT"], "not SCENE and OUT"),
    (["OUT", "--annotated", "every:0"], "--annotated"),
    (["OUT", "--annotated", "7"], "--annotated"),
    (["OUT", "--min-hit-ratio", "1.5"], "--min-hit-ratio"),
])
def test_gt_from_sequence_bad_options(seq, tmp_path, capsys, args, msg):
    argv = [a.replace("SCENE", str(tmp_path / "x")).replace("OUT", str(tmp_path / "g.npz")) for a in args]
    rc, _, err = run(capsys, "gt", "--from-sequence", seq, *argv)
    assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_lift_options_need_from_sequence(tmp_path, capsys):
    rc, _, err = run(capsys, "gt", tmp_path / "scene", tmp_path / "g.npz", "--min-frames", "3")
    assert rc == 2 and "--min-frames" in err and "--from-sequence" in err


def test_annotated_frames_need_labels(seq, tmp_path, capsys):
    import shutil

    s = tmp_path / "seq"
    shutil.copytree(seq, s)
    (s / "semantic" / "000001.png").unlink()  # only frames 0 and 2 annotated
    rc, _, err = run(capsys, "gt", "--from-sequence", s, tmp_path / "g.npz", "--annotated", "all")
    assert rc == 2 and "000001.png" in err and "annotated frame 1" in err and not (tmp_path / "g.npz").exists()
    rc, _, err = run(capsys, "gt", "--from-sequence", s, tmp_path / "g0.npz", "--annotated", "0,2", "--quiet")
    assert rc == 0, err
    shutil.rmtree(s / "semantic")
    rc, _, err = run(capsys, "gt", "--from-sequence", s, tmp_path / "g.npz")
    assert rc == 2 and "semantic/" in err and not (tmp_path / "g.npz").exists()
    rc, out, err = run(capsys, "gt", "--from-sequence", s, tmp_path / "g.npz", "--annotated", "none", "--quiet")
    assert rc == 0, err
    from panovocc_cli.io.grid import read_grid

    g = read_grid(tmp_path / "g.npz")
    assert set(np.unique(g.labels)) <= {0, 254, 255} and (g.labels == 254).sum() > 500
