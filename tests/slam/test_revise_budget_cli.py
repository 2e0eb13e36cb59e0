"""``panovocc map SEQ OUT --poses slam`` with the front end's options: ``--revise-per-frame K`` (the tracker's
revision budget, ``SlamParams.revise_per_frame``), ``--heading-prior``, ``--slam-preset NAME`` and
``--slam-params JSON`` (any ``SlamParams`` field) from the command line, recorded in config.json and slam.json; refused without
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


def test_slam_params_from_the_command_line(short_seq, tmp_path, capsys):
    """``--slam-params JSON`` sets SlamParams fields (an int where a float is expected is taken), recorded in
    config.json and slam.json; an unknown field, a value of the wrong type, text that is not a JSON object, a
    value the parameters refuse (out of its range, not finite, a contradiction) and a run without ``--poses slam``
    are each refused in one line, exit 2, nothing written."""
    base = ["--poses", "slam", "--first-pose", "reference", "--segmenter", "none", "--quiet"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "p", *base, "--slam-params",
                                    '{"refine_radius_m": 1, "refine_partners": 2, "refine": true}'])
    assert code == 0, err
    assert json.loads((tmp_path / "p" / "config.json").read_text())["slam_params"] == (
        '{"refine":true,"refine_partners":2,"refine_radius_m":1}')
    got = json.loads((tmp_path / "p" / "slam.json").read_text())["params"]
    assert got["refine_radius_m"] == 1.0 and isinstance(got["refine_radius_m"], float) and got["refine_partners"] == 2
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "d", *base])
    assert code == 0, err
    assert "slam_params" not in json.loads((tmp_path / "d" / "config.json").read_text())  # as before the option
    assert json.loads((tmp_path / "d" / "slam.json").read_text())["params"]["refine_radius_m"] == SlamParams().refine_radius_m
    for text, word in [('{"refine_radius": 1.0}', "refine_radius"), ('{"refine": 1}', "refine must be bool"),
                       ('{"refine_partners": 2.5}', "refine_partners must be int"), ("[1, 2]", "JSON object"),
                       ("{refine: 1}", "JSON object"), ('{"backend": "icp"}', "backend must be one of"),
                       ('{"voxel_m": 0}', "voxel_m must be a finite number > 0"),
                       ('{"refine_radius_m": NaN}', "refine_radius_m must be a finite number"),
                       ('{"max_range_m": 0.1}', "min_range_m must be below max_range_m")]:
        out = tmp_path / "bad"
        code, _, err = run_cli(capsys, ["map", short_seq, out, *base, "--slam-params", text])
        assert code == 2 and "--slam-params" in err and word in err and err.count("\n") == 1, (text, err)
        assert not out.exists()
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "m", "--segmenter", "none", "--quiet",
                                    "--slam-params", '{"refine_radius_m": 1.0}'])
    assert code == 2 and "--slam-params" in err and err.count("\n") == 1, err
    assert not (tmp_path / "m").exists()


def test_slam_preset_from_the_command_line(short_seq, tmp_path, capsys):
    """``--slam-preset building`` sets the building recipe's fields (slam.json's params, and its heading and level
    figures), ``--slam-params`` applies on top of it, config.json records it (and nothing for the default, as
    before the option); an unknown name and a run without ``--poses slam`` are refused in one line, exit 2,
    nothing written. The option's names are the tracker's presets."""
    from panovocc_cli.mapping.config import SLAM_PRESETS
    from panovocc_cli.slam.tracker import PRESETS

    assert tuple(PRESETS) == SLAM_PRESETS and PRESETS["default"] == {}
    base = ["--poses", "slam", "--first-pose", "reference", "--segmenter", "none", "--quiet"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "b", *base, "--slam-preset", "building"])
    assert code == 0, err
    assert json.loads((tmp_path / "b" / "config.json").read_text())["slam_preset"] == "building"
    info = json.loads((tmp_path / "b" / "slam.json").read_text())
    assert {k: info["params"][k] for k in PRESETS["building"]} == PRESETS["building"]
    assert info["heading"]["priors"] >= 1 and info["level"]["priors"] >= 1
    assert SlamParams().refine_radius_m != 1.0 and not SlamParams().heading_prior and not SlamParams().level_prior
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "o", *base, "--slam-preset", "building",
                                    "--slam-params", '{"refine_radius_m": 2.0}'])
    assert code == 0, err
    got = json.loads((tmp_path / "o" / "slam.json").read_text())["params"]
    assert got["refine_radius_m"] == 2.0 and got["heading_prior"] and got["level_prior"]
    code, _, err = run_cli(capsys, ["map", short_seq, tmp_path / "d", *base, "--slam-preset", "default"])
    assert code == 0, err
    assert "slam_preset" not in json.loads((tmp_path / "d" / "config.json").read_text())
    for args, word in [([*base, "--slam-preset", "house"], "--slam-preset"),
                       (["--segmenter", "none", "--quiet", "--slam-preset", "building"], "--slam-preset")]:
        out = tmp_path / "bad"
        code, _, err = run_cli(capsys, ["map", short_seq, out, *args])
        assert code == 2 and word in err and err.count("\n") == 1, (args, err)
        assert not out.exists()
