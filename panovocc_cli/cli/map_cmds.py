"""Commands: ``map`` (sequence -> persistent semantic memory + grid), ``revise`` (new poses), ``bench`` (speed),
``segeval`` (a segmenter's own per-frame 2D mIoU)."""

from __future__ import annotations

from pathlib import Path

import typer

from ..errors import PanovoccError
from ..mapping.bench import BenchConfig
from ..mapping.params import GeometryParams, OccupancyParams
from ..mapping.config import MapConfig, ReviseConfig, SegevalConfig, SemanticParams
from ._app import app
from .options import OptionValues, build_config, config_command


@config_command(app, MapConfig, "map", nested=("geometry", "occupancy", "semantic"))
def map_cmd(
    o: OptionValues,
    resume: bool = typer.Option(False, "--resume", help="Continue the interrupted run in OUT (its config is used)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a map already in OUT."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Map a panoramic RGB-D sequence into a persistent semantic occupancy memory (OUT/) and grid
    (OUT/prediction.npz), labelling occupied voxels with classes of the vocabulary."""
    from ..mapping.pipeline import run_map

    seq, out = o["seq"], o["out"]
    if resume:
        target = out if out is not None else seq
        if target is None or (seq is not None and out is not None):
            raise PanovoccError("--resume takes only the output folder: panovocc map --resume OUT")
        given = [o.flags[n] for n in o.given if n not in ("seq", "out")]
        if given:
            raise PanovoccError(f"--resume reuses the run's saved config; {', '.join(sorted(given))} cannot change it")
        summary = run_map(resume_out=target, progress=not quiet)
    else:
        if seq is None or out is None:
            raise PanovoccError("map needs SEQ and OUT (or --resume OUT)")
        if "segmenter" not in o.given and not (Path(seq) / "semantic").is_dir() and (Path(seq) / "meta.json").is_file():
            raise PanovoccError(f"{seq} has no ground-truth labels (semantic/) for the default simulated "
                                "segmenter: pass --segmenter precomputed:DIR, or --segmenter none (geometry only)")
        cfg = build_config(MapConfig, o, geometry=build_config(GeometryParams, o),
                           occupancy=build_config(OccupancyParams, o), semantic=build_config(SemanticParams, o))
        summary = run_map(cfg, overwrite=overwrite, progress=not quiet)
    classed = f", {summary['classed']} with a class" if "classed" in summary else ""
    seg = f", segmenter {summary['segmenter_ms_per_frame']:.1f} ms" if "segmenter_ms_per_frame" in summary else ""
    typer.echo(f"mapped {summary['integrated']} of {summary['frames']} frames, {summary['ms_per_frame']:.1f} ms/frame "
               f"(update {summary['update_ms_per_frame']:.1f} ms{seg}): {summary['occupied']} occupied{classed}, "
               f"{summary['free']} free voxels -> {summary['out']}")
    empty = summary.get("empty_frames") or []
    if empty:
        shown = ", ".join(map(str, empty[:10])) + (", ..." if len(empty) > 10 else "")
        typer.echo(f"{len(empty)} frame(s) had no valid depth and were mapped as empty observations: {shown}")


@config_command(app, ReviseConfig, "revise")
def revise(o: OptionValues) -> None:
    """Re-integrate exactly the frames whose pose changed, and rewrite OUT/prediction.npz and OUT/map.ply."""
    from ..mapping.pipeline import run_revise

    s = run_revise(ReviseConfig(**o))
    classed = f", {s['classed']} with a class" if "classed" in s else ""
    typer.echo(f"revised {s['revised']} of {s['frames']} frames in {s['seconds']:.2f} s: {s['occupied']} occupied"
               f"{classed}, {s['free']} free voxels")


@config_command(app, SegevalConfig, "segeval")
def segeval(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """A segmenter's own per-frame 2D mIoU on a labelled sequence (pixel counts pooled over frames)."""
    import math

    from ..mapping.semantic import run_segeval

    res, frames = run_segeval(SegevalConfig(**o), progress=not quiet)
    for (name, v), here in zip(res.iou.items(), res.present):
        shown = "-" if math.isnan(v) else f"{100 * v:5.1f}"
        typer.echo(f"  {name:<12} {shown}{'' if here else '  (absent from the ground truth, not in the mean)'}")
    typer.echo(f"2D mIoU ({o['classes']}, pooled over {len(frames)} frames): {100 * res.miou:.1f}%, "
               f"pixel accuracy {100 * res.accuracy:.1f}%")


@config_command(app, BenchConfig, "bench", only=("out", "frames", "width"))
def bench(o: OptionValues) -> None:
    """Mapper speed against Open3D VoxelBlockGrid TSDF fusion (cube faces) on the same frames."""
    from ..mapping.bench import run_bench

    r = run_bench(BenchConfig(**o))
    typer.echo(r["line"])
