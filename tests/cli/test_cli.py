"""The command line as a whole: every command documents its options, and misuse exits 2 on one line."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PANOVOCC = [sys.executable, "-m", "panovocc_cli"]
COMMANDS = ["synth", "render", "gt", "map", "revise", "eval", "coverage", "show", "demo", "bench", "version"]


def run(*args, cwd=None):
    env = dict(os.environ, COLUMNS="120")
    return subprocess.run([*PANOVOCC, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def test_top_level_help_lists_every_command():
    r = run("--help")
    assert r.returncode == 0
    for c in COMMANDS + ["convert"]:
        assert c in r.stdout, c


@pytest.mark.parametrize("cmd", COMMANDS)
def test_subcommand_help(cmd):
    r = run(cmd, "--help")
    assert r.returncode == 0, r.stderr
    assert "Usage" in r.stdout


def test_units_are_named_in_help():
    assert "metres" in run("gt", "--help").stdout
    assert "pixels" in run("render", "--help").stdout
    assert "degrees" in run("coverage", "--help").stdout


@pytest.mark.parametrize("args", [["nosuch"], ["eval", "--out"], ["render"], ["gt", "--voxel-size", "abc", "a", "b"]])
def test_usage_errors_exit_2_without_traceback(args):
    r = run(*args)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr


def test_expected_failure_is_one_line(tmp_path: Path):
    r = run("eval", str(tmp_path / "missing.npz"), str(tmp_path / "gt.npz"))
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "missing.npz" in lines[0]
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("args", [["--width", "63"], ["--width", "0"], ["--noise", "foo"], ["--frames", "1"],
                                  ["--seed", "-1"]])
def test_demo_refuses_bad_options_before_any_stage_runs(tmp_path: Path, args):
    r = run("demo", str(tmp_path / "d"), *args)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1, r.stderr
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_demo_two_frames_end_to_end(tmp_path: Path):
    """The whole pipeline on 2 frames at 64x32: every stage's outputs and its config.json, the seed passed
    on to the scene, the render noise and the simulated segmenter."""
    import json

    out = tmp_path / "demo"
    r = run("demo", str(out), "--frames", "2", "--width", "64", "--seed", "1", "--noise", "realistic")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "mIoU" in r.stdout and "stage times" in r.stdout
    for p in ("scene/habitat/mesh_semantic.ply", "seq/meta.json", "gt.npz", "map/prediction.npz",
              "eval/scores.csv", "compare.png", "coverage/coverage.png"):
        assert (out / p).is_file(), p
    configs = {name: json.loads((out / name).read_text()) for name in (
        "config.json", "scene/config.json", "seq/config.json", "gt.config.json", "map/config.json",
        "eval/config.json", "compare.config.json", "coverage/config.json")}
    assert configs["config.json"] == {"out": str(out), "seed": 1, "frames": 2, "width": 64, "noise": "realistic"}
    assert configs["scene/config.json"]["seed"] == 1 and configs["scene/config.json"]["frames"] == 2
    assert configs["seq/config.json"]["seed"] == 1 and configs["seq/config.json"]["width"] == 64
    assert configs["map/config.json"]["semantic"]["seed"] == 1  # --seed reaches the segmenter
    assert configs["gt.config.json"]["voxel_size"] == 0.08
