"""Command: demo (the whole pipeline on the embedded default scene)."""

from __future__ import annotations

import typer

from ..demo import DemoConfig
from ._app import app
from .options import OptionValues, config_command


@config_command(app, DemoConfig, "demo")
def demo(o: OptionValues) -> None:
    """Render, map and evaluate the embedded default scene end to end, then print the score table."""
    from ..demo import run_demo
    from ..evaluation.run import format_report

    res = run_demo(DemoConfig(**o))
    typer.echo("")
    typer.echo(format_report(res["scores"]))
    typer.echo("")
    total = sum(res["timings"].values())
    typer.echo("stage times: " + ", ".join(f"{k} {v:.1f} s" for k, v in res["timings"].items())
               + f" (total {total:.1f} s)")
    for k, p in res["paths"].items():
        typer.echo(f"  {k:13s} {p}")
