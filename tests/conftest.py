"""Tests run under the same process settings as the command line (panovocc_cli.runtime.setup)."""

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")

import panovocc_cli.runtime  # noqa: E402

panovocc_cli.runtime.setup()
