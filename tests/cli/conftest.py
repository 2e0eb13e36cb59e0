"""Shared small data for the command-line robustness suites (built once per test session).

``base`` is a folder with ``scene/`` (``panovocc synth --seed 3 --frames 4``), ``seq/`` (its 256x128
render), ``gt.npz``, ``map/`` (``panovocc map seq map``) and ``pred.npz`` (the map's prediction). Tests
treat it as read-only input and prove they left it untouched (:func:`snapshot`); a test that needs to
change something copies it first.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_helpers import build_base


@pytest.fixture(scope="session")
def base(tmp_path_factory) -> Path:
    return build_base(tmp_path_factory.mktemp("base"))
