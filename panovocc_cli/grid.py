"""The semantic occupancy grid, the toolkit's core data type, and its label constants (CONVENTIONS.md).

``labels`` (X, Y, Z) uint8: 0 empty (observed free), 1..253 a class index into ``class_names``,
254 occupied with no class, 255 unknown (never observed; ignored in ground truth). ``origin`` is the
centre of voxel [0, 0, 0] in world metres, ``voxel_size`` the edge length in metres, and
``class_names[0] == "empty"``. The file format is :mod:`panovocc_cli.io.grid`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .classes import canonical_name
from .errors import PanovoccError
from .geometry.lattice import index_to_center, origin_to_index

EMPTY = 0
OCCUPIED_UNKNOWN_CLASS = 254
UNKNOWN = 255
MAX_CLASSES = 254  # ids 0..253


def _values_used(labels: np.ndarray) -> np.ndarray:
    """The distinct values of a uint8 array (sorted), a slab of about 16 MB at a time (``np.unique`` of a
    building's grid would sort a copy of all of it)."""
    seen = np.zeros(256, np.bool_)
    step = max(1, (1 << 24) // max(int(np.prod(labels.shape[1:])), 1))
    for a in range(0, labels.shape[0], step):
        seen[np.unique(labels[a:a + step])] = True
    return np.flatnonzero(seen)


@dataclass
class Grid:
    """A semantic occupancy grid on the global lattice.

    labels : (X, Y, Z) uint8; origin : (3,) float64 metres, centre of voxel [0, 0, 0];
    voxel_size : float metres; class_names : list[str] with class_names[0] == "empty".
    """

    labels: np.ndarray
    origin: np.ndarray
    voxel_size: float
    class_names: list[str]

    def __post_init__(self):
        self.labels = np.asarray(self.labels)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        self.voxel_size = float(self.voxel_size)
        self.class_names = [str(c) for c in self.class_names]

    @property
    def index0(self) -> np.ndarray:
        """Lattice index (3,) int64 of voxel [0, 0, 0]."""
        return origin_to_index(self.origin, self.voxel_size)

    def centers(self, ijk: np.ndarray) -> np.ndarray:
        """World centres (n, 3) of grid-local indices (n, 3)."""
        return index_to_center(np.asarray(ijk) + self.index0, self.voxel_size)

    def validate(self, path: str | Path | None = None) -> "Grid":
        where = path
        if self.labels.ndim != 3 or self.labels.dtype != np.uint8:
            raise PanovoccError(f"labels must be a 3-D uint8 array, got {self.labels.dtype} {self.labels.shape}", where)
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise PanovoccError(f"voxel_size must be positive, got {self.voxel_size}", where)
        if not np.all(np.isfinite(self.origin)):
            raise PanovoccError("origin has non-finite values", where)
        try:
            origin_to_index(self.origin, self.voxel_size)
        except PanovoccError as e:
            raise PanovoccError(str(e), where) from None
        if not self.class_names or self.class_names[0] != "empty":
            raise PanovoccError("class_names[0] must be 'empty'", where)
        if len(self.class_names) > MAX_CLASSES:
            raise PanovoccError(f"{len(self.class_names)} classes; at most {MAX_CLASSES} fit in uint8 labels", where)
        seen: dict[str, int] = {}
        for k, raw in enumerate(self.class_names[1:], start=1):
            name = canonical_name(raw)
            if name in seen:
                # two ids of one class would be merged by name when scoring and change the scores
                raise PanovoccError(f"class_names has {name!r} twice (ids {seen[name]} and {k}; names are compared "
                                    "after lower-casing and tv-screen -> tv, lamp -> lighting)", where)
            seen[name] = k
        used = _values_used(self.labels)
        bad = used[(used >= len(self.class_names)) & (used < OCCUPIED_UNKNOWN_CLASS)]
        if bad.size:
            raise PanovoccError(f"label {int(bad[0])} has no entry in class_names ({len(self.class_names)} names)", where)
        return self
