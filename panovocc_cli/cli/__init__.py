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
from ..errors import printable as _printable
from ._app import app

# Importing a module registers its commands on ``app``, in the order --help lists them. They are
# imported by load_commands(), after runtime.setup(): their config dataclasses (the options' single
# declaration) live in modules that import numba, which reads its settings when first imported.
COMMAND_MODULES = ("data_cmds", "views_cmds", "map_cmds", "eval_cmds", "holo_cmds", "import_cmds", "traj_cmds",
                   "demo_cmds", "baselines_cmds", "reproduce_cmds", "query_cmds", "viz_cmds")
# the modules that register each command: running one imports only these (a command not listed here
# loads every module, so a missing entry costs start-up time, never correctness)
COMMAND_HOMES = {
    "synth": ("data_cmds",), "render": ("data_cmds",), "gt": ("data_cmds",), "views": ("views_cmds",),
    "map": ("map_cmds",), "revise": ("map_cmds",), "segeval": ("map_cmds",), "bench": ("map_cmds",),
    "merge": ("map_cmds",), "compact": ("map_cmds",),
    "eval": ("eval_cmds",), "coverage": ("eval_cmds",), "show": ("eval_cmds",), "convert": ("eval_cmds", "holo_cmds", "import_cmds"),
    "traj": ("traj_cmds",), "demo": ("demo_cmds",), "baselines": ("baselines_cmds",),
    "reproduce": ("reproduce_cmds",), "query": ("query_cmds",), "relabel": ("query_cmds",), "view": ("viz_cmds",),
    "version": (),
}


def version() -> None:
    """Print the toolkit's version."""
    from .. import __version__

    typer.echo(__version__)


def _end_progress_bars() -> None:
    """Close the progress bars a failed command left open (a bar driven from a generator is closed only when it is
    collected), so that the error line starts a line of its own instead of trailing the bar."""
    tqdm_module = sys.modules.get("tqdm")
    if tqdm_module is None:
        return
    for bar in list(getattr(tqdm_module.tqdm, "_instances", ())):
        bar.close()


def load_commands(argv: list[str] | None = None) -> typer.Typer:
    """Register the commands on :data:`app` and return it: those of ``argv[0]``'s modules when it names a
    command of :data:`COMMAND_HOMES` (so ``panovocc map ...`` imports no other command's libraries),
    else all of them, listed in :data:`COMMAND_MODULES` order. Each module registers once."""
    import importlib

    first = argv[0] if argv else None
    names = COMMAND_HOMES[first] if first in COMMAND_HOMES else COMMAND_MODULES
    for name in names:
        importlib.import_module(f"{__name__}.{name}")
    if not getattr(app, "_panovocc_version", False):
        app.command("version")(version)
        app._panovocc_version = True
    if names is COMMAND_MODULES:  # --help lists them in module order, whatever was loaded first

        def order(info):  # a command by its callback's module, a group by its first command's
            cb = getattr(info, "callback", None)
            if cb is None:
                cb = next((c.callback for c in getattr(info.typer_instance, "registered_commands", ())), None)
            tail = getattr(cb, "__module__", "").rsplit(".", 1)[-1]
            return COMMAND_MODULES.index(tail) if tail in COMMAND_MODULES else len(COMMAND_MODULES)

        app.registered_commands.sort(key=order)
        app.registered_groups.sort(key=order)
    return app


def entry() -> None:
    """The ``panovocc`` console script and ``python -m panovocc_cli``: :func:`main` on ``sys.argv``; a command that
    succeeded then ends the process without the interpreter's teardown (:func:`panovocc_cli.runtime.quick_exit`:
    its ``atexit`` handlers run and its output is flushed first). A failure exits as :func:`main` raises it."""
    try:
        main()
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    from ..runtime import quick_exit

    quick_exit(0)


def main(argv: list[str] | None = None) -> int:
    """Console entry point: expected failures print one line and exit 2; others keep their traceback.

    Applies the process settings of :func:`panovocc_cli.runtime.setup` first (before any kernel loads).
    """
    from ..runtime import setup

    setup()
    load_commands(sys.argv[1:] if argv is None else list(argv))
    try:
        rv = app(args=argv, standalone_mode=False, prog_name="panovocc")
    except PanovoccError as e:
        _end_progress_bars()
        print(f"error: {_printable(str(e))}", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except click.exceptions.UsageError as e:  # Typer's three lines (Usage / Try / Error) as one, like the rest
        where = e.ctx.command_path if e.ctx is not None else "panovocc"
        message = " ".join(line.strip() for line in e.format_message().splitlines() if line.strip())
        print(_printable(f"error: {message} (see {where} -h)"), file=sys.stderr)
        sys.exit(e.exit_code)
    except click.exceptions.ClickException as e:
        e.show()
        sys.exit(e.exit_code)
    except (typer.Abort, getattr(click.exceptions, "Abort", typer.Abort)):
        print("aborted", file=sys.stderr)
        sys.exit(130)
    except OSError as e:  # disk full, read-only file system, a path the OS refuses: one line naming it
        _end_progress_bars()
        where = e.filename if e.filename is not None else "?"
        print(_printable(f"error: {os.fsdecode(where) if isinstance(where, bytes) else where}: {e.strerror or e}"),
              file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)
    except KeyboardInterrupt:
        _end_progress_bars()
        print("interrupted", file=sys.stderr)
        sys.exit(130)
    sys.exit(rv if isinstance(rv, int) else 0)
