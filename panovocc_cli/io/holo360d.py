"""The released Holo360D scene layout (read only), converted to the toolkit's conventions at the boundary.

::

    SCENE/rgb/<stem>.jpg                      panorama, RGB (ERP, W = 2 H)
    SCENE/depth/mesh_depth/<stem>.exr         float radial depth, metres (rendered from the scan's mesh)
    SCENE/depth/pointcloud_depth/<stem>.exr   float radial depth, metres (from the point cloud)
    SCENE/mask/<stem>.jpg                     validity mask (taken as: bright = valid; optional)
    SCENE/poses/*.txt                         one header line, then ``name tx ty tz r1 .. r9`` per line

Stems are timestamps shared across the modalities; a pose line's ``name`` is matched by its stem (an
extension is dropped). No official loader is released: the only pose reader of the authors (in their
fine-tuning code) builds ``[[R.T, t], [0, 0, 0, 1]]`` with ``R = reshape(r1 .. r9, 3 x 3)`` (row-major) and
uses it as camera-to-world. Their camera frame is z up (column 0 looks along +x, the centre column along
-x); a point in it is ``p_holo = R_AXES p_ours`` with :data:`R_AXES`, so
``T_world_cam(ours) = T_holo @ diag(R_AXES, 1)`` and the images need no remapping. None of this has been
checked on a released file: the pose form is an explicit choice (:data:`POSE_FORMS`, :data:`CAMERA_AXES`)
and ``convert holo360d --check`` measures which one makes overlapping frames' depth agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..geometry.poses import check_rigid

R_AXES = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""p_holo = R_AXES @ p_ours (Holo360D's z-up camera frame from the toolkit's OpenCV one)."""

POSE_FORMS = ("rt-c2w", "r-c2w", "rt-w2c", "r-w2c")
"""How a pose line's R and t make a matrix: ``rt``: [[R.T, t]] (the authors' reader), ``r``: [[R, t]];
``c2w``: the matrix is camera-to-world (the authors' use), ``w2c``: world-to-camera (inverted here)."""
CAMERA_AXES = ("holo", "opencv")
"""The camera frame the matrix maps from: ``holo`` (z up, :data:`R_AXES`) or ``opencv`` (the toolkit's own)."""
DEPTH_KINDS = ("mesh", "pointcloud")
"""Which depth folder: ``depth/mesh_depth`` or ``depth/pointcloud_depth``."""
_DEPTH_DIRS = {"mesh": "mesh_depth", "pointcloud": "pointcloud_depth"}


def read_holo_poses(folder: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every pose line of ``folder/*.txt``: stem -> (t (3,) float64 metres, R (3, 3) float64 as written).

    Each file's first line is a header and is skipped (as the authors' reader does); blank lines are
    ignored; every other line must be ``name tx ty tz r1 .. r9``.

    Raises
    ------
    PanovoccError naming the file and line of a malformed entry, a rotation that is not one (not
    orthonormal with det +1: ``geometry.poses.check_rigid``), a stem given twice, or no pose at all.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise PanovoccError("poses/ folder not found (expected poses/*.txt: name tx ty tz r1..r9 per line)", folder)
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for path in sorted(folder.glob("*.txt")):
        try:
            lines = path.read_text(encoding="utf-8").splitlines()
        except UnicodeDecodeError:
            raise PanovoccError("not a text file (expected a header line, then name tx ty tz r1..r9)", path) from None
        for n, line in enumerate(lines[1:], start=2):
            parts = line.split()
            if not parts:
                continue
            try:
                if len(parts) != 13:
                    raise ValueError
                v = np.array([float(x) for x in parts[1:]], dtype=np.float64)
                if not np.all(np.isfinite(v)):
                    raise ValueError
            except ValueError:
                raise PanovoccError(f"line {n}: expected 'name tx ty tz r1 .. r9' (13 fields, finite numbers), "
                                    f"got {len(parts)} fields", path) from None
            stem = Path(parts[0]).stem
            if stem in out:
                raise PanovoccError(f"line {n}: a second pose for {stem!r}", path)
            M = np.eye(4)
            M[:3, :3], M[:3, 3] = v[3:].reshape(3, 3), v[:3]  # R is a rotation in every pose form (or R.T is)
            check_rigid(M, what=f"{path}: line {n} (frame {stem})")
            out[stem] = (v[:3], v[3:].reshape(3, 3))
    if not out:
        raise PanovoccError("no pose lines in poses/*.txt (expected a header line, then name tx ty tz r1..r9)", folder)
    return out


def holo_pose(t: np.ndarray, R: np.ndarray, form: str = "rt-c2w", axes: str = "holo") -> np.ndarray:
    """The toolkit's ``T_world_cam`` (4, 4) float64 of one Holo360D pose line under a pose form.

    Parameters
    ----------
    t : (3,) metres; R : (3, 3) the nine numbers of the line, row-major
    form : one of :data:`POSE_FORMS`; axes : one of :data:`CAMERA_AXES`
    """
    if form not in POSE_FORMS:
        raise PanovoccError(f"--pose-form: {form!r} is not one of {', '.join(POSE_FORMS)}")
    if axes not in CAMERA_AXES:
        raise PanovoccError(f"--camera-axes: {axes!r} is not one of {', '.join(CAMERA_AXES)}")
    M = np.eye(4)
    M[:3, :3] = np.asarray(R, dtype=np.float64).T if form.startswith("rt") else R
    M[:3, 3] = t
    if form.endswith("w2c"):
        M = np.linalg.inv(M)
    if axes == "holo":
        A = np.eye(4)
        A[:3, :3] = R_AXES
        M = M @ A
    return M


@dataclass
class HoloScene:
    """The frames of a Holo360D scene folder that have an RGB image, a depth map and a pose.

    stems : the frames' stems, in time order (numeric when every stem is a number, else by name)
    rgb, depth, mask : per stem, the file (mask: None when absent)
    poses : stem -> (t, R) as read
    skipped : stems with some modality missing, and what (``stem: no depth``)
    """

    root: Path
    stems: list[str]
    rgb: dict[str, Path]
    depth: dict[str, Path]
    mask: dict[str, Path | None]
    poses: dict[str, tuple[np.ndarray, np.ndarray]]
    skipped: list[str]


def _by_stem(folder: Path, exts: tuple[str, ...]) -> dict[str, Path]:
    if not folder.is_dir():
        return {}
    return {p.stem: p for p in sorted(folder.iterdir()) if p.suffix.lower() in exts and p.is_file()}


def _order(stems) -> list[str]:
    stems = list(stems)
    try:
        return sorted(stems, key=lambda s: (float(s), s))
    except ValueError:
        return sorted(stems)


def read_holo_scene(root: str | Path, depth_kind: str = "mesh") -> HoloScene:
    """List a Holo360D scene folder (nothing decoded yet).

    Raises
    ------
    PanovoccError when the folder, its rgb/ or depth folder is missing, or no frame has all three of RGB,
    depth and pose.
    """
    root = Path(root)
    if not root.is_dir():
        raise PanovoccError("Holo360D scene folder not found", root)
    if depth_kind not in DEPTH_KINDS:
        raise PanovoccError(f"--depth: {depth_kind!r} is not one of {', '.join(DEPTH_KINDS)}")
    dfolder = root / "depth" / _DEPTH_DIRS[depth_kind]
    for f, what in ((root / "rgb", "rgb/*.jpg"), (dfolder, f"depth/{_DEPTH_DIRS[depth_kind]}/*.exr")):
        if not f.is_dir():
            raise PanovoccError(f"not a Holo360D scene: {what} not found", root)
    rgb = _by_stem(root / "rgb", (".jpg", ".jpeg", ".png"))
    depth = _by_stem(dfolder, (".exr",))
    masks = _by_stem(root / "mask", (".jpg", ".jpeg", ".png"))
    poses = read_holo_poses(root / "poses")
    stems, skipped = [], []
    for s in _order(set(rgb) | set(depth) | set(poses)):
        missing = [w for w, d in (("rgb", rgb), ("depth", depth), ("pose", poses)) if s not in d]
        if missing:
            skipped.append(f"{s}: no {' or '.join(missing)}")
        else:
            stems.append(s)
    if not stems:
        raise PanovoccError("no frame has an RGB image, a depth map and a pose with the same stem", root)
    return HoloScene(root, stems, {s: rgb[s] for s in stems}, {s: depth[s] for s in stems},
                     {s: masks.get(s) for s in stems}, {s: poses[s] for s in stems}, skipped)


def read_holo_frame(scene: HoloScene, stem: str, use_mask: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """RGB (H, W, 3) uint8 and radial depth (H, W) float32 metres (0 = invalid) of one frame.

    Non-finite or negative depth becomes 0 (no measurement); with ``use_mask`` a mask image present for the
    frame zeroes the depth where the mask is dark (< 128).

    Raises
    ------
    PanovoccError when a file cannot be decoded, the panorama is not 2:1, or the images differ in size.
    """
    from .images import read_exr, read_image, read_rgb

    rgb = read_rgb(scene.rgb[stem])
    depth = read_exr(scene.depth[stem])
    h, w = rgb.shape[:2]
    if w != 2 * h:
        raise PanovoccError(f"panorama is {w}x{h}, expected 2:1 (ERP)", scene.rgb[stem])
    if depth.shape != (h, w):
        raise PanovoccError(f"depth is {depth.shape[1]}x{depth.shape[0]}, the RGB image {w}x{h}", scene.depth[stem])
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0).astype(np.float32)
    m = scene.mask.get(stem)
    if use_mask and m is not None:
        mask = read_image(m, "unchanged")
        if mask.ndim == 3:
            mask = mask.max(axis=2)
        if mask.shape != (h, w):
            raise PanovoccError(f"mask is {mask.shape[1]}x{mask.shape[0]}, the RGB image {w}x{h}", m)
        depth[mask < 128] = 0
    return rgb, depth
