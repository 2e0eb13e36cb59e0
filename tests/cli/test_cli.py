"""The command line as a whole: every command documents its options, and misuse exits 2 on one line."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PANOVOCC = [sys.executable, "-m", "panovocc_cli"]
COMMANDS = ["synth", "render", "gt", "map", "revise", "segeval", "eval", "coverage", "show", "demo", "bench", "version"]
SUBCOMMANDS = [["convert", "replicaocc"], ["convert", "to-replicaocc"]]


def run(*args, cwd=None):
    env = dict(os.environ, COLUMNS="120")
    return subprocess.run([*PANOVOCC, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=120)


def test_top_level_help_lists_every_command():
    r = run("--help")
    assert r.returncode == 0
    for c in COMMANDS + ["convert"]:
        assert c in r.stdout, c


def test_version_prints_the_version():
    """``panovocc version`` alone registers one command; the app stays a group (it once took ``version`` for an
    extra argument of that command and exited 2)."""
    from panovocc_cli import __version__

    r = run("version")
    assert r.returncode == 0 and r.stdout.strip() == __version__, r.stderr


@pytest.mark.parametrize("cmd", COMMANDS + SUBCOMMANDS)
def test_subcommand_help(cmd):
    r = run(*([cmd] if isinstance(cmd, str) else cmd), "--help")
    assert r.returncode == 0, r.stderr
    assert "Usage" in r.stdout


def _commands():
    """(name, click command) of every command and convert subcommand."""
    import typer

    from panovocc_cli.cli import load_commands

    top = typer.main.get_command(load_commands())
    out = []
    for name, cmd in top.commands.items():
        subs = getattr(cmd, "commands", None)
        out += [(f"{name} {n}", c) for n, c in subs.items()] if subs else [(name, cmd)]
    return out


def test_every_command_documents_every_option():
    """Each parameter of each command has a help text; options declared on a config dataclass keep their
    default and show their range."""
    cmds = dict(_commands())
    assert {c for c in COMMANDS} | {" ".join(c) for c in SUBCOMMANDS} <= set(cmds)
    for name, cmd in cmds.items():
        assert (cmd.help or "").strip(), name
        for p in cmd.params:
            if p.name == "help":
                continue
            assert len((getattr(p, "help", None) or "").strip()) >= 10, (name, p.name)
    seed = next(p for p in cmds["synth"].params if p.name == "seed")
    assert seed.default == 0 and "0 <= x <= 18446744073709551615" in seed.help  # 64 bits, in full (issue 26)
    vs = next(p for p in cmds["map"].params if p.name == "voxel_size")
    assert vs.default == 0.08 and "metres" in vs.help


def test_options_are_declared_once_on_the_config():
    """A command's config options are exactly the dataclass fields that carry option metadata."""
    from panovocc_cli.cli.options import option_specs
    from panovocc_cli.datasets.synth import SynthConfig
    from panovocc_cli.mapping.params import GeometryParams, OccupancyParams
    from panovocc_cli.mapping.pipeline import MapConfig
    from panovocc_cli.mapping.config import SemanticParams
    from panovocc_cli.rendering.render import RenderConfig

    cmds = dict(_commands())
    for name, classes in (("synth", [SynthConfig]), ("render", [RenderConfig]),
                          ("map", [MapConfig, GeometryParams, OccupancyParams, SemanticParams])):
        declared = {s.name for c in classes for s in option_specs(c)}
        params = {p.name for p in cmds[name].params}
        assert declared <= params, (name, declared - params)


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


BAD_VALUES = [
    ["synth", "{t}/s", "--seed", "-1"], ["synth", "{t}/s", "--rooms", "0"], ["synth", "{t}/s", "--frames", "1"],
    ["render", "{t}/scene", "{t}/seq", "--width", "2"], ["render", "{t}/scene", "{t}/seq", "--width", "66",
                                                         "--seed", "-1"],
    ["render", "{t}/scene", "{t}/seq", "--threads", "-1"], ["render", "{t}/scene", "{t}/seq", "--every", "0"],
    ["render", "{t}/scene", "{t}/seq", "--noise", "foo"], ["render", "{t}/scene", "{t}/seq", "--backend", "gl"],
    ["gt", "{t}/scene", "{t}/gt.npz", "--voxel-size", "0"], ["gt", "{t}/scene", "{t}/gt.npz", "--voxel-size", "nan"],
    ["map", "{t}/seq", "{t}/m", "--nu", "2"], ["map", "{t}/seq", "{t}/m", "--kappa", "-1"],
    ["map", "{t}/seq", "{t}/m", "--stride", "100000"], ["map", "{t}/seq", "{t}/m", "--max-range", "0"],
    ["map", "{t}/seq", "{t}/m", "--seed", "-1"], ["map", "{t}/seq", "{t}/m", "--noise", "-0.5"],
    ["map", "{t}/seq", "{t}/m", "--gamma-f", "1.5"], ["map", "{t}/seq", "{t}/m", "--ply-color", "blue"],
    ["segeval", "{t}/seq", "--every", "0"], ["bench", "{t}/b", "--frames", "1"],
    ["coverage", "{t}/seq", "{t}/gt.npz", "--out", "{t}/c", "--fov-deg", "180"],
    ["coverage", "{t}/seq", "{t}/gt.npz", "--out", "{t}/c", "--every", "0"],
    ["show", "{t}/a.npz", "{t}/b.png", "--width-px", "10000000"], ["show", "{t}/a.npz", "{t}/b.png", "--cut-top", "-2"],
    ["eval", "{t}/a.npz", "{t}/b.npz", "--mask", "all"],
    ["convert", "replicaocc", "{t}/a.pkl", "{t}/a.npz", "--voxel-size", "-0.08"],
    ["demo", "{t}/d", "--width", "0"],
]


@pytest.mark.parametrize("args", BAD_VALUES, ids=lambda a: " ".join(x for x in a if "{t}" not in x))
def test_out_of_range_option_values_are_one_line_before_any_work(tmp_path: Path, capsys, args):
    from panovocc_cli.cli import main

    with pytest.raises(SystemExit) as e:
        main([a.format(t=tmp_path) for a in args])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: --"), err
    flag = next(a for a in args[::-1] if a.startswith("--") and a not in ("--out",))
    assert flag in lines[0]
    assert list(tmp_path.iterdir()) == []  # checked before any file was read or written
