"""``panovocc map SEQ OUT --poses slam --poses-align se3|se3-pose [--poses-reference FILE]``: the front end's final
poses fitted to a reference trajectory by one rigid motion, every frame revised to its fitted pose, so the map is in the
reference's world, placed by the whole trajectory (a reference with per-frame noise: issue 22)."""

import json

import numpy as np
import pytest
from cli_helpers import run_cli

from panovocc_cli.evaluation.trajectory import align_trajectory, evaluate_trajectory
from panovocc_cli.io.poses import read_poses, read_trajectory, write_poses

BASE = ["--segmenter", "none", "--quiet"]


@pytest.mark.parametrize("fit", ["se3", "se3-pose"])
def test_poses_align_fits_the_final_poses_to_a_noisy_reference(short_seq, tmp_path, capsys, fit):
    truth = read_poses(short_seq / "poses.txt")
    code, _, err = run_cli(capsys, ["traj", "perturb", short_seq / "poses.txt", tmp_path / "jit.txt", "--jitter",
                                    "0.01", "--rot-jitter-deg", "0.1", "--seed", "0"])
    assert code == 0, err
    jit = read_poses(tmp_path / "jit.txt")
    out = tmp_path / "al"
    code, _, err = run_cli(capsys, ["map", short_seq, out, "--poses", "slam", "--poses-align", fit,
                                    "--poses-reference", tmp_path / "jit.txt", *BASE])
    assert code == 0, err
    est = read_poses(out / "poses.txt")
    # fitted: aligning the result to the reference again moves nothing
    _, R, t, _ = align_trajectory(est, jit, fit)
    assert np.abs(R - np.eye(3)).max() < 1e-9 and np.abs(t).max() < 1e-9
    # placed by every frame of the noisy reference, not by one of them: far nearer the truth than the reference is
    raw = evaluate_trajectory(est, truth, "none").ate["rmse"]
    ref_err = evaluate_trajectory(jit, truth, "none").ate["rmse"]
    assert raw < ref_err / 2, (raw, ref_err)
    t_ids, tum, _ = read_trajectory(out / "trajectory.tum")
    assert np.allclose(tum, est[t_ids.astype(int)], atol=1e-9)
    world = json.loads((out / "slam.json").read_text())["world"]
    assert world["aligned_to"] == str(tmp_path / "jit.txt") and world["first_pose"] is None
    assert (out / "trajectory.tum").read_text().startswith("# world: the reference trajectory's world")
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["poses_align"] == fit and cfg["poses_reference"] == str(tmp_path / "jit.txt")
    # the memory is the one a map built from the final poses holds, bit for bit (the same origin)
    origin = ",".join(repr(float(x)) for x in cfg["origin"])
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "direct", "--poses", out / "poses.txt", "--origin",
                                    origin, *BASE])
    assert code == 0, err
    for name in ("memory.npz", "prediction.npz"):
        assert (out / name).read_bytes() == (tmp_path / "direct" / name).read_bytes(), name


def test_poses_align_to_a_reference_90_km_away(short_seq, tmp_path):
    """A georeferenced reference (90 km from the world origin): the run starts in its world, so the keys stay in
    range, and the poses are the near reference's moved by the same 90 km."""
    from panovocc_cli.mapping.config import MapConfig, SemanticParams
    from panovocc_cli.slam.run import run_map_slam

    truth = read_poses(short_seq / "poses.txt")
    far = truth.copy()
    far[:, :3, 3] += [90_000.0, -35_000.0, 120.0]
    write_poses(tmp_path / "near.txt", truth)
    write_poses(tmp_path / "far.txt", far)
    sem = SemanticParams(segmenter="none")
    est = {}
    for name in ("near", "far"):
        s = run_map_slam(MapConfig(seq=str(short_seq), out=str(tmp_path / name), semantic=sem, poses_align="se3",
                                   poses_reference=str(tmp_path / f"{name}.txt")), progress=False)
        assert s["slam"]["unplaced_frames"] == []
        est[name] = read_poses(tmp_path / name / "poses.txt")
    shift = est["far"][:, :3, 3] - est["near"][:, :3, 3] - [90_000.0, -35_000.0, 120.0]
    assert np.abs(shift).max() < 1e-4 and np.abs(est["far"][:, :3, :3] - est["near"][:, :3, :3]).max() < 1e-6
    assert evaluate_trajectory(est["far"], far, "none").ate["rmse"] < 0.005
    cfg = json.loads((tmp_path / "far" / "config.json").read_text())
    assert np.abs(np.asarray(cfg["origin"]) - far[0, :3, 3]).max() <= cfg["geometry"]["voxel_size"]


@pytest.mark.parametrize("case", ["sim3", "with-first-pose", "pose-fit-with-first-pose", "reference-alone",
                                  "missing-reference"])
def test_poses_align_with_slam_refused_in_one_line(short_seq, tmp_path, capsys, case):
    ref = tmp_path / "ref.txt"
    write_poses(ref, read_poses(short_seq / "poses.txt"))
    argv = ["map", short_seq, tmp_path / "out", "--poses", "slam", *BASE]
    argv += {"sim3": ["--poses-align", "sim3"],
             "with-first-pose": ["--poses-align", "se3", "--first-pose", ref],
             "pose-fit-with-first-pose": ["--poses-align", "se3-pose", "--first-pose", ref],
             "reference-alone": ["--poses-reference", ref],
             "missing-reference": ["--poses-align", "se3", "--poses-reference", tmp_path / "nowhere.txt"]}[case]
    expect = {"sim3": "sim3", "with-first-pose": "--first-pose", "pose-fit-with-first-pose": "--first-pose",
              "reference-alone": "--poses-reference",
              "missing-reference": "nowhere.txt"}[case]
    code, _, err = run_cli(capsys, argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and "Traceback" not in err and len(lines) == 1 and lines[0].startswith("error:"), err
    assert expect in lines[0], lines[0]
    assert not (tmp_path / "out").exists()
