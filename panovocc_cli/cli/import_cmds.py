"""Commands: ``convert rosbag`` (a ROS 1 / ROS 2 recording -> a sequence) and ``convert s2d3ds`` (a Stanford
2D-3D-S area's panoramas -> a sequence, its annotated point clouds -> a ground-truth grid).

Registered on the ``convert`` group of :mod:`panovocc_cli.cli.eval_cmds` (imported first, COMMAND_MODULES)."""

from __future__ import annotations

import typer

from ..datasets.rosbag import ConvertRosbagConfig
from ..datasets.s2d3ds import ConvertS2d3dsConfig
from ..gt_config import S2d3dsGtConfig
from .eval_cmds import convert_app
from .options import OptionValues, config_command


@config_command(convert_app, ConvertRosbagConfig, "rosbag")
def convert_rosbag_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Convert an ERP RGB-D recording in a ROS 1 or ROS 2 bag into a sequence: depth and colour images paired by
    time within --max-dt, each given the camera pose at its time (--poses TOPIC or --tf PARENT:CHILD)."""
    from ..datasets.rosbag import run_convert_rosbag

    s = run_convert_rosbag(ConvertRosbagConfig(**o, progress=not quiet))
    typer.echo(f"{o['out']}: {s['frames']} frames {s['width']}x{s['height']}")
    typer.echo(f"pairing: {s['depth']} depth and {s['rgb']} colour images, {s['paired']} pairs within --max-dt "
               f"(median {s['dt_median_ms']:.1f} ms, max {s['dt_max_ms']:.1f} ms apart); unpaired: "
               f"{s['unpaired_depth']} depth, {s['unpaired_rgb']} colour; dropped: {s['no_pose']} without a pose"
               + (f", {s['no_labels']} without a label image" if o["labels"] else ""))


@config_command(convert_app, ConvertS2d3dsConfig, "s2d3ds")
def convert_s2d3ds_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Convert a Stanford 2D-3D-S area's panoramas (pano/rgb, pano/depth, pano/semantic, pano/pose) into a sequence;
    --check reports how well neighbouring panoramas' depth agrees under each pose convention."""
    from ..datasets.s2d3ds import run_convert_s2d3ds

    s = run_convert_s2d3ds(ConvertS2d3dsConfig(**o, progress=not quiet))
    typer.echo(f"{o['out']}: {s['frames']} panoramas {s['width']}x{s['height']} from {len(s['rooms'])} rooms"
               + (f", {len(s['skipped'])} skipped (a modality missing: {s['skipped'][0]}"
                  + (", ..." if len(s['skipped']) > 1 else "") + ")" if s["skipped"] else ""))
    typer.echo(f"poses: camera_rt_matrix's centre and camera_location differ by at most "
               f"{s['rt_location_max_diff_m']:.3f} m")
    c = s.get("check")
    if c is not None:
        from .holo_cmds import echo_check

        echo_check(c)


@config_command(convert_app, S2d3dsGtConfig, "s2d3ds-gt")
def convert_s2d3ds_gt_cmd(o: OptionValues, quiet: bool = typer.Option(False, "--quiet", help="No progress bar.")) -> None:
    """Ground truth of a 2D-3D-S / S3DIS area from its annotated point clouds (ROOM/Annotations/<class>_<k>.txt):
    occupied where points fall, the class with the most points, on the global lattice (the rules of panovocc gt)."""
    from ..gt.s2d3ds import run_s2d3ds_gt

    s = run_s2d3ds_gt(S2d3dsGtConfig(**o, progress=not quiet))
    typer.echo(f"{s['path']}: {s['occupied']} occupied voxels from {s['points']} points in {s['rooms']} rooms"
               + (f" ({s['skipped_lines']} malformed lines skipped)" if s["skipped_lines"] else ""))
    typer.echo("classes: " + ", ".join(f"{k} {v}" for k, v in s["classes"].items()))
