"""``views``: split a panoramic sequence into twelve pinhole view sequences (the perspective baselines' input)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..baselines.views import ViewsConfig
from ._app import app

_H = {k: f.metadata["help"] for k, f in ViewsConfig.__dataclass_fields__.items()}


@app.command()
def views(
    seq: Path = typer.Argument(..., help=_H["seq"]),
    out: Path = typer.Argument(..., help=_H["out"]),
    fov_deg: float = typer.Option(90.0, "--fov-deg", help=_H["fov_deg"]),
    size: Optional[int] = typer.Option(None, "--size", help=_H["size"]),
    pitch_deg: float = typer.Option(ViewsConfig.pitch_deg, "--pitch-deg", help=_H["pitch_deg"]),
    overwrite: bool = typer.Option(False, "--overwrite", help=_H["overwrite"]),
) -> None:
    """Split each panorama into twelve pinhole views (4 azimuths x up/mid/down): RGB, z-depth, labels, poses."""
    from ..baselines.views import run_views

    s = run_views(ViewsConfig(seq=seq, out=out, fov_deg=fov_deg, size=size, pitch_deg=pitch_deg,
                              overwrite=overwrite))
    typer.echo(f"{out}: {s['views']} view sequences of {s['frames']} frames, {s['size']}x{s['size']} px "
               f"(fx {s['fx']:.1f}), valid depth {100 * s['valid_depth']:.1f}%, labels {'yes' if s['labels'] else 'no'}, "
               f"in {s['seconds']:.1f} s")
