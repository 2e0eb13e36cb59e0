"""Commands that make data: ``synth`` (procedural scenes), ``render`` (ERP sequences), ``gt`` (mesh ground truth)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..config import DEFAULT_SEED, DEFAULT_VOXEL_SIZE, DEFAULT_WIDTH
from ..errors import PanovoccError
from ._app import app


@app.command()
def synth(
    scene: Path = typer.Argument(..., help="Scene folder to write (Replica layout: habitat/mesh_semantic.ply, "
                                           "habitat/info_semantic.json, traj.txt)."),
    seed: int = typer.Option(DEFAULT_SEED, "--seed", help="Random seed; the same seed gives the same files."),
    rooms: Optional[int] = typer.Option(None, "--rooms", help="Number of rooms, 1-6 (default: 2 or 3 from the seed)."),
    frames: int = typer.Option(60, "--frames", help="Number of trajectory poses."),
    offset: Optional[str] = typer.Option(None, "--offset", help="X,Y,Z metres: move the home (laid out from the "
                                                                "origin) by this offset instead of the seeded one "
                                                                "(e.g. 0,0,0 puts the floor on a voxel face)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous panovocc scene in SCENE (never "
                                                             "any other folder)."),
) -> None:
    """Write a procedural multi-room indoor scene in Replica's format, with a trajectory through every room."""
    from ..datasets.synth import SynthConfig, parse_offset, run_synth
    from ..io.atomic import check_output

    if seed < 0:
        raise PanovoccError(f"--seed must be >= 0, got {seed}")
    check_output(scene, "scene", overwrite)
    s = run_synth(SynthConfig(out=scene, seed=seed, rooms=rooms, frames=frames,
                              offset=None if offset is None else parse_offset(offset)))
    typer.echo(f"{scene}: {s['rooms']} rooms, {s['faces']} quads, {s['objects']} objects, "
               f"{len(s['classes'])} classes, {s['frames']} poses over {s['path_m']:.1f} m")


@app.command()
def render(
    scene: Path = typer.Argument(..., help="Replica-format scene folder (habitat/mesh_semantic.ply + info_semantic.json)."),
    seq: Path = typer.Argument(..., help="Sequence folder to write (meta.json, rgb/, depth/, semantic/, poses.txt)."),
    traj: Optional[Path] = typer.Option(None, "--traj", help="Trajectory, NICE-SLAM (16 numbers a line) or TUM; "
                                                              "default SCENE/traj.txt."),
    width: int = typer.Option(DEFAULT_WIDTH, "--width", help="ERP width in pixels (even; height = width / 2)."),
    backend: str = typer.Option("raycast", "--backend", help="raycast (exact spherical rays, Open3D) or pyrender "
                                                             "(six rasterised cube faces, OSMesa)."),
    every: int = typer.Option(1, "--every", help="Render every k-th pose."),
    noise: str = typer.Option("none", "--noise", help="none, or realistic: range-dependent depth noise (metres), "
                                                      "dropouts, no depth on glass, edge bleeding."),
    seed: int = typer.Option(DEFAULT_SEED, "--seed", help="Noise seed."),
    threads: int = typer.Option(0, "--threads", help="Ray-casting threads (0 = all cores)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a previous panovocc sequence in SEQ (never "
                                                             "any other folder, never an input)."),
) -> None:
    """Render a panoramic RGB-D sequence (RGB, radial depth in mm, class labels) along a trajectory."""
    from ..rendering.render import RenderConfig, run_render

    s = run_render(RenderConfig(scene=scene, out=seq, traj=traj, width=width, backend=backend, every=every,
                                noise=noise, seed=seed, threads=threads, overwrite=overwrite))
    typer.echo(f"{seq}: {s['frames']} frames {s['width']}x{s['height']} in {s['seconds']:.1f} s "
               f"({s['ms_per_frame']:.0f} ms/frame), valid depth {100 * s['valid_depth']:.1f}%")


@app.command()
def gt(
    scene: Path = typer.Argument(..., help="Replica-format scene folder."),
    out: Path = typer.Argument(..., help="Ground-truth grid to write (.npz: labels, origin, voxel_size, class_names)."),
    voxel_size: float = typer.Option(DEFAULT_VOXEL_SIZE, "--voxel-size", help="Voxel edge length in metres."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing OUT file (never an input)."),
) -> None:
    """Voxelise the scene's mesh surface on the global lattice (area-vote class per voxel)."""
    from ..gt import GtConfig, run_gt

    s = run_gt(GtConfig(scene=scene, out=out, voxel_size=voxel_size, overwrite=overwrite))
    typer.echo(f"{out}: grid {s['shape'][0]}x{s['shape'][1]}x{s['shape'][2]} at {s['voxel_size']} m, "
               f"{s['occupied']} occupied voxels, {s['classes']} classes")
