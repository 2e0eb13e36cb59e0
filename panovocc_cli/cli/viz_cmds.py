"""Command: ``view`` (a finished map in Rerun: voxels by class, trajectory, frusta, panoramas, GT difference)."""

from __future__ import annotations

import typer

from ..viz.view import ViewConfig
from ._app import app
from .options import OptionValues, config_command


@config_command(app, ViewConfig, "view")
def view_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Show a map folder in Rerun (rerun-sdk): occupied voxels coloured by class with a legend, free space
    (--free), the trajectory and camera frusta, the panoramas on a frame timeline, and the difference to a
    ground-truth grid (--gt). Opens the viewer when there is a display, else writes MAP.rrd (or --out)."""
    from ..viz.view import run_view

    s = run_view(ViewConfig(**o), progress=not quiet)
    diff = s.get("difference")
    extra = (f"; against --gt: {diff['false_positive']} false positive, {diff['false_negative']} false negative, "
             f"{diff['wrong_class']} wrong-class voxels" if diff else "")
    typer.echo(f"{s['map']}: {s['occupied']} occupied voxels"
               + (f", {s['free']} free" if s.get("free") else "")
               + f", {s['frames']} poses, {s['panoramas']} panoramas{extra} -> {s['out']}")
    if s["note"]:
        typer.echo(f"note: {s['note']}")
    if s["out"] != "viewer":
        typer.echo(f"open it with: rerun {s['out']}")
