"""The views stage: each panorama of a sequence -> twelve pinhole views, written as twelve pinhole sequences.

Maths (no files): :class:`ViewSampler` holds, for one rig and one ERP size, where each view pixel's ray
meets the panorama; :meth:`ViewSampler.split` turns one ERP frame into the views' RGB (bilinear), z-depth
and labels (nearest neighbour: no value is ever blended across an edge). :func:`run_views` reads a
sequence and writes ``OUT/views.json`` plus one pinhole sequence folder per view (docs/views.md).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..config import option, validate_config
from ..errors import PanovoccError
from ..geometry.cameras import TWELVE_PITCH_DEG, ViewRig

#: Marker file of a views output folder (``io.atomic.OUTPUT_MARKERS["views"]``).
VIEWS_JSON = "views.json"


class ViewSampler:
    """Lookup tables from every pixel of every view of ``rig`` to the ERP image of ``width`` x ``width / 2``.

    Attributes
    ----------
    u, v : (V, h, w) float64, continuous ERP column / row hit by each view pixel's ray (the centre of ERP
        pixel (i, j) is (i, j); ``u`` in [-0.5, W - 0.5))
    col, row : (V, h, w) int64, the ERP pixel containing that point (nearest neighbour; column wrapped)
    z_per_r : (V, h, w) float64, z-depth per metre of radial depth along each view pixel's ray

    Memory: 40 bytes a view pixel (12 views of 1024 x 1024: 0.5 GB; of 4096 x 4096, the largest
    ``--size``: 8 GB).
    """

    def __init__(self, rig: ViewRig, width: int):
        from ..geometry.erp import check_erp_size, project

        self.rig = rig
        self.width, self.height = check_erp_size(width)
        us, vs, zr = [], [], []
        for view in rig:
            rays_view = view.camera.rays()                      # (h, w, 3) unit, view frame
            rays_cam = rays_view @ view.R_cam_view.T            # the same rays in the panorama's frame
            u, v, _ = project(rays_cam, self.width, self.height)
            us.append(u)
            vs.append(v)
            zr.append(rays_view[..., 2])
        self.u, self.v, self.z_per_r = np.stack(us), np.stack(vs), np.stack(zr)
        self.u = np.where(self.u >= self.width - 0.5, self.u - self.width, self.u)  # atan2's +pi edge
        self.col = np.floor(self.u + 0.5).astype(np.int64) % self.width
        self.row = np.clip(np.floor(self.v + 0.5).astype(np.int64), 0, self.height - 1)

    def nearest(self, image: np.ndarray) -> np.ndarray:
        """Nearest-neighbour views ``(V, h, w, ...)`` of an ERP image ``(H, W, ...)`` (any dtype, values kept)."""
        return np.asarray(image)[self.row, self.col]

    def bilinear(self, image: np.ndarray) -> np.ndarray:
        """Bilinear views ``(V, h, w, C)`` float64 of an ERP image ``(H, W, C)``; longitude wraps around, rows
        beyond the poles repeat the first / last row."""
        img = np.asarray(image, dtype=np.float64)
        u0 = np.floor(self.u)
        v0 = np.floor(self.v)
        fu = (self.u - u0)[..., None]
        fv = (self.v - v0)[..., None]
        c0 = u0.astype(np.int64) % self.width
        c1 = (c0 + 1) % self.width
        r0 = np.clip(v0.astype(np.int64), 0, self.height - 1)
        r1 = np.clip(v0.astype(np.int64) + 1, 0, self.height - 1)
        top = img[r0, c0] * (1.0 - fu) + img[r0, c1] * fu
        bot = img[r1, c0] * (1.0 - fu) + img[r1, c1] * fu
        return top * (1.0 - fv) + bot * fv

    def split(self, rgb: np.ndarray | None, depth: np.ndarray, labels: np.ndarray | None = None):
        """One ERP frame -> its views.

        Parameters
        ----------
        rgb : (H, W, 3) uint8 or None; depth : (H, W) float, metres, radial, 0 = invalid;
        labels : (H, W) int class ids or None

        Returns
        -------
        rgb_views : (V, h, w, 3) uint8 (bilinear, rounded) or None
        depth_views : (V, h, w) float64, metres, **z-depth** of each view (nearest ERP pixel's radial depth
            along the view pixel's ray), 0 = invalid
        label_views : (V, h, w) int64 (nearest neighbour) or None
        """
        d = np.asarray(depth, dtype=np.float64)
        if d.shape != (self.height, self.width):
            raise PanovoccError(f"depth is {d.shape[1]}x{d.shape[0]}, expected {self.width}x{self.height}")
        z = self.nearest(d) * self.z_per_r
        out_rgb = None
        if rgb is not None:
            out_rgb = np.clip(np.floor(self.bilinear(rgb) + 0.5), 0, 255).astype(np.uint8)
        out_lab = None if labels is None else self.nearest(np.asarray(labels, dtype=np.int64))
        return out_rgb, z, out_lab


@dataclass
class ViewsConfig:
    """Options of ``panovocc views``, declared once (help with units, ranges: cli/options.py reads them).

    seq: panoramic (ERP) sequence folder to read; out: folder to write (views.json, config.json and twelve
    pinhole sequences); fov_deg: field of view of every view, degrees; size: view width = height in pixels
    (None: W / 4, the panorama's angular resolution at the view centre for a 90-degree view); pitch_deg:
    elevation of the upper and lower rows, degrees; overwrite: replace a previous views output in ``out``.
    """

    seq: Path = option(argument=True, metavar="SEQ", help="Panoramic (ERP) sequence folder to split (meta.json, "
                       "rgb/, depth/, poses.txt; semantic/ carried when present).")
    out: Path = option(argument=True, metavar="OUT", help="Folder to write: views.json, config.json and twelve "
                       "pinhole sequences view_NN_azAAA_{up,mid,down}/.")
    fov_deg: float = option(90.0, min=10.0, max=170.0, help="Horizontal = vertical field of view of every view, "
                            "degrees.")
    size: int | None = option(None, min=8, max=4096, show_default="ERP width / 4",
                              help="View width = height in pixels (lookup tables: 40 bytes a view pixel).")
    pitch_deg: float = option(TWELVE_PITCH_DEG, min=0.0, max=90.0, help="Pitch of the upper (+) and lower (-) "
                              "rows, degrees.")
    progress: bool = True
    overwrite: bool = option(False, help="Replace a previous panovocc views output in OUT (never any other "
                             "folder, never an input).")

    def check(self) -> None:
        """Raise :class:`PanovoccError` on an option outside its declared range (for calls from Python)."""
        validate_config(self)

def rig_for(cfg: ViewsConfig, erp_width: int) -> ViewRig:
    """The twelve-view rig of ``cfg`` for panoramas ``erp_width`` pixels wide."""
    size = cfg.size if cfg.size is not None else max(8, erp_width // 4)
    return ViewRig.twelve(size, math.radians(cfg.fov_deg), math.radians(cfg.pitch_deg))


def run_views(cfg: ViewsConfig) -> dict:
    """Split every frame of ``cfg.seq`` into twelve pinhole views written under ``cfg.out``; returns a summary.

    Writes ``OUT/config.json`` (the config as given, io/runconfig.py), ``OUT/views.json`` (the resolved
    config, the source, each view's name, direction, intrinsics and ``T_cam_view``) and one pinhole
    sequence per view (CONVENTIONS.md layout: meta.json with
    ``"camera": "pinhole"`` and fx, fy, cx, cy; rgb/, depth/ z-depth, semantic/ when the source has labels;
    poses.txt ``T_world_view = T_world_cam @ T_cam_view``). The folder is built aside and renamed whole.
    """
    import time

    from tqdm import tqdm

    from ..config import DEPTH_SCALE
    from ..io.atomic import atomic_dir, check_output, write_text
    from ..io.images import write_png
    from ..io.runconfig import CONFIG_NAME, RUNTIME_ONLY, write_run_config
    from ..io.sequence import Sequence, SequenceMeta, frame_images, write_meta, write_sequence_poses

    cfg = validate_config(cfg)  # the ranges declared above (config.py option)
    seq = Sequence(cfg.seq)
    if seq.meta.camera != "erp":
        raise PanovoccError(f"camera is {seq.meta.camera!r}; views splits panoramic (erp) sequences",
                            Path(cfg.seq) / "meta.json")
    check_output(cfg.out, "views", cfg.overwrite, inputs=(cfg.seq,))
    seq.check_files(("depth", "rgb") + (("semantic",) if seq.has_labels else ()))
    rig = rig_for(cfg, seq.meta.width)
    sampler = ViewSampler(rig, seq.meta.width)
    cam = rig[0].camera
    n = len(seq)
    t0 = time.perf_counter()
    resolved = {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items() if k not in RUNTIME_ONLY}
    resolved["size"] = cam.width
    views_doc = {
        "config": resolved,
        "source": {"seq": str(cfg.seq), "width": seq.meta.width, "height": seq.meta.height, "frames": n},
        "pose": "T_world_view = T_world_cam @ T_cam_view (poses.txt of each view)",
        "views": [{"name": v.name, "azimuth_deg": round(math.degrees(v.azimuth_rad), 9),
                   "pitch_deg": round(math.degrees(v.pitch_rad), 9), "width": cam.width, "height": cam.height,
                   **cam.intrinsics(), "T_cam_view": v.T_cam_view.tolist()} for v in rig],
    }
    valid = 0.0
    with atomic_dir(cfg.out) as tmp:
        for k, view in enumerate(rig):
            folder = tmp / view.name
            for d in ("rgb", "depth") + (("semantic",) if seq.has_labels else ()):
                (folder / d).mkdir(parents=True)
            meta = SequenceMeta(width=cam.width, height=cam.height, frames=n, camera="pinhole",
                                depth_scale=DEPTH_SCALE, class_names=list(seq.meta.class_names),
                                fx=cam.fx, fy=cam.fy, cx=cam.cx, cy=cam.cy,
                                extra={"views": {"source": str(cfg.seq), "view": k, "name": view.name,
                                                 "azimuth_deg": views_doc["views"][k]["azimuth_deg"],
                                                 "pitch_deg": views_doc["views"][k]["pitch_deg"],
                                                 "fov_deg": cfg.fov_deg,
                                                 "T_cam_view": view.T_cam_view.tolist()}})
            write_meta(folder, meta)
            write_sequence_poses(folder, view.T_world_view(seq.poses))
        for i in tqdm(range(n), desc="views", unit="frame", file=sys.stderr, disable=not cfg.progress):
            rgb, z, lab = sampler.split(seq.rgb(i), seq.depth(i), seq.labels(i))
            valid += float((z > 0).mean())
            for k, view in enumerate(rig):
                for path, image in frame_images(tmp / view.name, i, rgb[k], z[k],
                                                None if lab is None else lab[k], DEPTH_SCALE):
                    write_png(path, image)
        write_run_config(tmp / CONFIG_NAME, cfg)
        write_text(tmp / VIEWS_JSON, json.dumps(views_doc, indent=2) + "\n")
    dt = time.perf_counter() - t0
    return {"frames": n, "views": len(rig), "size": cam.width, "fx": cam.fx, "labels": seq.has_labels,
            "valid_depth": valid / max(1, n), "seconds": dt}
