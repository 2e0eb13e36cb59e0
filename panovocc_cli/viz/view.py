"""``panovocc view MAP``: a finished map folder in Rerun.

What is logged (entity layout in :mod:`.rerun_log`): the map's grid ``MAP/prediction.npz`` (occupied voxels
as boxes coloured by class, with the class table as an annotation context and a markdown legend; free
voxels as points with ``--free``), the trajectory and a frustum a panorama from ``MAP/poses.txt``, on the
``frame`` timeline each frame's pose and (every ``pano_stride``-th frame) its panorama and depth read from
the sequence named in ``MAP/config.json``, and with ``--gt`` the difference to a ground-truth grid.

Where it goes: ``--out FILE.rrd``; else a native viewer when a display is there (``DISPLAY`` or
``WAYLAND_DISPLAY``); else ``MAP.rrd`` beside the map folder. An ``.rrd`` is written under a temporary name
and renamed, with its config beside it (``FILE.config.json``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError

MAX_PANORAMAS = 100
"""Default: at most this many panoramas are logged (evenly spread) unless --pano-stride is given."""


@dataclass
class ViewConfig:
    """Options of ``panovocc view``."""

    map: Path = option(argument=True, metavar="MAP", help="A map folder written by panovocc map.")
    out: Path | None = option(None, help="Write the recording to this .rrd file (default: open a viewer when "
                                         "there is a display, else MAP.rrd beside the map folder).",
                              show_default=False)
    gt: Path | None = option(None, help="Ground-truth grid .npz: also show the difference (false positives red, "
                                        "false negatives blue, wrong class orange).", show_default=False)
    free: bool = option(False, help="Also show the observed free voxels (grey points).")
    cut_top: int = option(0, min=0, help="Leave out the top K voxel layers (to look into rooms), as show --cut-top.")
    pano_stride: int = option(0, min=0, help="Log the panorama and depth of every k-th frame (0 = evenly spread, "
                                             f"at most {MAX_PANORAMAS}).")
    pano_width: int = option(512, min=0, help="Subsample panoramas to at most this width in pixels (0 = full size).")
    no_images: bool = option(False, flag="--no-images", help="Do not read the sequence's panoramas at all.")
    overwrite: bool = option(False, help="Replace an existing .rrd file.")


def has_display() -> bool:
    """Whether a native viewer window can open (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def default_rrd(map_dir: str | Path) -> Path:
    """``MAP.rrd`` beside the map folder."""
    m = Path(map_dir)
    return m.parent / (m.resolve().name + ".rrd")


def read_map_folder(map_dir: str | Path):
    """(MapConfig, prediction Grid, poses (n, 4, 4) float64) of a finished map folder.

    Raises
    ------
    PanovoccError (one line) when the folder is not a panovocc map or the run did not finish.
    """
    from ..io.atomic import is_output_of_kind
    from ..io.grid import read_grid
    from ..io.poses import read_poses
    from ..mapping.pipeline import load_config

    m = Path(map_dir)
    if not m.is_dir():
        raise PanovoccError("map folder not found", m)
    if not is_output_of_kind(m, "map"):
        raise PanovoccError("not a panovocc map folder (expected config.json with a geometry section, "
                            "prediction.npz and poses.txt, as panovocc map writes them)", m)
    if not (m / "prediction.npz").is_file():
        raise PanovoccError("prediction.npz not found: the map run did not finish (panovocc map --resume)", m)
    cfg = load_config(m)
    grid = read_grid(m / "prediction.npz")
    poses = read_poses(m / "poses.txt") if (m / "poses.txt").is_file() else np.zeros((0, 4, 4))
    return cfg, grid, poses


def pano_frames(n: int, stride: int) -> list[int]:
    """The frames whose panoramas are logged: every ``stride``-th, or (0) at most MAX_PANORAMAS evenly spread."""
    if n <= 0:
        return []
    if stride <= 0:
        stride = max(1, int(np.ceil(n / MAX_PANORAMAS)))
    return list(range(0, n, stride))


def run_view(cfg: ViewConfig, spawn: bool | None = None, progress: bool = False) -> dict:
    """Log the map ``cfg.map`` to an ``.rrd`` file or a viewer; returns a summary dict.

    spawn : open a native viewer (None: when :func:`has_display` and no ``--out``)
    """
    from tqdm import tqdm

    from ..io.atomic import atomic_path
    from ..io.grid import read_grid
    from ..io.runconfig import check_file_output, write_run_config
    from . import rerun_log as rl

    cfg = validate_config(cfg)
    rl.require_rerun()
    map_cfg, grid, poses = read_map_folder(cfg.map)
    gt = read_grid(cfg.gt) if cfg.gt is not None else None
    if spawn is None:
        spawn = cfg.out is None and has_display()
    out = None if spawn else Path(cfg.out) if cfg.out is not None else default_rrd(cfg.map)
    if out is not None:
        if out.suffix != ".rrd":
            raise PanovoccError("expected a .rrd file name (Rerun's recording format)", out)
        config_path = check_file_output(out, "recording", cfg.overwrite, inputs=(cfg.map, cfg.gt))
    seq = None
    note = ""
    if not cfg.no_images and len(poses):
        from ..io.sequence import Sequence

        try:
            seq = Sequence(map_cfg.seq, poses=poses)
        except PanovoccError as e:
            note = f"panoramas not shown ({e})"
    frames = pano_frames(len(poses), cfg.pano_stride) if seq is not None else []
    summary = {"map": str(cfg.map), "out": str(out) if out is not None else "viewer", "frames": len(poses),
               "panoramas": len(frames), "note": note}

    z_keep = None
    if cfg.cut_top:
        from ..evaluation.render_grid import drawing_box

        z_keep = drawing_box([grid] + ([gt] if gt is not None else []), cfg.cut_top)[2]
    shown = rl.cut_top(grid, z_keep)
    eye = rl.overview_eye(shown)

    def log_all(rec):
        summary.update(rl.log_grid(rec, shown, free=cfg.free))
        rl.log_markdown(rec, "legend", rl.legend_markdown(grid, f"Classes of {Path(cfg.map).name}"))
        rl.log_poses(rec, poses)
        if gt is not None:
            summary["difference"] = rl.log_difference(rec, shown, rl.cut_top(gt, z_keep))
        want = set(frames)
        for i in tqdm(range(len(poses)), desc="view", unit="frame", disable=not progress):
            rec.set_time(rl.TIMELINE, sequence=i)
            rl.log_camera(rec, poses[i])
            if i in want:
                rl.log_frame_images(rec, seq.rgb(i), seq.depth(i), max_width=cfg.pano_width)
        if note:
            rl.log_text(rec, note, level="WARN")

    if out is None:
        rec = rl.open_stream(spawn=True, eye=eye)
        log_all(rec)
        rec.flush()
        return summary
    with atomic_path(out) as tmp:
        rec = rl.open_stream(rrd=tmp, eye=eye)
        try:
            log_all(rec)
        finally:
            rec.flush()
            rec.disconnect()
    write_run_config(config_path, cfg)
    return summary
