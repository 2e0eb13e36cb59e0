"""Helpers of the command-line robustness suites (tests/cli): run ``panovocc`` in or out of process, snapshot
folders, build the shared fixture data. A module of its own, not ``conftest``: test folders each have a
``conftest.py``, and which one ``from conftest import ...`` finds depends on the folders collected."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

PANOVOCC = [sys.executable, "-m", "panovocc_cli"]


def run_cli(capsys, argv) -> tuple[int, str, str]:
    """Run ``panovocc ARGV`` in this process; (exit code, stdout, stderr). A numpy RuntimeWarning is an error."""
    from panovocc_cli.cli import main

    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(SystemExit) as e:
            main([os.fspath(a) if isinstance(a, Path) else str(a) for a in argv])
    cap = capsys.readouterr()
    return int(e.value.code or 0), cap.out, cap.err


def run_sub(*args, timeout=300, **kw) -> subprocess.CompletedProcess:
    """``panovocc ARGS`` in a child process (for crashes that would take the test process down, and kills)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    return subprocess.run([*PANOVOCC, *[os.fsencode(a) if isinstance(a, Path) else a for a in args]],
                          capture_output=True, env=env, timeout=timeout, **kw)


def snapshot(*roots) -> dict:
    """Every file (bytes digest) and folder under ``roots``: equal snapshots = nothing changed."""
    out = {}
    for root in roots:
        root = Path(root)
        if not root.exists():
            out[os.fsencode(root)] = None
            continue
        if root.is_file():
            out[os.fsencode(root)] = hashlib.sha1(root.read_bytes()).hexdigest()
            continue
        for dirpath, dirs, files in os.walk(os.fsencode(root)):
            out[dirpath] = "dir"
            for f in files:
                p = os.path.join(dirpath, f)
                with open(p, "rb") as fh:
                    out[p] = hashlib.sha1(fh.read()).hexdigest()
    return out


def build_base(root: Path) -> Path:
    """The four-frame fixture data under ``root`` (see the module docstring)."""
    from panovocc_cli.datasets.synth import SynthConfig, run_synth
    from panovocc_cli.gt import GtConfig, run_gt
    from panovocc_cli.mapping.pipeline import MapConfig, run_map
    from panovocc_cli.rendering.render import RenderConfig, run_render

    run_synth(SynthConfig(out=root / "scene", seed=3, frames=4))
    run_gt(GtConfig(scene=root / "scene", out=root / "gt.npz"))
    run_render(RenderConfig(scene=root / "scene", out=root / "seq", width=256, progress=False, threads=1))
    run_map(MapConfig(seq=str(root / "seq"), out=str(root / "map")), progress=False)
    shutil.copyfile(root / "map" / "prediction.npz", root / "pred.npz")
    return root
