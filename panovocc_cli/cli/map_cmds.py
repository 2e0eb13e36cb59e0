"""Commands: ``map`` (sequence -> persistent semantic memory + grid), ``revise`` (new poses), ``bench`` (speed),
``segeval`` (a segmenter's own per-frame 2D mIoU)."""

from __future__ import annotations

from pathlib import Path
from typing import List

import typer

from ..errors import PanovoccError
from ..benchmark.bench import BenchConfig
from ..mapping.params import GeometryParams, OccupancyParams
from ..mapping.ablation import AblationParams
from ..evaluation.run import SegevalConfig
from ..mapping.config import FIRST_POSE_REFERENCE, POSES_SLAM, MapConfig, ReviseConfig, SemanticParams
from ._app import app
from .options import OptionValues, build_config, config_command


MAP_SECTIONS = (GeometryParams, OccupancyParams, SemanticParams, AblationParams)


@config_command(app, MapConfig, "map", nested=("geometry", "occupancy", "semantic", "ablation"))
def map_cmd(
    o: OptionValues,
    config: Path = typer.Option(None, "--config", help="JSON file of map options by field name (e.g. {\"kernel\": "
                                "\"point\", \"use_gsc\": false, \"use_rpu\": false}); options given on the "
                                "command line win.", show_default=False),
    resume: bool = typer.Option(False, "--resume", help="Continue the interrupted run in OUT (its config is used)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a map already in OUT."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    rerun: Path = typer.Option(None, "--rerun", metavar="FILE.rrd", show_default=False,
                               help="Log the run live to this Rerun recording: each frame's panorama, depth and "
                                    "pose, the growing map, SLAM loop closures and revisions (rerun-sdk)."),
    rerun_connect: bool = typer.Option(False, "--rerun-connect", help="Stream the live log to a running Rerun "
                                       "viewer (start one with: rerun) instead of a file."),
    rerun_url: str = typer.Option(None, "--rerun-url", show_default=False,
                                  help="The viewer's gRPC URL for --rerun-connect (default "
                                       "rerun+http://127.0.0.1:9876/proxy)."),
    rerun_every: int = typer.Option(10, "--rerun-every", min=1, help="Frames between two logs of the growing map."),
    workers: int = typer.Option(0, "--workers", min=0, help="Integrate the frames in shards on a local Dask cluster "
                                "of N worker processes (one thread each); 0 = in this process. The map's bytes "
                                "do not depend on N (docs/sharding.md)."),
    scheduler: str = typer.Option(None, "--scheduler", metavar="ADDRESS", show_default=False,
                                  help="Integrate the frames in shards on the workers of this running Dask "
                                       "scheduler (tcp://HOST:8786); they must see SEQ at the same path and run "
                                       "this checkout (docs/sharding.md)."),
    shards_per_worker: int = typer.Option(None, "--shards-per-worker", min=1, show_default=False,
                                          help="Shards a worker gets with --workers/--scheduler (default 1: each "
                                               "shard costs a partial memory; more balance slow workers better). "
                                               "The map's bytes do not depend on it."),
) -> None:
    """Map a panoramic RGB-D sequence into a persistent semantic occupancy memory (OUT/) and grid
    (OUT/prediction.npz), labelling occupied voxels with classes of the vocabulary."""
    live = _live_log(rerun, rerun_connect, rerun_url, rerun_every, overwrite, o)
    try:
        summary = _map(o, config, resume, overwrite, quiet, live, workers, scheduler, shards_per_worker)
        if live is not None:
            live.close(ok=True)
    finally:
        if live is not None:
            live.close(ok=False)
    _report(summary)
    if live is not None and rerun is not None:
        typer.echo(f"live log -> {rerun} (open it with: rerun {rerun})")


def _live_log(rrd, connect: bool, url, every: int, overwrite: bool, o: OptionValues):
    """The Rerun live log of ``map --rerun`` / ``--rerun-connect`` (None without either); the .rrd path is
    checked here, before the run, against the map's inputs and its other outputs (``o``: the command's values)."""
    if url is not None and not connect:
        raise PanovoccError("--rerun-url is the viewer address of --rerun-connect; give --rerun-connect too")
    if rrd is None and not connect:
        return None
    if rrd is not None and connect:
        raise PanovoccError("give --rerun FILE.rrd or --rerun-connect, not both")
    from ..io.atomic import check_outputs
    from ..viz.live import LiveLog

    if rrd is not None:
        inputs = [o[k] for k in ("seq", "poses", "poses_reference", "first_pose")
                  if o.get(k) not in (None, POSES_SLAM, FIRST_POSE_REFERENCE)]
        check_outputs([(o.get("out"), "map", True), (o.get("frame_times"), "frame times", False),
                       (rrd, "recording", False)], overwrite, inputs=inputs)
    return LiveLog(rrd=rrd, connect=(url or "") if connect else None, every=every)


def _map(o: OptionValues, config, resume: bool, overwrite: bool, quiet: bool, live, workers: int = 0,
         scheduler: str | None = None, shards_per_worker: int | None = None) -> dict:
    if shards_per_worker is not None and not (workers or scheduler):
        raise PanovoccError("--shards-per-worker needs --workers N or --scheduler ADDRESS")
    if workers or scheduler:
        import contextlib
        import sys

        from ..benchmark.runner import dask_client
        from ..benchmark.sharded import DaskShards

        if workers and scheduler:
            raise PanovoccError("give --workers N (a local cluster) or --scheduler ADDRESS (a running one), not both")
        with contextlib.ExitStack() as stack:
            client = stack.enter_context(dask_client(scheduler, workers, log=None if quiet else sys.stderr))
            shards = DaskShards(client) if shards_per_worker is None else DaskShards(client, shards_per_worker)
            shards.check_workers()  # other code, or no workers: one line before anything is written
            summary = _map_with(o, config, resume, overwrite, quiet, live, shards)
            summary["shards"] = shards.stats
            return summary
    return _map_with(o, config, resume, overwrite, quiet, live, None)


def _map_with(o: OptionValues, config, resume: bool, overwrite: bool, quiet: bool, live, shards) -> dict:
    from ..mapping.pipeline import run_map

    seq, out = o["seq"], o["out"]
    if resume:
        target = out if out is not None else seq
        if target is None or (seq is not None and out is not None):
            raise PanovoccError("--resume takes only the output folder: panovocc map --resume OUT")
        given = [o.flags[n] for n in o.given if n not in ("seq", "out")] + (["--config"] if config is not None else [])
        if given:
            raise PanovoccError(f"--resume reuses the run's saved config; {', '.join(sorted(given))} cannot change it")
        return run_map(resume_out=target, progress=not quiet, observer=live, shards=shards)
    else:
        from_file = apply_config_file(o, config) if config is not None else set()
        seq, out = o["seq"], o["out"]
        if seq is None or out is None:
            raise PanovoccError("map needs SEQ and OUT (or --resume OUT)")
        if "segmenter" not in (o.given | from_file) and not (Path(seq) / "semantic").is_dir() and (Path(seq) / "meta.json").is_file():
            raise PanovoccError(f"{seq} has no ground-truth labels (semantic/) for the default simulated "
                                "segmenter: pass --segmenter clip (a CLIP model), --segmenter precomputed:DIR, or "
                                "--segmenter none (geometry only)")
        cfg = build_config(MapConfig, o, geometry=build_config(GeometryParams, o),
                           occupancy=build_config(OccupancyParams, o), semantic=build_config(SemanticParams, o),
                           ablation=build_config(AblationParams, o))
        if cfg.poses == POSES_SLAM:  # poses estimated online (slam/run.py); SEQ/poses.txt is never read
            if shards is not None:
                raise PanovoccError("--poses slam tracks the frames in order, in one process: it cannot be sharded "
                                    "(--workers/--scheduler)")
            from ..slam.run import run_map_slam

            return run_map_slam(cfg, overwrite=overwrite, progress=not quiet, observer=live)
        return run_map(cfg, overwrite=overwrite, progress=not quiet, observer=live, shards=shards)


def _report(summary: dict) -> None:
    classed = f", {summary['classed']} with a class" if "classed" in summary else ""
    if "corrected" in summary:
        classed += f", {summary['corrected']} pose corrections applied"
    seg = f", segmenter {summary['segmenter_ms_per_frame']:.1f} ms" if "segmenter_ms_per_frame" in summary else ""
    st = summary.get("shards")
    detail = f"update {summary['update_ms_per_frame']:.1f} ms{seg}"
    if st:  # the frames were read, segmented and integrated on the workers, not timed here
        detail = f"on the workers {1e3 * st['shard_cpu_s'] / max(st['frames'], 1):.1f} ms of CPU a frame"
    typer.echo(f"mapped {summary['integrated']} of {summary['frames']} frames, {summary['ms_per_frame']:.1f} ms/frame "
               f"({detail}): {summary['occupied']} occupied{classed}, "
               f"{summary['free']} free voxels -> {summary['out']}")
    if st:
        typer.echo(f"shards: {st['shards']} on {st['workers']} worker(s); sent back {st['record_bytes'] / 1e6:.1f} MB "
                   f"of delta records ({st['record_bytes'] / max(st['frames'], 1) / 1e6:.3f} MB a frame) and "
                   f"{st['partial_bytes'] / 1e6:.1f} MB of partial memories (to this process: {st['root_bytes'] / 1e6:.1f} MB of "
                   "sums)")
    if "compactions" in summary:
        c = summary["compactions"]
        typer.echo(f"delta log: {c['log_bytes'] / 1e6:.1f} MB; {c['count']} compaction(s) deleted {c['shards']} shard "
                   f"file(s), {c['freed_bytes'] / 1e6:.1f} MB, copying {c['copied_bytes'] / 1e6:.1f} MB of live records")
    if "slam" in summary:
        sl = summary["slam"]
        unplaced = sl["unplaced_frames"]
        shown = ", ".join(map(str, unplaced[:10])) + (", ..." if len(unplaced) > 10 else "")
        typer.echo(f"slam: {sl['placed']} of {sl['frames']} frames placed, {sl['track_ms_per_frame']:.1f} ms/frame, "
                   f"{sl['keyframes']} keyframes, {len(sl['loop_closures'])} loop closures, "
                   f"{len(sl['relocalised_frames'])} relocalised"
                   + (f"; could not place {len(unplaced)} frame(s): {shown}" if unplaced else ""))
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
    typer.echo(f"revised {s['revised']} of {s['frames']} frames in {s['seconds']:.2f} s (the revisions and their "
               f"records {s['revise_s']:.2f} s, {s['revise_cpu_s']:.2f} s CPU): {s['occupied']} occupied{classed}, "
               f"{s['free']} free voxels")


@app.command("compact")
def compact_cmd(out: Path = typer.Argument(..., metavar="OUT", help="A map folder (map, revise or merge output).")) -> None:
    """Drop the delta records no frame keeps any more (a revised frame's earlier poses, removed frames) from
    OUT/deltas: the map, its exports and the kept records do not change. Checkpoints and saves do this on
    their own once the dead records pass half the live ones; this does it now, for every shard."""
    from ..mapping.pipeline import run_compact

    s = run_compact(out)
    if s["after"] == s["before"]:
        typer.echo(f"nothing to compact: {s['frames']} frames, delta log {s['before'] / 1e6:.1f} MB in "
                   f"{s['shards']} shard file(s)")
        return
    typer.echo(f"compacted the delta log of {s['frames']} frames: {s['before'] / 1e6:.1f} MB -> "
               f"{s['after'] / 1e6:.1f} MB in {s['shards']} shard file(s)")


@config_command(app, SegevalConfig, "segeval")
def segeval(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """A segmenter's own per-frame 2D mIoU on a labelled sequence (pixel counts pooled over frames)."""
    import math

    from ..evaluation.run import run_segeval

    res, frames = run_segeval(SegevalConfig(**o), progress=not quiet)
    for (name, v), here in zip(res.iou.items(), res.present):
        shown = "-" if math.isnan(v) else f"{100 * v:5.1f}"
        typer.echo(f"  {name:<12} {shown}{'' if here else '  (absent from the ground truth, not in the mean)'}")
    typer.echo(f"2D mIoU ({o['classes']}, pooled over {len(frames)} frames): {100 * res.miou:.1f}%, "
               f"pixel accuracy {100 * res.accuracy:.1f}%")


@config_command(app, BenchConfig, "bench", only=("out", "frames", "width"))
def bench(o: OptionValues) -> None:
    """Mapper speed against Open3D VoxelBlockGrid TSDF fusion (cube faces) on the same frames."""
    from ..benchmark.bench import run_bench

    r = run_bench(BenchConfig(**o))
    typer.echo(r["line"])


def apply_config_file(o: OptionValues, path: Path) -> set:
    """Fill ``o`` from ``--config FILE``: a JSON object of map options by field name (the names of
    ``OUT/config.json``'s fields: ``kernel``, ``use_gsc``, ``use_rpu``, ``drift_rot_deg``, ``seq``, ...). A value
    given on the command line wins; an unknown name or a value outside its range is refused naming the file.
    Returns the names the file set."""
    import json

    from ..config import check_option, option_name
    from .options import option_specs

    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise PanovoccError("config file not found", path) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PanovoccError(f"not a JSON file ({type(e).__name__}: {e})", path) from None
    if not isinstance(d, dict):
        raise PanovoccError("expected a JSON object of map options by name", path)
    specs = {s.field: s for cls in (MapConfig, *MAP_SECTIONS) for s in option_specs(cls)}
    used = set()
    for key, value in d.items():
        spec = specs.get(key)
        if spec is None:
            raise PanovoccError(f"unknown map option {key!r} (expected field names such as {', '.join(sorted(specs)[:6])}, "
                                "...)", path)
        if key in o.given:
            continue
        if spec.opt.negate or isinstance(spec.default, bool):
            if not isinstance(value, bool):
                raise PanovoccError(f"{key} must be true or false, got {value!r}", path)
        elif value is not None:
            try:
                value = check_option(option_name(spec.field, spec.opt), spec.opt, value)
            except PanovoccError as e:
                raise PanovoccError(str(e), path) from None
            if spec.opt.parse is not None:
                value = spec.opt.parse(value)
        o[key] = value
        used.add(key)
    return used


@app.command("merge")
def merge_cmd(
    paths: List[Path] = typer.Argument(..., help="MAP_A MAP_B [MAP_C ...] OUT: map folders, then the merged map's "
                                       "folder."),
    transform: Path = typer.Option(None, "--transform", metavar="FILE", show_default=False,
                                   help="A 4x4 matrix (4 lines of 4 numbers) taking MAP_B's world into MAP_A's: "
                                        "MAP_B's frames are integrated again under it, in MAP_A's frame."),
    align: bool = typer.Option(False, "--align", help="Find --transform by registering MAP_B's occupied voxels onto "
                               "MAP_A's (the SLAM front end's GICP; from the identity, or from --transform)."),
    renumber: bool = typer.Option(False, "--renumber", help="Maps of separate captures: shift each map's frame ids "
                                  "past the previous maps' (else colliding ids are refused)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a map already in OUT."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """The exact sum of maps made with the same mapping parameters, vocabulary and origin: a map folder
    that exports, revises and merges like any other (docs/sharding.md)."""
    import numpy as np

    from ..mapping.merge import run_merge

    if len(paths) < 3:
        raise PanovoccError("expected MAP_A MAP_B [MAP_C ...] OUT")
    maps, out = paths[:-1], paths[-1]
    T = None
    if transform is not None:
        from ..io.poses import read_transform

        T = read_transform(transform)
    if align:
        from ..mapping.merge import occupied_points
        from ..slam.registration import register_points

        if len(maps) != 2:
            raise PanovoccError("--align registers the second of exactly two maps onto the first")
        T, fitness = register_points(occupied_points(maps[0]), occupied_points(maps[1]), T)
        typer.echo(f"--align: MAP_B registered onto MAP_A, fitness {fitness:.3f}, translation "
                   f"{np.round(T[:3, 3], 3).tolist()} m")
    s = run_merge(maps, out, overwrite=overwrite, transform=T, renumber=renumber, progress=not quiet)
    classed = f", {s['classed']} with a class" if "classed" in s else ""
    typer.echo(f"merged {s['maps']} maps ({s['frames']} frames): {s['occupied']} occupied{classed}, {s['free']} free "
               f"voxels -> {s['out']}")
