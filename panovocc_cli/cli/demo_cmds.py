"""Command: demo (the whole pipeline on the embedded default scene)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..config import DEFAULT_SEED, DEFAULT_WIDTH
from ._app import app


@app.command()
def demo(
    out: Path = typer.Argument(Path("work/demo"), help="Working folder for every stage's outputs."),
    seed: int = typer.Option(DEFAULT_SEED, "--seed", help="Seed of the procedural scene, render noise and segmenter."),
    frames: int = typer.Option(60, "--frames", min=1, help="Number of trajectory poses (frames)."),
    width: int = typer.Option(DEFAULT_WIDTH, "--width", help="ERP width in pixels (even; height = width / 2)."),
    noise: str = typer.Option("none", "--noise", help="Depth noise of the render: none | realistic."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous demo's outputs in OUT (never any "
                                                             "other folder)."),
) -> None:
    """Render, map and evaluate the embedded default scene end to end, then print the score table."""
    from ..demo import DemoConfig, run_demo
    from ..evaluation.run import format_report

    res = run_demo(DemoConfig(out=out, seed=seed, frames=frames, width=width, noise=noise, overwrite=overwrite))
    typer.echo("")
    typer.echo(format_report(res["scores"]))
    typer.echo("")
    total = sum(res["timings"].values())
    typer.echo("stage times: " + ", ".join(f"{k} {v:.1f} s" for k, v in res["timings"].items())
               + f" (total {total:.1f} s)")
    for k, p in res["paths"].items():
        typer.echo(f"  {k:13s} {p}")
