"""Semantic occupancy grid ``.npz`` (ground truth and predictions alike), CONVENTIONS.md:

============  ===================  ================================================================
key           shape, dtype         meaning
============  ===================  ================================================================
labels        (X, Y, Z) uint8      0 empty (observed free), 1..253 class index, 254 occupied with
                                   no class, 255 unknown (never observed; ignored in ground truth)
origin        (3,) float64         world coordinates of the centre of voxel [0, 0, 0]
voxel_size    () float64           edge length h in metres
class_names   (K,) str             class_names[0] == "empty"
============  ===================  ================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..geometry.lattice import index_to_center, origin_to_index
from .npz import write_npz

EMPTY = 0
OCCUPIED_UNKNOWN_CLASS = 254
UNKNOWN = 255
MAX_CLASSES = 254  # ids 0..253


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
        used = np.unique(self.labels)
        bad = used[(used >= len(self.class_names)) & (used < OCCUPIED_UNKNOWN_CLASS)]
        if bad.size:
            raise PanovoccError(f"label {int(bad[0])} has no entry in class_names ({len(self.class_names)} names)", where)
        return self


def read_grid(path: str | Path) -> Grid:
    """Load and validate a grid ``.npz`` (no pickle)."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("grid file not found", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("labels", "origin", "voxel_size", "class_names") if k not in z.files]
            if missing:
                raise PanovoccError(f"missing keys {missing} (expected labels, origin, voxel_size, class_names)", path)
            g = Grid(z["labels"], z["origin"], float(z["voxel_size"]), [str(c) for c in z["class_names"]])
    except PanovoccError:
        raise
    except Exception as e:  # zipfile.BadZipFile, ValueError (pickled object arrays), OSError
        raise PanovoccError(f"cannot read grid .npz ({type(e).__name__}: {e})", path) from None
    return g.validate(path)


def write_grid(path: str | Path, grid: Grid, compress: bool = True) -> None:
    """Validate and atomically write a grid ``.npz``."""
    grid.validate(path)
    write_npz(path, {"labels": grid.labels, "origin": grid.origin, "voxel_size": np.float64(grid.voxel_size),
                     "class_names": np.array(grid.class_names, dtype=np.str_)}, compress=compress)
