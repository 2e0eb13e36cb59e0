"""Holo360D scene -> toolkit sequence (``panovocc convert holo360d``), and the pose-convention check.

The conversion keeps the panoramas as they are (ERP, the same pixel grid), writes depth as float EXR
(metres, radial; nothing lost), and turns each pose line into ``T_world_cam`` under the chosen pose form
(:func:`panovocc_cli.io.holo360d.holo_pose`).

**The check** (``--check``): a pose convention is right when it makes overlapping frames' depth agree.
For pairs of frames (each frame with the next in time order), the depth points of one frame are moved
into the other's camera with the two poses and projected into its panorama; a point *agrees* when its
range is within ``max(CHECK_TOL_M, CHECK_TOL_REL * depth)`` of the depth measured at one of the four pixel
centres around its projection. The agreement
(percent of points that land on valid depth) is computed for the chosen form and, for comparison, for
every form and camera-axes choice; a wrong convention moves the points to the wrong place and its
agreement drops. With frames that barely move every convention agrees; the report gives the pairs'
median baseline and rotation so that case is visible.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError
from ..io.holo360d import CAMERA_AXES, DEPTH_KINDS, POSE_FORMS, holo_pose

CHECK_TOL_M = 0.05
"""Metres: the smallest range difference at which two frames' depth disagree (the check)."""
CHECK_TOL_REL = 0.02
"""Fraction of the range added to the check's tolerance (depth error grows with range)."""
CHECK_PAIRS = 24
"""At most this many frame pairs are compared (evenly spread over the sequence)."""
CHECK_SAMPLES = 20000
"""Depth points drawn (a regular pixel grid) from each frame of a pair."""


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


def depth_agreement(depth_a: np.ndarray, T_a: np.ndarray, depth_b: np.ndarray, T_b: np.ndarray,
                    samples: int = CHECK_SAMPLES, tol_m: float = CHECK_TOL_M,
                    tol_rel: float = CHECK_TOL_REL) -> tuple[int, int]:
    """How many of frame b's depth points agree with frame a's depth.

    Parameters
    ----------
    depth_a, depth_b : (H, W) float, metres, radial, 0 = invalid (ERP, same size)
    T_a, T_b : (4, 4) float64 T_world_cam
    samples : about this many pixels of b are used (a regular grid)

    Returns
    -------
    agree : points of b whose range in a's camera is within ``max(tol_m, tol_rel * depth_a)`` of a's depth
    compared : points of b that land on a valid depth pixel of a
    """
    from ..geometry.erp import backproject, project, project_to_pixel, ray_directions

    H, W = depth_b.shape
    step = max(1, int(np.sqrt(H * W / max(1, samples))))
    rays = ray_directions(W, H)[::step, ::step]
    d = np.asarray(depth_b, dtype=np.float64)[::step, ::step]
    ok = d > 0
    p_b = backproject(d, rays)[ok]
    T = np.linalg.inv(T_a) @ T_b
    p_a = p_b @ T[:3, :3].T + T[:3, 3]
    u, v, r = project(p_a, W, H)
    row, col, _ = project_to_pixel(p_a, W, H)
    dA = np.asarray(depth_a, dtype=np.float64)
    valid = dA[row, col] > 0
    agree = np.zeros(len(r), bool)
    for dv in (0, 1):  # any of the four pixel centres around the projection (the panorama is sampled)
        for du in (0, 1):
            rr = np.clip(np.floor(v).astype(np.int64) + dv, 0, H - 1)
            cc = (np.floor(u).astype(np.int64) + du) % W
            d = dA[rr, cc]
            agree |= (d > 0) & (np.abs(r - d) <= np.maximum(tol_m, tol_rel * d))
    agree &= valid
    return int(agree.sum()), int(valid.sum())


def check_pairs(n: int, pairs: int = CHECK_PAIRS) -> list[tuple[int, int]]:
    """Frame pairs (i, i + 1) of an n-frame sequence, at most ``pairs`` of them, evenly spread."""
    if n < 2:
        return []
    first = np.unique(np.linspace(0, n - 2, min(pairs, n - 1)).round().astype(int))
    return [(int(i), int(i) + 1) for i in first]


def pose_check(depths: dict[int, np.ndarray], lines: list[tuple[np.ndarray, np.ndarray]],
               pairs: list[tuple[int, int]], form: str, axes: str) -> dict:
    """Agreement of the pairs' depth under every pose form and axes choice.

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
    scores = {}
    for f in POSE_FORMS:
        for a in CAMERA_AXES:
            T = {i: holo_pose(*lines[i], f, a) for p in pairs for i in p}
            agree = compared = 0
            for i, j in pairs:
                x, n = depth_agreement(depths[i], T[i], depths[j], T[j])
                y, m = depth_agreement(depths[j], T[j], depths[i], T[i])
                agree, compared = agree + x + y, compared + n + m
            scores[f"{f}/{a}"] = 100.0 * agree / compared if compared else float("nan")
    T = {i: holo_pose(*lines[i], form, axes) for p in pairs for i in p}
    base, rot = [], []
    for i, j in pairs:
        rel = np.linalg.inv(T[i]) @ T[j]
        base.append(float(np.linalg.norm(rel[:3, 3])))
        rot.append(float(np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1) / 2, -1, 1)))))
    finite = {k: v for k, v in scores.items() if np.isfinite(v)}
    chosen = f"{form}/{axes}"
    return {"chosen": chosen, "agreement": scores[chosen], "all": scores,
            "best": max(finite, key=finite.get) if finite else None,
            "median_baseline_m": float(np.median(base)) if base else float("nan"),
            "median_rotation_deg": float(np.median(rot)) if rot else float("nan"), "pairs": len(pairs)}


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
