"""Commands that make data: ``synth`` (procedural scenes), ``render`` (ERP sequences), ``gt`` (mesh ground truth).

Their options are declared once, on SynthConfig, RenderConfig and GtConfig (cli/options.py)."""

from __future__ import annotations

import typer

from ..datasets.synth import SynthConfig
from ..gt_config import GtConfig
from ..rendering.render import RenderConfig
from ._app import app
from .options import OptionValues, config_command


@config_command(app, SynthConfig, "synth")
def synth(o: OptionValues) -> None:
    """Write a procedural multi-room indoor scene in Replica's format, with a trajectory through every room."""
    from ..datasets.synth import run_synth

    s = run_synth(SynthConfig(**o))
    typer.echo(f"{o['out']}: {s['rooms']} rooms, {s['faces']} quads, {s['objects']} objects, "
               f"{len(s['classes'])} classes, {s['frames']} poses over {s['path_m']:.1f} m")


@config_command(app, RenderConfig, "render")
def render(o: OptionValues) -> None:
    """Render a panoramic RGB-D sequence (RGB, radial depth in mm, class labels) along a trajectory."""
    from ..rendering.render import run_render

    s = run_render(RenderConfig(**o))
    typer.echo(f"{o['out']}: {s['frames']} frames {s['width']}x{s['height']} in {s['seconds']:.1f} s "
               f"({s['ms_per_frame']:.0f} ms/frame), valid depth {100 * s['valid_depth']:.1f}%")


@config_command(app, GtConfig, "gt")
def gt(o: OptionValues) -> None:
    """Voxelise the scene's mesh surface on the global lattice (area-vote class per voxel)."""
    from ..gt import run_gt

    s = run_gt(GtConfig(**o))
    typer.echo(f"{o['out']}: grid {s['shape'][0]}x{s['shape'][1]}x{s['shape'][2]} at {s['voxel_size']} m, "
               f"{s['occupied']} occupied voxels, {s['classes']} classes")
