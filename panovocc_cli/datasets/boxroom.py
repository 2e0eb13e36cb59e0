"""A furnished box room with answers known in closed form (walls on known planes), as a scene source.

Used by ``panovocc bench`` (written in Replica's format, then rendered by ``run_render`` like any
scene) and by the mapping tests (rendered with :class:`~panovocc_cli.rendering.raycast.RaycastRenderer`).
World frame +Z up, metres; the trajectory's poses follow CONVENTIONS.md (``T_world_cam``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.poses import look_at
from .scene import UNLABELED, Scene, split_polygons

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


def write_box_room(folder: str | Path, frames: int, furniture: bool = True) -> Path:
    """Write the room as a Replica-format scene folder plus ``traj.txt`` (``frames`` poses), atomically."""
    from ..io.atomic import atomic_dir
    from ..io.poses import write_poses
    from .replica import TRAJ_NAME, write_replica_scene

    v, q, obj, col, names = room_polygons(furniture)
    with atomic_dir(folder) as tmp:
        write_replica_scene(tmp, v, q, obj, col, names)
        write_poses(tmp / TRAJ_NAME, room_trajectory(frames))
    return Path(folder)
