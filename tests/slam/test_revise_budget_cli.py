"""``panovocc map SEQ OUT --poses slam --revise-per-frame K``: the tracker's revision budget
(``SlamParams.revise_per_frame``) from the command line, recorded in config.json and slam.json; refused without
``--poses slam`` (issue 22)."""

import json

import numpy as np
from cli_helpers import run_cli

from panovocc_cli.io.poses import read_poses
from panovocc_cli.slam import SlamParams


def test_revise_per_frame_reaches_the_tracker_and_the_records(short_seq, tmp_path, capsys):
    base = ["--poses", "slam", "--first-pose", "reference", "--segmenter", "none", "--quiet"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "k1", *base, "--revise-per-frame", "1"])
    assert code == 0, err
    assert json.loads((tmp_path / "k1" / "config.json").read_text())["revise_per_frame"] == 1
    assert json.loads((tmp_path / "k1" / "slam.json").read_text())["params"]["revise_per_frame"] == 1
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "k0", *base])
    assert code == 0, err
    assert "revise_per_frame" not in json.loads((tmp_path / "k0" / "config.json").read_text())  # as before the option
    assert json.loads((tmp_path / "k0" / "slam.json").read_text())["params"]["revise_per_frame"] == 0
    # the same estimates either way: the poses handed out at the end agree within the final revision threshold
    a, b = read_poses(tmp_path / "k1" / "poses.txt"), read_poses(tmp_path / "k0" / "poses.txt")
    assert np.abs(a[:, :3, 3] - b[:, :3, 3]).max() <= 2 * SlamParams().final_revise_m


def test_revise_per_frame_needs_poses_slam(short_seq, tmp_path, capsys):
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "m", "--segmenter", "none", "--quiet",
                                    "--revise-per-frame", "2"])
    assert code == 2 and "--revise-per-frame" in err and err.count("\n") == 1, err
    assert not (tmp_path / "m").exists()


def test_heading_prior_from_the_command_line(short_seq, tmp_path, capsys):
    """``--heading-prior`` reaches the tracker (slam.json's params and its heading figures) and config.json;
    refused without ``--poses slam``."""
    base = ["--poses", "slam", "--first-pose", "reference", "--segmenter", "none", "--quiet"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "h", *base, "--heading-prior"])
    assert code == 0, err
    assert json.loads((tmp_path / "h" / "config.json").read_text())["heading_prior"] is True
    info = json.loads((tmp_path / "h" / "slam.json").read_text())
    assert info["params"]["heading_prior"] is True and info["heading"]["priors"] >= 1
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "m", "--segmenter", "none", "--quiet",
                                    "--heading-prior"])
    assert code == 2 and "--heading-prior" in err and err.count("\n") == 1, err
    assert not (tmp_path / "m").exists()
