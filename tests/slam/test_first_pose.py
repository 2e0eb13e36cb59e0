"""``panovocc map SEQ OUT --poses slam --first-pose FILE|reference``: the SLAM world starts at a given pose of the
first frame, so the map is in the reference's world and scores without alignment (issue 22)."""

import json

import numpy as np
import pytest
from cli_helpers import run_cli

from panovocc_cli.evaluation.trajectory import evaluate_trajectory
from panovocc_cli.geometry.drift import so3_exp
from panovocc_cli.io.poses import read_poses, read_trajectory, write_poses


def _iou(pred, ref) -> float:
    """Occupancy IoU (%) of two map folders' prediction.npz, ``ref``'s grid as the ground truth."""
    from panovocc_cli.evaluation.metrics import count_pair
    from panovocc_cli.io.grid import read_grid

    c = count_pair(read_grid(pred / "prediction.npz"), read_grid(ref / "prediction.npz"))["freeocc"]
    return 100.0 * c.tp / (c.tp + c.fp + c.fn)


def test_first_pose_reference_puts_the_map_in_the_reference_world(short_seq, tmp_path, capsys):
    from panovocc_cli.geometry.lattice import local_origin

    truth = read_poses(short_seq / "poses.txt")
    base = ["--segmenter", "none", "--quiet"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "ref", "--poses", "slam", "--first-pose", "reference",
                                    *base])
    assert code == 0, err
    est = read_poses(tmp_path / "ref" / "poses.txt")
    assert np.allclose(est[0], truth[0], atol=1e-12)
    # the trajectory is in the reference's world: its error without alignment is about the aligned one
    raw = evaluate_trajectory(est, truth, "none").ate["rmse"]
    aligned = evaluate_trajectory(est, truth, "se3").ate["rmse"]
    assert raw < 0.005 and raw < aligned + 0.002, (raw, aligned)  # measured 0.8 and 0.6 mm
    t, tum, _ = read_trajectory(tmp_path / "ref" / "trajectory.tum")
    assert np.allclose(tum, est[t.astype(int)], atol=1e-9)
    assert (tmp_path / "ref" / "trajectory.tum").read_text().startswith("# world: the reference trajectory's world")
    # the records say which world
    cfg = json.loads((tmp_path / "ref" / "config.json").read_text())
    assert cfg["first_pose"] == "reference"
    h = cfg["geometry"]["voxel_size"]
    assert np.allclose(cfg["origin"], local_origin(truth[0, :3, 3], h) * h)  # the first frame's voxel, that world
    world = json.loads((tmp_path / "ref" / "slam.json").read_text())["world"]
    assert world["first_pose"] == "reference" and world["first_frame"] == 0
    assert np.allclose(world["T_world_first"], truth[0], atol=1e-12)

    # the grid scores against the true-pose map without alignment as well as the aligned variant does
    run_cli(capsys, ["map", short_seq, tmp_path / "true", *base])
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "aligned", "--poses", tmp_path / "ref" / "poses.txt",
                                    "--poses-align", "se3", *base])
    assert code == 0, err
    iou_first, iou_aligned = _iou(tmp_path / "ref", tmp_path / "true"), _iou(tmp_path / "aligned", tmp_path / "true")
    assert iou_first > 90 and abs(iou_first - iou_aligned) < 2, (iou_first, iou_aligned)  # measured 98.9, 98.5
    # the default world (the first frame levelled at the origin) is not that world
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "level", "--poses", "slam", *base])
    assert code == 0, err
    assert _iou(tmp_path / "level", tmp_path / "true") < 10  # measured 0.9
    assert json.loads((tmp_path / "level" / "slam.json").read_text())["world"]["first_pose"] is None


def test_first_pose_file_moves_the_whole_trajectory(short_seq, tmp_path):
    """T_world_cam(i) = T_first inv(T_slam(0)) T_slam(i): the default run's trajectory moved rigidly."""
    from panovocc_cli.mapping.config import MapConfig, SemanticParams
    from panovocc_cli.slam.run import run_map_slam

    A = np.eye(4)
    A[:3, :3], A[:3, 3] = so3_exp([0.02, -0.01, 2.1]), [250.0, -40.0, 3.0]  # a survey point, turned and tilted
    (tmp_path / "first.txt").write_text("".join(" ".join(repr(float(x)) for x in row) + "\n" for row in A))
    sem = SemanticParams(segmenter="none")
    run_map_slam(MapConfig(seq=str(short_seq), out=str(tmp_path / "level"), semantic=sem), progress=False)
    s = run_map_slam(MapConfig(seq=str(short_seq), out=str(tmp_path / "file"), semantic=sem,
                               first_pose=str(tmp_path / "first.txt")), progress=False)
    assert s["slam"]["unplaced_frames"] == []
    level, est = read_poses(tmp_path / "level" / "poses.txt"), read_poses(tmp_path / "file" / "poses.txt")
    assert np.allclose(est[0], A, atol=1e-12)
    moved = A @ np.linalg.inv(level[0]) @ level
    assert np.abs(est[:, :3, 3] - moved[:, :3, 3]).max() < 1e-4 and np.abs(est[:, :3, :3] - moved[:, :3, :3]).max() < 1e-5
    cfg = json.loads((tmp_path / "file" / "config.json").read_text())
    assert cfg["first_pose"] == str(tmp_path / "first.txt")
    assert np.abs(np.asarray(cfg["origin"]) - A[:3, 3]).max() <= cfg["geometry"]["voxel_size"]
    # the front end alone (the benchmark's poses task) gives the same poses.txt in that world
    from panovocc_cli.slam.run import run_slam_poses

    run_slam_poses(short_seq, tmp_path / "poses_only", first_pose=str(tmp_path / "first.txt"))
    assert (tmp_path / "poses_only" / "poses.txt").read_bytes() == (tmp_path / "file" / "poses.txt").read_bytes()


@pytest.mark.parametrize("case", ["missing", "empty", "non-rigid", "without-slam", "reference-of-a-file",
                                  "inside-the-output"])
def test_first_pose_bad_input_refused_in_one_line(short_seq, tmp_path, capsys, case):
    f = tmp_path / "first.txt"
    extra, expect, out = [], "first.txt", tmp_path / "out"
    if case == "empty":
        f.write_text("\n")
        expect = "empty"
    elif case == "non-rigid":
        f.write_text("1 0 0 0\n0 1 0.5 0\n0 0 1 0\n0 0 0 1\n")
        expect = "not rigid"
    elif case == "missing":
        expect = "not found"
    else:
        write_poses(f, np.eye(4)[None])
        if case == "without-slam":
            extra, expect = ["--first-pose", f], "--first-pose"
        elif case == "reference-of-a-file":
            extra, expect = ["--poses-reference", short_seq / "poses.txt"], "--poses-reference"
        else:  # --overwrite OUT would remove the file the run reads
            extra, expect, out = ["--overwrite"], "first.txt", tmp_path
    argv = ["map", short_seq, out, "--segmenter", "none", "--quiet"]
    argv += extra if case == "without-slam" else ["--poses", "slam", "--first-pose", f, *extra]
    code, _, err = run_cli(capsys, argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and "Traceback" not in err and len(lines) == 1 and lines[0].startswith("error:"), err
    assert expect in lines[0], lines[0]
    assert not (tmp_path / "out").exists() and sorted(p.name for p in tmp_path.iterdir()) in ([], ["first.txt"])
