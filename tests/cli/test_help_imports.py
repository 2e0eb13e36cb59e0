"""``--help`` stays instant: building the command line (every command's options come from its config
dataclass) must not import the heavy libraries, which only the command that runs needs (STYLE.md)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("numba", "open3d", "cv2", "matplotlib", "pyrender", "scipy", "torch")
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
                                  ("segeval", "--help"), ("revise", "--help"),
                                  ("views", "--help"), ("convert", "holo360d", "--help")])
def test_help_imports_no_heavy_library(args):
    heavy = sorted(set(HEAVY) & _imported_modules(*args))
    assert not heavy, f"panovocc {' '.join(args)} imports {heavy}"
