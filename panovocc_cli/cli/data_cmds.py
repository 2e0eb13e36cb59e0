"""Commands that make data: ``synth`` (procedural scenes), ``render`` (ERP sequences), ``gt`` (mesh ground truth,
or ground truth lifted from a captured sequence).

Their options are declared once, on SynthConfig, RenderConfig and GtConfig (cli/options.py)."""

from __future__ import annotations

import typer

from ..datasets.synth import SynthConfig
from ..errors import PanovoccError
from ..gt_config import GtConfig, LiftParams
from ..rendering.render import RenderConfig
from ._app import app
from .options import OptionValues, build_config, config_command


@config_command(app, SynthConfig, "synth")
def synth(o: OptionValues) -> None:
    """Write a procedural indoor scene in Replica's format (a home, --house, or a multi-floor --building), with a
    trajectory through every room."""
    from ..datasets.synth import run_synth

    s = run_synth(SynthConfig(**o))
    if s["floors"]:
        where = f" on {s['floors']} floors ({s['floor_area']:.0f} m², corridors and a staircase)"
    else:
        where = " and a corridor" if s["corridor"] else ""
    typer.echo(f"{o['out']}: {s['rooms']} rooms{where}, {s['faces']} quads, {s['objects']} objects, "
               f"{len(s['classes'])} classes, {s['frames']} poses over {s['path_m']:.1f} m")


@config_command(app, RenderConfig, "render")
def render(o: OptionValues) -> None:
    """Render a panoramic RGB-D sequence (RGB, radial depth in mm, class labels) along a trajectory."""
    from ..rendering.render import run_render

    s = run_render(RenderConfig(**o))
    typer.echo(f"{o['out']}: {s['frames']} frames {s['width']}x{s['height']} in {s['seconds']:.1f} s "
               f"({s['ms_per_frame']:.0f} ms/frame), valid depth {100 * s['valid_depth']:.1f}%")


@config_command(app, GtConfig, "gt", nested=("lift",))
def gt(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Ground truth on the global lattice: voxelise a scene's mesh (gt SCENE OUT; area-vote class per voxel), or
    lift a captured sequence (gt --from-sequence SEQ OUT: occupancy from every frame's depth, classes from the
    annotated frames' labels; docs/gt.md)."""
    from ..gt import run_gt

    scene, out = o["scene"], o["out"]
    if o["from_sequence"] is not None:
        if out is not None:
            raise PanovoccError("gt --from-sequence SEQ takes one more argument, OUT (not SCENE and OUT)")
        scene, out = None, scene
        lift_given = []
    else:
        lift_given = [o.flags[n] for n in o.given if n in LiftParams.__dataclass_fields__]
        if lift_given:
            raise PanovoccError(f"{', '.join(sorted(lift_given))} only apply with --from-sequence SEQ")
        if scene is None or out is None:
            raise PanovoccError("gt needs SCENE and OUT (or --from-sequence SEQ OUT)")
    o["scene"], o["out"] = scene, out
    cfg = build_config(GtConfig, o, lift=build_config(LiftParams, o), progress=not quiet)
    s = run_gt(cfg)
    text = (f"{out}: grid {s['shape'][0]}x{s['shape'][1]}x{s['shape'][2]} at {s['voxel_size']} m, "
            f"{s['occupied']} occupied voxels, {s['classes']} classes")
    if "voted" in s:
        text += (f"; {s['frames']} frames, {s['annotated']} annotated: {s['voted']} voxels labelled by votes, "
                 f"{s['transferred']} by nearest-label transfer, {s['no_class']} left 254; {s['free']} free, "
                 f"{s['unknown']} never observed (255)")
    typer.echo(text)
