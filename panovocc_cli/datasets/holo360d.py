"""Holo360D scene -> toolkit sequence (``panovocc convert holo360d``), and the pose-convention check.

The conversion keeps the panoramas as they are (ERP, the same pixel grid), writes depth as float EXR
(metres, radial; nothing lost), and turns each pose line into ``T_world_cam`` under the chosen pose form
(:func:`panovocc_cli.io.holo360d.holo_pose`).

**The check** (``--check``, :mod:`.pose_check`): for pairs of frames (each frame with the next in time
order) the depth of one is moved into the other's panorama under the chosen pose form and, for comparison,
under every form and camera-axes choice; the agreement of the depth says which convention is right.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError
from ..io.holo360d import CAMERA_AXES, DEPTH_KINDS, POSE_FORMS, holo_pose
from .pose_check import (CHECK_PAIRS, CHECK_SAMPLES, CHECK_TOL_M, CHECK_TOL_REL, check_pairs,  # noqa: F401
                         convention_report, depth_agreement)


#: Bytes a converted pixel holds at once: RGB (3) and float depth (4), their resized copies, and the PNG and
#: EXR encoders' buffers (the estimate of ``--width``'s memory check).
BYTES_PER_PIXEL = 16


@dataclass
class ConvertHolo360dConfig:
    """Options of ``panovocc convert holo360d``."""

    scene: Path = option(argument=True, metavar="SCENE_DIR",
                         help="Holo360D scene folder (rgb/, depth/mesh_depth/, depth/pointcloud_depth/, mask/, poses/).")
    out: Path = option(argument=True, metavar="SEQ", help="Sequence folder to write (meta.json, rgb/, depth/, poses.txt).")
    pose_form: str = option("rt-c2w", choices=POSE_FORMS,
                            help="How a pose line's R, t make the pose: rt-c2w ([[R.T, t]] camera-to-world, the "
                                 "authors' reader), r-c2w ([[R, t]]), rt-w2c / r-w2c (world-to-camera).")
    camera_axes: str = option("holo", choices=CAMERA_AXES,
                              help="The camera frame of the poses: holo (z up; converted to the toolkit's OpenCV "
                                   "frame) or opencv (already the toolkit's).")
    depth: str = option("mesh", choices=DEPTH_KINDS, help="Depth to use: mesh (depth/mesh_depth) or pointcloud.")
    mask: bool = option(True, flag="--no-mask", negate=True,
                        help="Do not zero depth where mask/<stem>.jpg is dark.")
    width: int = option(0, min=0, even=True, help="Resize panoramas to this width (even; 0 = keep).")
    check: bool = option(False, help="Fuse overlapping frames' depth under the pose form and report their "
                                     "agreement, beside every other form's.")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous panovocc sequence in SEQ (never any other folder).")


def pose_check(depths: dict[int, np.ndarray], lines: list[tuple[np.ndarray, np.ndarray]],
               pairs: list[tuple[int, int]], form: str, axes: str) -> dict:
    """Agreement of the pairs' depth under every pose form and axes choice (:func:`.pose_check.convention_report`).

    Parameters
    ----------
    depths : frame index -> (H, W) float32 metres, for every frame of ``pairs``
    lines : per frame, the pose line's (t, R)
    pairs : (i, j) frame indices
    form, axes : the chosen convention

    Returns
    -------
    dict: ``chosen`` "form/axes", ``agreement`` percent for it, ``all`` {"form/axes": percent}, ``best``,
    ``median_baseline_m``, ``median_rotation_deg`` of the pairs (under the chosen convention), ``pairs``.
    """
    frames = sorted({i for p in pairs for i in p})
    candidates = {f"{f}/{a}": {i: holo_pose(*lines[i], f, a) for i in frames} for f in POSE_FORMS for a in CAMERA_AXES}
    return convention_report(depths, candidates, pairs, f"{form}/{axes}")


def run_convert_holo360d(cfg: ConvertHolo360dConfig) -> dict:
    """Convert ``cfg.scene`` into the sequence ``cfg.out`` (and run the check); returns a summary dict."""
    import cv2
    from tqdm import tqdm

    from ..io.atomic import atomic_dir, check_output
    from ..io.holo360d import read_holo_frame, read_holo_scene
    from ..io.images import write_exr, write_png
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from ..io.sequence import SequenceMeta, frame_stem, write_meta, write_sequence_poses

    cfg = validate_config(cfg)
    check_output(cfg.out, "sequence", cfg.overwrite, inputs=(cfg.scene,))
    scene = read_holo_scene(cfg.scene, cfg.depth)
    lines = [scene.poses[s] for s in scene.stems]
    poses = np.stack([holo_pose(t, R, cfg.pose_form, cfg.camera_axes) for t, R in lines])
    pairs = check_pairs(len(scene.stems)) if cfg.check else []
    keep = {i for p in pairs for i in p}
    if cfg.width:  # a resized frame (and every depth the check keeps) must fit before anything is written
        from ..runtime import check_memory

        pixels = float(cfg.width) * (cfg.width // 2)
        check_memory(pixels * (BYTES_PER_PIXEL + 4 * len(keep)), f"--width {cfg.width} ({cfg.width}x{cfg.width // 2}"
                     f" panoramas{', ' + str(len(keep)) + ' depths kept for --check' if keep else ''})",
                     "choose a smaller --width")
    depths: dict[int, np.ndarray] = {}
    size = None
    with atomic_dir(cfg.out) as tmp:
        (tmp / "rgb").mkdir()
        (tmp / "depth").mkdir()
        for i, s in enumerate(tqdm(scene.stems, desc="convert", unit="frame", disable=not cfg.progress)):
            rgb, depth = read_holo_frame(scene, s, cfg.mask)
            if cfg.width and cfg.width != rgb.shape[1]:
                wh = (cfg.width, cfg.width // 2)
                rgb = cv2.resize(rgb, wh, interpolation=cv2.INTER_AREA)
                depth = cv2.resize(depth, wh, interpolation=cv2.INTER_NEAREST)
            if size is None:
                size = rgb.shape[:2]
            elif rgb.shape[:2] != size:
                raise PanovoccError(f"panorama is {rgb.shape[1]}x{rgb.shape[0]}, the first frame's "
                                    f"{size[1]}x{size[0]} (pass --width to resize all)", scene.rgb[s])
            write_png(tmp / "rgb" / f"{frame_stem(i)}.png", rgb)
            write_exr(tmp / "depth" / f"{frame_stem(i)}.exr", depth)
            if i in keep:
                depths[i] = depth
        H, W = size
        meta = SequenceMeta(width=W, height=H, frames=len(scene.stems), camera="erp",
                            extra={"holo360d": {"scene": str(cfg.scene), "pose_form": cfg.pose_form,
                                                "camera_axes": cfg.camera_axes, "depth": cfg.depth,
                                                "stems": scene.stems, "skipped": scene.skipped}})
        report = pose_check(depths, lines, pairs, cfg.pose_form, cfg.camera_axes) if cfg.check else None
        if report is not None:
            meta.extra["holo360d"]["check"] = report
        write_meta(tmp, meta)
        write_sequence_poses(tmp, poses)
        write_run_config(tmp / CONFIG_NAME, cfg)
    return {"frames": len(scene.stems), "width": W, "height": H, "skipped": scene.skipped, "check": report}
