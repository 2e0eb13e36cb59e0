"""A panoramic (or pinhole) RGB-D sequence folder, laid out as CONVENTIONS.md says::

    SEQ/meta.json          {"camera": "erp", "width": W, "height": H, "depth_scale": 1000.0,
                            "frames": N, "class_names": ["unlabeled", ...], ...}
    SEQ/rgb/000000.png     uint8 RGB (JPEG accepted on input)
    SEQ/depth/000000.png   uint16 radial depth x depth_scale; 0 = no measurement (float EXR accepted)
    SEQ/semantic/000000.png  uint16 ids into class_names (optional); 0 = unlabeled
    SEQ/poses.txt          N lines of 16 floats, T_world_cam row-major
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import PanovoccError
from ..frame import Frame
from .images import depth_to_uint16, read_depth, read_labels, read_rgb, write_png
from .poses import read_poses, write_poses
from .atomic import write_text
from .jsonfile import read_json

STEM_DIGITS = 6


def frame_stem(i: int) -> str:
    """Zero-padded stem of frame ``i`` (``000042``)."""
    return f"{i:0{STEM_DIGITS}d}"


@dataclass
class SequenceMeta:
    """Contents of ``meta.json``; unknown keys are kept in ``extra`` and written back."""

    width: int
    height: int
    frames: int
    camera: str = "erp"
    depth_scale: float = 1000.0
    class_names: list[str] = field(default_factory=lambda: ["unlabeled"])
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"camera": self.camera, "width": self.width, "height": self.height,
                             "depth_scale": self.depth_scale, "frames": self.frames,
                             "class_names": list(self.class_names)}
        if self.camera == "pinhole":
            d.update(fx=self.fx, fy=self.fy, cx=self.cx, cy=self.cy)
        d.update(self.extra)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any], path: Path) -> "SequenceMeta":
        try:
            camera = str(d.get("camera", "erp"))
            width, height, frames = int(d["width"]), int(d["height"]), int(d["frames"])
            depth_scale = float(d.get("depth_scale", 1000.0))
        except (KeyError, TypeError, ValueError) as e:
            raise PanovoccError(f"missing or invalid key {e} (expected camera, width, height, frames)", path) from None
        for k in ("width", "height", "frames"):  # JSON integers only: "256" or 256.5 is a broken file
            if type(d[k]) is not int:
                raise PanovoccError(f"{k} is {d[k]!r}; expected a whole number (JSON integer)", path)
        if isinstance(d.get("depth_scale"), (bool, str)) or not np.isfinite(depth_scale):
            raise PanovoccError(f"depth_scale is {d.get('depth_scale')!r}; expected a positive finite number "
                                "(depth PNG units per metre)", path)
        if camera not in ("erp", "pinhole"):
            raise PanovoccError(f"camera is {camera!r}, expected 'erp' or 'pinhole'", path)
        if camera == "erp" and width != 2 * height:
            raise PanovoccError(f"ERP size {width}x{height} is not 2:1", path)
        if width <= 0 or height <= 0 or frames < 0 or depth_scale <= 0:
            raise PanovoccError("width, height and depth_scale must be positive and frames >= 0", path)
        names = d.get("class_names", ["unlabeled"])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise PanovoccError("class_names must be a list of strings", path)
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise PanovoccError(f"class_names has duplicates {dup}; each id needs its own name", path)
        known = {"camera", "width", "height", "depth_scale", "frames", "class_names", "fx", "fy", "cx", "cy"}
        meta = cls(width=width, height=height, frames=frames, camera=camera, depth_scale=depth_scale,
                   class_names=names, extra={k: v for k, v in d.items() if k not in known})
        if camera == "pinhole":
            try:
                meta.fx, meta.fy, meta.cx, meta.cy = (float(d[k]) for k in ("fx", "fy", "cx", "cy"))
            except (KeyError, TypeError, ValueError):
                raise PanovoccError("a pinhole sequence needs fx, fy, cx, cy", path) from None
        return meta

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)


def read_meta(seq: str | Path) -> SequenceMeta:
    path = Path(seq) / "meta.json"
    if not path.is_file():
        raise PanovoccError("not a sequence folder: meta.json not found", Path(seq))
    d = read_json(path, "a sequence's meta.json")
    if not isinstance(d, dict):
        raise PanovoccError("expected a JSON object", path)
    return SequenceMeta.from_json(d, path)


def write_meta(seq: str | Path, meta: SequenceMeta) -> None:
    write_text(Path(seq) / "meta.json", json.dumps(meta.to_json(), indent=2) + "\n")


def _find(folder: Path, stem: str, exts: tuple[str, ...]) -> Path:
    for e in exts:
        p = folder / f"{stem}{e}"
        if p.is_file():
            return p
    raise PanovoccError(f"frame {stem} not found (expected {stem}{exts[0]})", folder)


class Sequence:
    """Read access to a sequence folder. Frames are read lazily and validated on read.

    ``seq.rgb(i)`` (H, W, 3) uint8; ``seq.depth(i)`` (H, W) float32 metres (radial for ERP, z for
    pinhole), 0 = invalid; ``seq.labels(i)`` (H, W) int64 ids into ``seq.meta.class_names`` or None;
    ``seq.poses`` (N, 4, 4) float64 T_world_cam. ``seq.frame(i)`` and ``seq.frames()`` give whole
    :class:`~panovocc_cli.frame.Frame` objects (ERP sequences).

    ``poses`` (N, 4, 4) float64, when given, replaces the pose file (nothing is read from
    ``poses_path`` or ``SEQ/poses.txt``); ``poses_path`` names where they came from in messages.
    """

    def __init__(self, root: str | Path, poses_path: str | Path | None = None, poses: np.ndarray | None = None):
        self.root = Path(root)
        if not self.root.is_dir():
            raise PanovoccError("sequence folder not found", self.root)
        self.meta = read_meta(self.root)
        self.poses_path = Path(poses_path) if poses_path is not None else self.root / "poses.txt"
        self.poses = read_poses(self.poses_path) if poses is None else np.asarray(poses, np.float64)
        if len(self.poses) != self.meta.frames:
            raise PanovoccError(f"{len(self.poses)} poses for {self.meta.frames} frames (meta.json)", self.poses_path)

    def __len__(self) -> int:
        return self.meta.frames

    @property
    def has_labels(self) -> bool:
        return (self.root / "semantic").is_dir()

    def check_files(self, parts: tuple[str, ...] | None = None) -> None:
        """Check every frame before any work: each file present, its PNG header readable and complete, its
        size and type right (nothing decoded). ``parts``: of ``depth``, ``rgb``, ``semantic``; default depth,
        plus rgb and semantic where their folders exist. Raises :class:`PanovoccError` naming the first bad file."""
        from .images import check_image_header

        exts = {"depth": (".png", ".exr"), "rgb": (".png", ".jpg", ".jpeg"), "semantic": (".png",)}
        role = {"rgb": "rgb", "depth": "depth", "semantic": "labels"}
        if parts is None:
            parts = ("depth",) + tuple(p for p in ("rgb", "semantic") if (self.root / p).is_dir())
        for sub in parts:
            if not (self.root / sub).is_dir():
                raise PanovoccError(f"folder {sub}/ not found (expected the frames' {role[sub]} images)", self.root)
        for i in range(len(self)):
            for sub in parts:
                check_image_header(_find(self.root / sub, frame_stem(i), exts[sub]), role[sub], self.meta.shape)

    def rgb(self, i: int) -> np.ndarray:
        return read_rgb(_find(self.root / "rgb", frame_stem(i), (".png", ".jpg", ".jpeg")), self.meta.shape)

    def depth(self, i: int) -> np.ndarray:
        return read_depth(_find(self.root / "depth", frame_stem(i), (".png", ".exr")), self.meta.depth_scale,
                          self.meta.shape)

    def labels(self, i: int) -> np.ndarray | None:
        if not self.has_labels:
            return None
        lab = read_labels(_find(self.root / "semantic", frame_stem(i), (".png",)), self.meta.shape)
        if lab.size and lab.max() >= len(self.meta.class_names):
            raise PanovoccError(f"label id {lab.max()} but meta.json has {len(self.meta.class_names)} class_names",
                                self.root / "semantic" / f"{frame_stem(i)}.png")
        return lab

    def camera(self):
        """The sequence's camera model (:mod:`panovocc_cli.geometry.cameras`); ERP only so far."""
        from ..geometry.cameras import ErpCamera

        if self.meta.camera != "erp":
            raise PanovoccError(f"camera {self.meta.camera!r}: only ERP sequences can be read as frames",
                                self.root / "meta.json")
        return ErpCamera(self.meta.width, self.meta.height)

    def frame(self, i: int, T_world_cam: np.ndarray | None = None) -> Frame:
        """Frame ``i`` read from the folder: rgb, depth, pose (``seq.poses[i]`` unless given), camera;
        no logits (a segmenter adds them)."""
        T = self.poses[i] if T_world_cam is None else T_world_cam
        return Frame(rgb=self.rgb(i), depth=self.depth(i), T_world_cam=T, camera=self.camera(), index=int(i))

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Frame]:
        """Frames ``start .. stop - 1`` (default: to the end), read one at a time."""
        for i in range(start, len(self) if stop is None else stop):
            yield self.frame(i)


def frame_images(seq: str | Path, i: int, rgb: np.ndarray, depth_m: np.ndarray, labels: np.ndarray | None,
                 depth_scale: float = 1000.0) -> list[tuple[Path, np.ndarray]]:
    """The PNGs of frame ``i`` as (path, encoded image) pairs, in the layout above.

    rgb (H, W, 3) uint8; depth (H, W) metres -> uint16 ``depth * depth_scale``; labels (H, W) int ids
    -> uint16 (omitted when None). Callers write each with :func:`io.images.write_png`, in any order.
    """
    seq = Path(seq)
    stem = frame_stem(i)
    out = [(seq / "rgb" / f"{stem}.png", rgb), (seq / "depth" / f"{stem}.png", depth_to_uint16(depth_m, depth_scale))]
    if labels is not None:
        out.append((seq / "semantic" / f"{stem}.png", np.asarray(labels).astype(np.uint16)))
    return out


def write_frame(seq: str | Path, i: int, rgb: np.ndarray, depth_m: np.ndarray, labels: np.ndarray | None,
                depth_scale: float = 1000.0) -> None:
    """Write frame ``i``: rgb (H, W, 3) uint8, depth (H, W) metres, labels (H, W) int ids or None."""
    for path, image in frame_images(seq, i, rgb, depth_m, labels, depth_scale):
        write_png(path, image)


def write_sequence_poses(seq: str | Path, T_world_cam: np.ndarray) -> None:
    write_poses(Path(seq) / "poses.txt", T_world_cam)
