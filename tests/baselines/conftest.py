"""Fixtures of the baselines tests: the command line run in-process, and a small labelled room sequence."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


@pytest.fixture()
def cli(capsys):
    """``cli(argv) -> (exit code, stdout, stderr)`` of ``panovocc ARGV`` run in this process."""
    from panovocc_cli.cli import main

    def run(argv):
        capsys.readouterr()
        with pytest.raises(SystemExit) as e:
            main([os.fspath(a) if isinstance(a, Path) else str(a) for a in argv])
        cap = capsys.readouterr()
        return int(e.value.code or 0), cap.out, cap.err

    return run


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """The furnished, labelled box room of semantics_helpers, 4 frames of 128 x 64 (read-only input)."""
    from semantics_helpers import write_labelled_room

    return write_labelled_room(tmp_path_factory.mktemp("room") / "seq", 128, 4)
