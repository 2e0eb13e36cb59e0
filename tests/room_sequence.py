"""The furnished box room of the mapping tests (walls on known planes), rendered into sequences.

The room is a :class:`~panovocc_cli.datasets.scene.Scene` of boxes, rendered by the toolkit's own ray
caster (rendering/raycast.py) and written without labels (no semantic/ folder), so a map of it is
geometry only unless a test asks for more. World frame +Z up, metres; poses ``T_world_cam``.
"""

from pathlib import Path

import numpy as np

from panovocc_cli.datasets.scene import UNLABELED, Scene, split_polygons
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses
from panovocc_cli.rendering.raycast import RaycastRenderer

# Surfaces deliberately off the 0.08 m lattice's planes (a floor exactly on a voxel boundary is a
# degenerate case: see docs/mapping.md, "known limits").
ROOM = ((-3.01, -2.53, 0.013), (3.03, 2.49, 2.83))  # min, max corners, metres
FURNITURE = ((((1.0, 0.8, 0.013), (2.2, 2.0, 0.75)), "table"),  # a table-like block
             (((-2.6, -2.2, 0.013), (-1.6, -0.6, 1.6)), "cabinet"),
             (((-0.4, 1.6, 0.3), (0.4, 2.4, 1.1)), "shelf"))  # a floating box
COLORS = {"wall": (200, 200, 195), "table": (150, 110, 70), "cabinet": (120, 120, 140), "shelf": (90, 140, 90)}

# The 8 corners of a box (bit 0 = x, bit 1 = y, bit 2 = z of the max corner) and its 6 faces as quads.
_CORNERS = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], dtype=np.float64)
_QUADS = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]])


def room_polygons(furniture: bool = True):
    """The room as quads: walls (normals outward; ray casting is two-sided) and furniture boxes.

    Returns
    -------
    vertices : (V, 3) float64, metres, world frame
    quads : (F, 4) int32 vertex indices
    face_object : (F,) int32 object id of each quad (0 = the walls)
    colors : (V, 3) uint8 RGB
    object_classes : list[str], the class name of each object id
    """
    boxes = [(ROOM, "wall")] + (list(FURNITURE) if furniture else [])
    verts, quads, obj, cols = [], [], [], []
    for k, ((lo, hi), name) in enumerate(boxes):
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        verts.append(lo + _CORNERS * (hi - lo))
        quads.append(_QUADS + 8 * k)
        obj.append(np.full(6, k, np.int32))
        cols.append(np.tile(np.array(COLORS[name], np.uint8), (8, 1)))
    return (np.concatenate(verts), np.concatenate(quads).astype(np.int32), np.concatenate(obj),
            np.concatenate(cols), [name for _, name in boxes])


def room_scene(furniture: bool = True) -> Scene:
    """The room as a :class:`Scene` (class names ``unlabeled, wall, table, cabinet, shelf``)."""
    v, q, obj, col, names = room_polygons(furniture)
    class_names = [UNLABELED] + list(dict.fromkeys(names))
    obj_class = np.array([class_names.index(n) for n in names], np.int32)
    return Scene(v, split_polygons(q), np.repeat(obj_class[obj], 2), np.repeat(obj, 2), col, class_names,
                 name="box room").validate()


def room_trajectory(n: int) -> np.ndarray:
    """(n, 4, 4) float64 ``T_world_cam``: a loop around the room's centre at 1.2-1.6 m height, turning."""
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / max(n, 1)
        pos = np.array([1.2 * np.cos(a), 0.9 * np.sin(a), 1.4 + 0.2 * np.sin(2 * a)])
        fwd = np.array([np.cos(a + 1.0), np.sin(a + 1.0), 0.05])
        poses.append(look_at(pos, fwd, np.array([0.0, 0.0, 1.0])))
    return np.stack(poses)


def write_room_sequence(seq, n_frames: int, width: int, furniture: bool = True) -> np.ndarray:
    """Render the room along :func:`room_trajectory` into the sequence folder ``seq``; return the poses
    (n_frames, 4, 4) float64 T_world_cam."""
    ren = RaycastRenderer(room_scene(furniture), width)
    poses = room_trajectory(n_frames)
    seq = Path(seq)
    for i, T in enumerate(poses):
        fr = ren.render(T)
        write_frame(seq, i, fr.rgb, fr.depth, None)
    write_meta(seq, SequenceMeta(width=width, height=width // 2, frames=n_frames))
    write_sequence_poses(seq, poses)
    return poses
