"""Command: reproduce (the whole benchmark: sweep on Dask, tables and figures in results/)."""

from __future__ import annotations

import typer

from ..benchmark.run import ReproduceConfig
from ._app import app
from .options import OptionValues, config_command


@config_command(app, ReproduceConfig, "reproduce")
def reproduce(
    o: OptionValues,
    small: bool = typer.Option(False, "--small", help="Shorthand for --scale small (minutes; what the tests run)."),
) -> None:
    """Rebuild every benchmark table and figure: splits x methods x variants as cached tasks on Dask.

    Finished tasks stay in --cache and are never recomputed, so an interrupted sweep resumes. Methods and
    splits this build lacks are listed as not available; no number is made up for them.
    """
    from ..benchmark.run import run_reproduce
    from ..errors import PanovoccError

    if small:
        if "scale" in o.given and o["scale"] != "small":
            raise PanovoccError(f"--small contradicts --scale {o['scale']}")
        o["scale"] = "small"
    s = run_reproduce(ReproduceConfig(**o))
    for what, why in s["unavailable"].items():
        typer.echo(f"{what}: {why}")
    typer.echo(f"{s['tasks']} tasks: {s['computed']} computed, {s['cached']} cached")
    typer.echo(f"wrote {len(s['tables'])} table files and {len(s['figures'])} figures to {o['out']}")
