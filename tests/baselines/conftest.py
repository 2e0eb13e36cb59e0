"""Fixtures of the baselines tests: the command line run in-process, and a small labelled room sequence."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture()
def cli(capsys):
    """``cli(argv) -> (exit code, stdout, stderr)`` of ``panovocc ARGV`` run in this process."""
    from cli_helpers import run_cli

    return lambda argv: run_cli(capsys, argv)


@pytest.fixture(scope="module")
def room(tmp_path_factory) -> Path:
    """The furnished, labelled box room of semantics_helpers, 4 frames of 128 x 64 (read-only input)."""
    from semantics_helpers import write_labelled_room

    return write_labelled_room(tmp_path_factory.mktemp("room") / "seq", 128, 4)
