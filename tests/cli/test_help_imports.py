"""``--help`` stays instant: building the command line (every command's options come from its config
dataclass) must not import the heavy libraries, which only the command that runs needs (STYLE.md)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("numba", "open3d", "cv2", "matplotlib", "pyrender", "scipy", "torch", "rerun", "rosbags")
ROOT = Path(__file__).resolve().parents[2]


def _imported_modules(*args: str) -> set[str]:
    """Top-level names of every module ``python -X importtime -m panovocc_cli ARGS`` imported."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-X", "importtime", "-m", "panovocc_cli", *args],
                         capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "Usage" in res.stdout
    names = set()
    for line in res.stderr.splitlines():
        if line.startswith("import time:") and line.count("|") == 2:
            names.add(line.rsplit("|", 1)[1].strip().split(".")[0])
    assert "panovocc_cli" in names and "typer" in names  # the trace was read
    return names


@pytest.mark.parametrize("args", [("--help",), ("map", "--help"), ("gt", "--help"), ("render", "--help"),
                                  ("segeval", "--help"), ("revise", "--help"), ("compact", "--help"),
                                  ("views", "--help"), ("convert", "holo360d", "--help"), ("view", "--help"),
                                  ("convert", "rosbag", "--help"), ("convert", "s2d3ds", "--help"),
                                  ("convert", "s2d3ds-gt", "--help")])
def test_help_imports_no_heavy_library(args):
    heavy = sorted(set(HEAVY) & _imported_modules(*args))
    assert not heavy, f"panovocc {' '.join(args)} imports {heavy}"


def test_a_command_imports_only_its_own_module():
    """`panovocc map ...` registers the commands of map's module only (no other command's libraries load);
    every command of the full line is listed in COMMAND_HOMES with the module that registers it."""
    import typer

    from panovocc_cli import cli

    full = typer.main.get_command(cli.load_commands())
    for name, cmd in full.commands.items():
        assert name in cli.COMMAND_HOMES, f"{name}: add it to cli.COMMAND_HOMES"
        homes = cli.COMMAND_HOMES[name]
        callbacks = [cmd.callback] if cmd.callback is not None else []
        callbacks += [c.callback for c in getattr(cmd, "commands", {}).values()]
        mods = {c.__module__.rsplit(".", 1)[-1] for c in callbacks if c is not None and c.__module__ != cli.__name__}
        assert mods <= set(homes), f"{name} is registered by {mods}, COMMAND_HOMES says {homes}"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    script = ("import sys\nfrom panovocc_cli.cli import main\ntry:\n    main(['map', '--help'])\nexcept SystemExit:\n"
              "    pass\nprint(sorted(m for m in sys.modules if m.startswith('panovocc_cli.cli.')), file=sys.stderr)")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert "--semantic-stride" in res.stdout, res.stderr[-2000:]
    loaded = set(eval(res.stderr.strip().splitlines()[-1]))
    assert "panovocc_cli.cli.map_cmds" in loaded
    assert not {f"panovocc_cli.cli.{m}" for m in cli.COMMAND_MODULES if m != "map_cmds"} & loaded
