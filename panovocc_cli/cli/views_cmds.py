"""``views``: split a panoramic sequence into twelve pinhole view sequences (the perspective baselines' input).

Its options are declared once, on ViewsConfig (cli/options.py)."""

from __future__ import annotations

import typer

from ..baselines.views import ViewsConfig
from ._app import app
from .options import OptionValues, config_command


@config_command(app, ViewsConfig, "views")
def views(o: OptionValues) -> None:
    """Split each panorama into twelve pinhole views (4 azimuths x up/mid/down): RGB, z-depth, labels, poses."""
    from ..baselines.views import run_views

    s = run_views(ViewsConfig(**o))
    typer.echo(f"{o['out']}: {s['views']} view sequences of {s['frames']} frames, {s['size']}x{s['size']} px "
               f"(fx {s['fx']:.1f}), valid depth {100 * s['valid_depth']:.1f}%, labels {'yes' if s['labels'] else 'no'}, "
               f"in {s['seconds']:.1f} s")
