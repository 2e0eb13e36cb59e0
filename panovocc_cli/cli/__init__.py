"""The ``panovocc`` command line: thin Typer commands that build a config and call one ``run_*``.

Commands live in one module per area so that each stays small; heavy libraries (open3d, pyrender,
matplotlib) are imported inside the command that needs them, so ``--help`` is instant.
"""

from __future__ import annotations

import os
import sys

import typer

try:  # typer >= 0.20 ships its own copy of click; older typer uses the click package
    from typer import _click as click
except ImportError:  # pragma: no cover
    import click

from ..errors import EXIT_BAD_INPUT, PanovoccError
from ._app import app

# Importing a module registers its commands on ``app``, in the order --help lists them. They are
# imported by load_commands(), after runtime.setup(): their config dataclasses (the options' single
# declaration) live in modules that import numba, which reads its settings when first imported.
COMMAND_MODULES = ("data_cmds", "views_cmds", "map_cmds", "eval_cmds", "holo_cmds", "traj_cmds", "demo_cmds",
                   "baselines_cmds", "reproduce_cmds", "query_cmds")


def version() -> None:
    """Print the toolkit's version."""
    from .. import __version__

    typer.echo(__version__)


def _printable(text: str) -> str:
    """A message with any undecodable path bytes (surrogate escapes) shown as backslash escapes, never an encoding error."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def load_commands() -> typer.Typer:
    """Register every command on :data:`app` (once) and return it."""
    import importlib

    if not getattr(app, "_panovocc_loaded", False):
        for name in COMMAND_MODULES:
            importlib.import_module(f"{__name__}.{name}")
        app.command("version")(version)
        app._panovocc_loaded = True
    return app


def main(argv: list[str] | None = None) -> int:
    """Console entry point: expected failures print one line and exit 2; others keep their traceback.

    Applies the process settings of :func:`panovocc_cli.runtime.setup` first (before any kernel loads).
    """
    from ..runtime import setup

    setup()
    load_commands()
    try:
        rv = app(args=argv, standalone_mode=False, prog_name="panovocc")
    except PanovoccError as e:
        print(f"error: {_printable(str(e))}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except click.exceptions.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except (typer.Abort, getattr(click.exceptions, "Abort", typer.Abort)):
        print("aborted", file=sys.stderr)
        sys.exit(130)
    except OSError as e:  # disk full, read-only file system, a path the OS refuses: one line naming it
        where = e.filename if e.filename is not None else "?"
        print(_printable(f"error: {os.fsdecode(where) if isinstance(where, bytes) else where}: {e.strerror or e}"),
              file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        sys.exit(130)
    sys.exit(rv if isinstance(rv, int) else 0)
