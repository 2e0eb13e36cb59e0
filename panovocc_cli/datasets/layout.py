"""The plan of a procedural home: rooms, the openings in their walls, and where the home sits on the lattice.

Coordinates: metres, +Z up, a room's interior is the box ``x0 <= x <= x1``, ``y0 <= y <= y1`` from its
floor (z = 0 in the layout) up; walls are ``WALL_T`` thick outside that box. A wall is named by the side
of the room it bounds (``S`` at ``y0``, ``N`` at ``y1``, ``W`` at ``x0``, ``E`` at ``x1``); along it, ``s``
is the coordinate along the wall (x for S/N, y for W/E) and ``o`` the distance outward from the room's face.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..classes import EVAL8, OPEN4
from .meshbuild import Transform2D

WALL_T = 0.12  # wall thickness, metres
NORMAL = {"S": (0.0, 1.0), "N": (0.0, -1.0), "W": (1.0, 0.0), "E": (-1.0, 0.0)}
"""Per wall side, the 2-D unit normal of its face pointing into the room."""
OPPOSITE = {"S": "N", "N": "S", "W": "E", "E": "W"}
REQUIRED = tuple(EVAL8) + tuple(OPEN4)
"""Classes every procedural scene holds (a layout draw that misses one is drawn again)."""

SHIFT_STREAM = 104729  # random stream of the home's offset from the origin (see lattice_offset)
SHIFT_STEP = 0.001  # metres: the seeded offset is a whole number of millimetres (the depth PNG's step)
SHIFT_SPAN = 1.0  # metres: the seeded offset lies in [0, SHIFT_SPAN) on each axis


class LayoutRetry(Exception):
    """A layout draw that cannot be furnished or traversed; the generator draws again."""


@dataclass
class Opening:
    kind: str  # "door" (interior, open leaf), "entrance" (closed leaf) or "window"
    side: str
    s0: float
    s1: float
    z0: float
    z1: float
    other: int | None = None
    owner: bool = True  # builds the reveals/tunnel
    leaf_here: bool = False  # the open leaf stands in this room
    hinge_s0: bool = True


@dataclass
class Room:
    idx: int
    kind: str
    x0: float
    x1: float
    y0: float
    y1: float
    openings: list[Opening] = field(default_factory=list)
    shared: dict[str, int] = field(default_factory=dict)

    def side_range(self, side: str) -> tuple[float, float]:
        return (self.x0, self.x1) if side in "SN" else (self.y0, self.y1)

    def P(self, side: str, s, o, z) -> np.ndarray:
        """World point at ``s`` along the wall, ``o`` metres outward from its room face, height ``z``."""
        s, o, z = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (s, o, z)))
        if side == "S":
            return np.stack([s, self.y0 - o, z], -1)
        if side == "N":
            return np.stack([s, self.y1 + o, z], -1)
        if side == "W":
            return np.stack([self.x0 - o, s, z], -1)
        return np.stack([self.x1 + o, s, z], -1)

    def aabb(self, side: str, s0, s1, o0, o1) -> tuple[float, float, float, float]:
        """2-D box (x0, x1, y0, y1) of wall coordinates s in [s0, s1], o in [o0, o1]."""
        p = self.P(side, [s0, s1], [o0, o1], [0.0, 0.0])
        return (min(p[:, 0]), max(p[:, 0]), min(p[:, 1]), max(p[:, 1]))

    @property
    def center(self) -> np.ndarray:
        return np.array([(self.x0 + self.x1) / 2, (self.y0 + self.y1) / 2])


def overlap(a, b, gap=0.0) -> bool:
    return a[0] < b[1] + gap and b[0] < a[1] + gap and a[2] < b[3] + gap and b[2] < a[3] + gap


def tf_yaw(tf: Transform2D) -> float:
    """The yaw (radians about +Z) of a placement."""
    return float(np.arctan2(tf.R[1, 0], tf.R[0, 0]))


def lattice_offset(seed: int) -> np.ndarray:
    """The home's seeded offset from the origin: (3,) float64 metres, each axis uniform over the whole
    millimetres of [0, ``SHIFT_SPAN``), drawn from ``np.random.default_rng([seed, SHIFT_STREAM])``.

    No clearance rule: modulo the default 8 cm lattice every millimetre position is equally likely, so
    the floor (laid out at z = 0) lies exactly on a voxel face one scene in 80 and within 3 mm of one
    about one in eleven, as large planes of real scans do. The mapper has to be robust to that.
    """
    rng = np.random.default_rng([seed, SHIFT_STREAM])
    return rng.integers(0, round(SHIFT_SPAN / SHIFT_STEP), size=3) * SHIFT_STEP


def place_scene(mesh, object_classes: list[str], rooms: list, T_world_cam: np.ndarray, seed: int,
                offset=None, **extra) -> dict:
    """A generated scene as the dict ``generate_*`` return, moved by ``offset`` ((x, y, z) metres; None:
    :func:`lattice_offset` of ``seed``). The layout does not depend on the offset.

    ``mesh`` is :meth:`MeshBuilder.finish`'s ``(vertices, quads, face_object, colors)`` and ``rooms`` the
    :class:`Room` s, both laid out from the origin. Returns ``vertices`` (4F, 3) float64 metres (+Z up),
    ``quads`` (F, 4) int32, ``face_object`` (F,) int32, ``colors`` (4F, 3) uint8, ``object_classes`` list[str]
    (Replica names, e.g. ``tv-screen``), ``T_world_cam`` (frames, 4, 4) float64 (OpenCV axes), ``rooms`` list
    of (x0, x1, y0, y1) interiors, ``floor_z`` float metres (the ground floor's height = the offset's z),
    ``offset`` (3,) float64 metres, and the ``extra`` items (``ceiling_height``, ...).
    """
    v, q, obj, col = mesh
    shift = lattice_offset(seed) if offset is None else np.asarray(offset, dtype=np.float64)
    sx, sy, sz = (float(x) for x in shift)
    shift = np.array([sx, sy, sz])
    T = T_world_cam.copy()
    T[:, :3, 3] += shift
    return {"vertices": v + shift, "quads": q, "face_object": obj, "colors": col,
            "object_classes": list(object_classes), "T_world_cam": T,
            "rooms": [(r.x0 + sx, r.x1 + sx, r.y0 + sy, r.y1 + sy) for r in rooms],
            "floor_z": sz, "offset": shift, **extra}
