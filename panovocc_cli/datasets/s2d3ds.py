"""Stanford 2D-3D-S area -> toolkit sequence (``panovocc convert s2d3ds``), and the pose-convention check.

Each panorama of ``AREA/pano`` (with RGB, depth and pose; with ``pano/semantic`` also its labels) becomes one
frame, ordered by room then camera uuid. The panoramas keep their pixel grid (ERP, the toolkit's convention
is assumed: row 0 the zenith, longitude increasing to the right); depth is already radial (1/512 m, 65535
missing -> 0) and is written as float EXR (nothing lost); labels become ids into ``class_names`` =
``["unlabeled"]`` + the 13 classes (through :data:`~panovocc_cli.io.s2d3ds.CLASS_MAP`), missing pixels and
``<UNK>`` 0. Poses: :func:`~panovocc_cli.io.s2d3ds.pano_pose` under the chosen form and panorama yaw.

**The check** (``--check``, :mod:`.pose_check`): each panorama is paired with the nearest other panorama of
its room (by ``camera_location``, which every form shares), and the pairs' depth agreement is measured under
every pose form and yaw: the right convention is the one under which neighbouring panoramas' depth agrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError
from ..io.s2d3ds import PANO_YAWS_DEG, POSE_FORMS
from .pose_check import CHECK_PAIRS, convention_report


@dataclass
class ConvertS2d3dsConfig:
    """Options of ``panovocc convert s2d3ds``."""

    area: Path = option(argument=True, metavar="AREA_DIR",
                        help="A 2D-3D-S area folder (pano/rgb, pano/depth, pano/pose, optionally pano/semantic).")
    out: Path = option(argument=True, metavar="SEQ", help="Sequence folder to write (meta.json, rgb/, depth/, poses.txt).")
    pose_form: str = option("rt", choices=POSE_FORMS,
                            help="How a pose JSON makes the pose: rt (camera_rt_matrix, world-to-camera [R|t] of an "
                                 "OpenCV camera) or euler (camera_location + final_camera_rotation of a Blender camera).")
    pano_yaw_deg: int = option(0, min=0, max=270, help="Where the panorama's centre column looks, degrees about the "
                                                       "camera's vertical axis from its +z: 0, 90, 180 or 270.")
    labels_json: Path | None = option(None, help="The dataset's semantic_labels.json (default: searched in the area, "
                                                 "beside it, and in assets/ beside it).", show_default=False)
    semantic: bool = option(True, flag="--no-semantic", negate=True, help="Do not convert pano/semantic.")
    rooms: str | None = option(None, help="Comma-separated rooms to keep (e.g. office_1,office_2; default all).",
                               show_default=False)
    width: int = option(0, min=0, even=True, help="Resize panoramas to this width (even; 0 = keep).")
    check: bool = option(False, help="Report how well neighbouring panoramas' depth agrees under every pose form "
                                     "and yaw.")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous panovocc sequence in SEQ (never any other folder).")


def nearest_pairs(locations: np.ndarray, rooms: list[str], pairs: int = CHECK_PAIRS) -> list[tuple[int, int]]:
    """Each frame with the nearest other frame of its room (locations (n, 3) metres), each pair once, at most
    ``pairs`` of them evenly spread."""
    out = set()
    loc = np.asarray(locations, np.float64)
    for i in range(len(loc)):
        same = [j for j in range(len(loc)) if j != i and rooms[j] == rooms[i]]
        if same:
            j = min(same, key=lambda j: (float(np.linalg.norm(loc[j] - loc[i])), j))
            out.add((min(i, j), max(i, j)))
    out = sorted(out)
    if len(out) > pairs:
        out = [out[int(k)] for k in np.unique(np.linspace(0, len(out) - 1, pairs).round().astype(int))]
    return out


def run_convert_s2d3ds(cfg: ConvertS2d3dsConfig) -> dict:
    """Convert ``cfg.area`` into the sequence ``cfg.out`` (and run the check); returns a summary dict."""
    import cv2
    from tqdm import tqdm

    from ..classes import canonical_name
    from ..io.atomic import atomic_dir, check_output
    from ..io.images import read_rgb, write_exr, write_png
    from ..io.runconfig import CONFIG_NAME, write_run_config
    from ..io.s2d3ds import (CLASS_MAP, S2D3DS_CLASSES, find_labels_json, label_class, pano_pose, read_area,
                             read_depth, read_pose_json, read_semantic, read_semantic_labels)
    from ..io.sequence import SequenceMeta, frame_stem, write_meta, write_sequence_poses

    cfg = validate_config(cfg)
    if cfg.pano_yaw_deg not in PANO_YAWS_DEG:
        raise PanovoccError(f"--pano-yaw-deg must be one of {', '.join(map(str, PANO_YAWS_DEG))}, got {cfg.pano_yaw_deg}")
    check_output(cfg.out, "sequence", cfg.overwrite, inputs=(cfg.area, cfg.labels_json))
    semantic = cfg.semantic and (Path(cfg.area) / "pano" / "semantic").is_dir()
    area = read_area(cfg.area, ("rgb", "depth", "pose") + (("semantic",) if semantic else ()))
    keys = area.keys
    if cfg.rooms:
        want = {r.strip() for r in cfg.rooms.split(",") if r.strip()}
        have = {k[1] for k in keys}
        if want - have:
            raise PanovoccError(f"--rooms: {', '.join(sorted(want - have))} not found (rooms: {', '.join(sorted(have))})",
                                cfg.area)
        keys = [k for k in keys if k[1] in want]
    names = ["unlabeled"] + [CLASS_MAP[c] for c in S2D3DS_CLASSES]
    lut = None
    if semantic:
        labels = read_semantic_labels(cfg.labels_json if cfg.labels_json is not None else find_labels_json(cfg.area))
        classes = [canonical_name(label_class(x)) for x in labels]
        names += sorted({c for c in classes if c not in S2D3DS_CLASSES and c not in ("", "<unk>")})
        ids = {n: k for k, n in enumerate(names)}
        lut = np.array([ids.get(CLASS_MAP.get(c, c), 0) for c in classes] + [0], np.uint16)
    poses_json = [read_pose_json(area.files[k]["pose"]) for k in keys]
    poses = np.stack([pano_pose(p, cfg.pose_form, cfg.pano_yaw_deg) for p in poses_json])
    locations = np.stack([p["location"] for p in poses_json])
    rt_centres = np.stack([-p["rt"][:3, :3].T @ p["rt"][:3, 3] for p in poses_json])  # -R^T t
    pairs = nearest_pairs(locations, [k[1] for k in keys]) if cfg.check else []
    keep = {i for p in pairs for i in p}
    depths: dict[int, np.ndarray] = {}
    size = None
    with atomic_dir(cfg.out) as tmp:
        for sub in ("rgb", "depth") + (("semantic",) if semantic else ()):
            (tmp / sub).mkdir()
        for i, k in enumerate(tqdm(keys, desc="convert", unit="pano", disable=not cfg.progress)):
            f = area.files[k]
            rgb = read_rgb(f["rgb"])
            depth = read_depth(f["depth"])
            h, w = rgb.shape[:2]
            if w != 2 * h:
                raise PanovoccError(f"panorama is {w}x{h}, expected 2:1 (ERP)", f["rgb"])
            if depth.shape != (h, w):
                raise PanovoccError(f"depth is {depth.shape[1]}x{depth.shape[0]}, the RGB image {w}x{h}", f["depth"])
            lab = None
            if semantic:
                idx = read_semantic(f["semantic"])
                if idx.shape != (h, w):
                    raise PanovoccError(f"semantic is {idx.shape[1]}x{idx.shape[0]}, the RGB image {w}x{h}", f["semantic"])
                lab = lut[np.minimum(idx, len(lut) - 1)]
            if cfg.width and cfg.width != w:
                wh = (cfg.width, cfg.width // 2)
                rgb = cv2.resize(rgb, wh, interpolation=cv2.INTER_AREA)
                depth = cv2.resize(depth, wh, interpolation=cv2.INTER_NEAREST)
                if lab is not None:
                    lab = cv2.resize(lab, wh, interpolation=cv2.INTER_NEAREST)
            if size is None:
                size = rgb.shape[:2]
            elif rgb.shape[:2] != size:
                raise PanovoccError(f"panorama is {rgb.shape[1]}x{rgb.shape[0]}, the first one's {size[1]}x{size[0]} "
                                    "(pass --width to resize all)", f["rgb"])
            stem = frame_stem(i)
            write_png(tmp / "rgb" / f"{stem}.png", rgb)
            write_exr(tmp / "depth" / f"{stem}.exr", depth)
            if lab is not None:
                write_png(tmp / "semantic" / f"{stem}.png", lab.astype(np.uint16))
            if i in keep:
                depths[i] = depth
        H, W = size
        report = None
        if cfg.check:
            frames = sorted(keep)
            candidates = {f"{form}/yaw{yaw}": {i: pano_pose(poses_json[i], form, yaw) for i in frames}
                          for form in POSE_FORMS for yaw in PANO_YAWS_DEG}
            report = convention_report(depths, candidates, pairs, f"{cfg.pose_form}/yaw{cfg.pano_yaw_deg}")
            if report["best"]:
                form, yaw = report["best"].split("/yaw")
                report["hint"] = f"--pose-form {form} --pano-yaw-deg {yaw}"
        meta = SequenceMeta(width=W, height=H, frames=len(keys), camera="erp", class_names=names,
                            extra={"s2d3ds": {"area": str(cfg.area), "pose_form": cfg.pose_form,
                                              "pano_yaw_deg": cfg.pano_yaw_deg,
                                              "panoramas": [f"{u} {r}" for u, r in keys], "skipped": area.skipped,
                                              "rt_location_max_diff_m": float(np.abs(rt_centres - locations).max()),
                                              **({"check": report} if report is not None else {})}})
        write_meta(tmp, meta)
        write_sequence_poses(tmp, poses)
        write_run_config(tmp / CONFIG_NAME, cfg)
    return {"frames": len(keys), "width": W, "height": H, "rooms": sorted({k[1] for k in keys}),
            "skipped": area.skipped, "check": report,
            "rt_location_max_diff_m": float(np.abs(rt_centres - locations).max())}
