"""Commands: eval_cmds."""

from ._app import app  # noqa: F401
