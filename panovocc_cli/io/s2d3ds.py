"""Stanford 2D-3D-S (read only): an area's equirectangular panoramas and the S3DIS annotated point clouds,
converted to the toolkit's conventions at this boundary.

Followed from the dataset's own repository (github.com/alexsax/2D-3D-Semantics: README.md and
assets/utils.py)::

    AREA/pano/rgb/camera_<uuid>_<room>_frame_equirectangular_domain_rgb.png
    AREA/pano/depth/camera_<uuid>_<room>_frame_equirectangular_domain_depth.png       uint16, 1/512 m,
                                                   65535 = missing; radial (distance from the camera centre)
    AREA/pano/semantic/camera_<uuid>_<room>_frame_equirectangular_domain_semantic.png 24-bit RGB: index
                                                   R*65536 + G*256 + B into semantic_labels.json (utils.get_index);
                                                   #0D0D0D (past the list's end) = missing
    AREA/pano/pose/camera_<uuid>_<room>_frame_equirectangular_domain_pose.json        camera_rt_matrix (3x4
                                                   [R|t]), camera_location, final_camera_rotation (XYZ Euler,
                                                   radians), camera_k_matrix, room, ...
    assets/semantic_labels.json                    ["<class>_<instance>_<roomType>_<roomNum>_<areaNum>", ...]
                                                   (utils.parse_label splits on "_")
    Area_N/<room>/Annotations/<class>_<k>.txt      S3DIS: one point a line, "x y z r g b" (metres, the area's frame)

``<room>`` is ``<roomType>_<roomNum>`` (``office_24``, ``conferenceRoom_1``). The panoramas' pose convention
is not written down by the dataset: :data:`POSE_FORMS` are the readings the check compares
(``convert s2d3ds --check``); see docs/datasets.md.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PanovoccError

MODALITIES = ("rgb", "depth", "semantic", "pose")
PANO_NAME = re.compile(r"^camera_([0-9A-Za-z]+)_(.+)_frame_equirectangular_domain_(rgb|depth|semantic|pose)\.(png|json)$")
DEPTH_UNITS_PER_M = 512.0
DEPTH_MISSING = 65535

POSE_FORMS = ("rt", "euler")
"""How a pose JSON makes ``T_world_cam``: ``rt``: ``camera_rt_matrix`` is world-to-camera ``[R|t]`` of an
OpenCV camera (x right, y down, z forward; the reading of the dataset's perspective images), inverted;
``euler``: a Blender camera (x right, y up, looking along -z) at ``camera_location`` turned by
``final_camera_rotation`` (XYZ Euler), its axes flipped to OpenCV's."""
PANO_YAWS_DEG = (0, 90, 180, 270)
"""Where the panorama's centre column looks, turned about the camera's vertical axis from its +z (degrees,
toward +x)."""

S2D3DS_CLASSES = ("ceiling", "floor", "wall", "beam", "column", "window", "door", "table", "chair", "sofa",
                  "bookcase", "board", "clutter")
"""The 13 classes of the annotations (S3DIS order)."""
CLASS_MAP = {name: name for name in S2D3DS_CLASSES}
"""2D-3D-S class -> the toolkit's name: the eight eval8 classes it has (ceiling floor wall window chair sofa
table) and ``door`` (open4) keep their names, as do the five it alone has (beam column bookcase board
clutter: no benchmark class of the toolkit is the same thing); ``<UNK>`` is unlabelled."""
UNKNOWN_LABEL = "<UNK>"


@dataclass
class S2d3dsArea:
    """The panoramas of a 2D-3D-S area folder with every modality needed.

    keys : (uuid, room) of each panorama, sorted by room then uuid
    files : per key, modality -> path
    skipped : "uuid room: no depth" for panoramas missing a modality
    """

    root: Path
    keys: list[tuple[str, str]]
    files: dict[tuple[str, str], dict[str, Path]]
    skipped: list[str]


def read_area(root: str | Path, need=("rgb", "depth", "pose")) -> S2d3dsArea:
    """List ``root/pano/*`` (nothing decoded).

    Raises
    ------
    PanovoccError when the folder or ``pano/`` is missing, a needed modality folder is missing, or no
    panorama has every needed modality.
    """
    root = Path(root)
    if not root.is_dir():
        raise PanovoccError("2D-3D-S area folder not found", root)
    pano = root / "pano"
    if not pano.is_dir():
        raise PanovoccError("not a 2D-3D-S area: pano/ not found (expected pano/rgb, pano/depth, pano/pose)", root)
    found: dict[tuple[str, str], dict[str, Path]] = {}
    for m in need:
        if not (pano / m).is_dir():
            raise PanovoccError(f"not a 2D-3D-S area: pano/{m}/ not found", root)
    for m in MODALITIES:
        if not (pano / m).is_dir():
            continue
        for p in sorted((pano / m).iterdir()):
            hit = PANO_NAME.match(p.name)
            if hit and hit.group(3) == m and p.is_file():
                found.setdefault((hit.group(1), hit.group(2)), {})[m] = p
    keys, skipped = [], []
    for k in sorted(found, key=lambda k: (k[1], k[0])):
        missing = [m for m in need if m not in found[k]]
        if missing:
            skipped.append(f"{k[0]} {k[1]}: no {' or '.join(missing)}")
        else:
            keys.append(k)
    if not keys:
        raise PanovoccError("no panorama has every one of " + ", ".join(f"pano/{m}" for m in need)
                            + " (names camera_<uuid>_<room>_frame_equirectangular_domain_<modality>.png/.json)", root)
    return S2d3dsArea(root, keys, {k: found[k] for k in keys}, skipped)


def read_pose_json(path: str | Path) -> dict:
    """A pose JSON's fields as arrays: ``rt`` (3, 4) float64 (a 4x4 is cut to 3x4), ``location`` (3,),
    ``rotation`` (3,) (XYZ Euler, radians), ``room`` (str or None).

    Raises
    ------
    PanovoccError naming the file when it is not JSON or a field is missing or not finite.
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PanovoccError(f"not a pose JSON ({type(e).__name__}: {e})", path) from None
    if not isinstance(d, dict):
        raise PanovoccError("expected a JSON object with camera_rt_matrix, camera_location, final_camera_rotation",
                            path)
    out = {}
    for key, name, shapes in (("camera_rt_matrix", "rt", ((3, 4), (4, 4))), ("camera_location", "location", ((3,),)),
                              ("final_camera_rotation", "rotation", ((3,),))):
        if key not in d:
            raise PanovoccError(f"{key} missing (expected camera_rt_matrix, camera_location, final_camera_rotation)",
                                path)
        try:
            a = np.asarray(d[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise PanovoccError(f"{key} is not an array of numbers", path) from None
        if a.shape not in shapes or not np.all(np.isfinite(a)):
            raise PanovoccError(f"{key} has shape {a.shape}, expected {' or '.join(str(s) for s in shapes)} finite "
                                "numbers", path)
        out[name] = a[:3] if name == "rt" else a
    out["room"] = d.get("room")
    return out


def _yaw(deg: float) -> np.ndarray:
    """(4, 4): a turn by ``deg`` about the camera's y axis (vertical), taking +z toward +x."""
    a = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    return T


def pano_pose(pose: dict, form: str = "rt", yaw_deg: float = 0) -> np.ndarray:
    """The toolkit's ``T_world_cam`` (4, 4) float64 of a pose JSON (:func:`read_pose_json`) under a pose form
    (:data:`POSE_FORMS`) and the panorama's yaw (:data:`PANO_YAWS_DEG`).

    Raises
    ------
    PanovoccError when the form is unknown or ``camera_rt_matrix``'s rotation is not one.
    """
    if form == "rt":
        M = np.eye(4)
        M[:3, :4] = pose["rt"]
        R = M[:3, :3]
        if not (np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0):
            raise PanovoccError("camera_rt_matrix's left 3x3 is not a rotation")
        T = np.linalg.inv(M)
    elif form == "euler":
        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", pose["rotation"]).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        T[:3, 3] = pose["location"]
    else:
        raise PanovoccError(f"--pose-form: {form!r} is not one of {', '.join(POSE_FORMS)}")
    return T @ _yaw(yaw_deg)


def read_depth(path: str | Path) -> np.ndarray:
    """(H, W) float32 metres, radial, 0 = missing, of a 2D-3D-S depth PNG (uint16 / 512; 65535 missing)."""
    from .images import read_image

    a = read_image(path, "unchanged")
    if a.ndim != 2 or a.dtype != np.uint16:
        raise PanovoccError(f"depth PNG is {a.dtype} with shape {a.shape}, expected one 16-bit channel (1/512 m)", path)
    return np.where(a == DEPTH_MISSING, 0.0, a / DEPTH_UNITS_PER_M).astype(np.float32)


def read_semantic(path: str | Path) -> np.ndarray:
    """(H, W) int64 indices into semantic_labels.json of a 2D-3D-S semantic PNG (R*65536 + G*256 + B, the
    dataset's ``utils.get_index``); missing pixels (#0D0D0D) come out past the list's end."""
    from .images import read_image

    a = read_image(path, "unchanged")
    if a.ndim != 3 or a.shape[2] < 3 or a.dtype != np.uint8:
        raise PanovoccError(f"semantic PNG is {a.dtype} with shape {a.shape}, expected 8-bit RGB", path)
    b, g, r = (a[:, :, k].astype(np.int64) for k in range(3))  # OpenCV reads BGR
    return r * 65536 + g * 256 + b


def read_semantic_labels(path: str | Path) -> list[str]:
    """The list of ``semantic_labels.json`` (``class_instance_roomType_roomNum_areaNum`` strings)."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("semantic_labels.json not found (the dataset's assets/semantic_labels.json; pass "
                            "--labels-json)", path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PanovoccError(f"not JSON ({type(e).__name__}: {e})", path) from None
    if not isinstance(d, list) or not all(isinstance(x, str) for x in d):
        raise PanovoccError("expected a JSON list of label strings (class_instance_roomType_roomNum_areaNum)", path)
    return d


def label_class(label: str) -> str:
    """The class of a label string (``chair_12_office_3_1`` -> ``chair``; utils.parse_label's first field)."""
    return label.split("_", 1)[0]


def find_labels_json(area: str | Path) -> Path:
    """Where ``semantic_labels.json`` is looked for: in the area, beside it, or in ``assets/`` beside it."""
    area = Path(area)
    for p in (area / "semantic_labels.json", area.parent / "semantic_labels.json",
              area.parent / "assets" / "semantic_labels.json", area / "assets" / "semantic_labels.json"):
        if p.is_file():
            return p
    return area.parent / "assets" / "semantic_labels.json"


# ---------------------------------------------------------------------------------------------
# S3DIS annotated point clouds


def list_annotations(root: str | Path) -> list[tuple[str, Path]]:
    """``(room, file)`` of every ``ROOM/Annotations/*.txt`` under ``root`` (an ``Area_N`` folder), sorted.

    Raises
    ------
    PanovoccError when the folder is missing or holds no annotation file.
    """
    root = Path(root)
    if not root.is_dir():
        raise PanovoccError("annotations folder not found (expected Area_N/ROOM/Annotations/*.txt)", root)
    out = [(p.parent.parent.name, p) for p in sorted(root.glob("*/Annotations/*.txt"))]
    if not out:
        raise PanovoccError("no ROOM/Annotations/*.txt under it (expected the S3DIS layout Area_N/ROOM/Annotations/"
                            "<class>_<k>.txt)", root)
    return out


def annotation_class(path: str | Path) -> str:
    """The class of an annotation file (``chair_3.txt`` -> ``chair``)."""
    return Path(path).stem.rsplit("_", 1)[0]


def read_annotation(path: str | Path) -> tuple[np.ndarray, int]:
    """(n, 3) float64 points (metres) of an annotation file and the number of malformed lines skipped.

    A line is ``x y z r g b``; only the first three numbers are read. A line that does not parse (the
    released files have a few with stray bytes) is skipped and counted, never guessed at.
    """
    import pandas as pd

    path = Path(path)
    try:
        df = pd.read_csv(path, sep=r"\s+", header=None, usecols=[0, 1, 2], dtype=np.float64, engine="c")
        pts = df.to_numpy(np.float64)
        bad = 0
    except (ValueError, pd.errors.ParserError):
        rows, bad = [], 0
        with open(path, "rb") as f:
            for line in f:
                parts = line.split()
                try:
                    xyz = [float(v) for v in parts[:3]]
                    if len(xyz) != 3:
                        raise ValueError
                    rows.append(xyz)
                except (ValueError, UnicodeDecodeError):
                    bad += 1 if parts else 0
        pts = np.asarray(rows, np.float64).reshape(-1, 3)
    except pd.errors.EmptyDataError:
        return np.zeros((0, 3)), 0
    except OSError as e:
        raise PanovoccError(f"cannot read ({e.strerror or e})", path) from None
    finite = np.all(np.isfinite(pts), axis=1)
    return pts[finite], bad + int((~finite).sum())
