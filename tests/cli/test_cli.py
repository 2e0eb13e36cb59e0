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
