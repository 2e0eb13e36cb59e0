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

from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..grid import Grid
from .npz import check_npz, write_npz



def read_grid(path: str | Path) -> Grid:
    """Load and validate a grid ``.npz`` (no pickle)."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("grid file not found", path)
    check_npz(path, "a grid .npz (labels, origin, voxel_size, class_names) written by map or gt")
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
