"""Aligning two grids on the global lattice (CONVENTIONS.md): integer offsets, no resampling.

Two grids of the same voxel size share the lattice, so voxel ``(i, j, k)`` of one grid is voxel
``(i, j, k) + a.index0 - b.index0`` of the other whatever their origins and extents.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import VOXEL_SIZE_RTOL
from ..errors import PanovoccError
from ..grid import Grid


@dataclass(frozen=True)
class Overlap:
    """The common box of two grids, as slices into each.

    ``a.labels[a_slices]`` and ``b.labels[b_slices]`` have the same shape and cover the same voxels
    of the lattice; ``empty`` is True when the grids do not overlap at all (the slices then select
    nothing).
    """

    a_slices: tuple[slice, slice, slice]
    b_slices: tuple[slice, slice, slice]
    shape: tuple[int, int, int]

    @property
    def empty(self) -> bool:
        return min(self.shape) <= 0


def check_same_voxel_size(a: Grid, b: Grid, what: str = "grids") -> None:
    """Raise :class:`PanovoccError` unless the two grids have the same voxel size (relative 1e-6)."""
    if not np.isclose(a.voxel_size, b.voxel_size, rtol=VOXEL_SIZE_RTOL, atol=0.0):
        raise PanovoccError(
            f"{what} have different voxel sizes ({a.voxel_size:g} m and {b.voxel_size:g} m); "
            "they must share one lattice (resample one of them first)"
        )


def overlap(a: Grid, b: Grid) -> Overlap:
    """Slices selecting the voxels the two grids have in common.

    Parameters
    ----------
    a, b : Grid
        Grids of the same voxel size (checked) on the global lattice.

    Returns
    -------
    Overlap
        ``a_slices``/``b_slices`` (3 slices each) and the common ``shape`` (all >= 0).
    """
    check_same_voxel_size(a, b)
    a0, b0 = a.index0, b.index0
    a1 = a0 + np.asarray(a.labels.shape, dtype=np.int64)
    b1 = b0 + np.asarray(b.labels.shape, dtype=np.int64)
    lo = np.maximum(a0, b0)
    hi = np.maximum(np.minimum(a1, b1), lo)
    a_sl = tuple(slice(int(lo[d] - a0[d]), int(hi[d] - a0[d])) for d in range(3))
    b_sl = tuple(slice(int(lo[d] - b0[d]), int(hi[d] - b0[d])) for d in range(3))
    return Overlap(a_sl, b_sl, tuple(int(x) for x in hi - lo))  # type: ignore[arg-type]


def resample_onto(src: Grid, dst: Grid, fill: int = 255) -> np.ndarray:
    """Labels of ``src`` on the voxels of ``dst`` (same lattice), ``fill`` where ``src`` has none.

    Returns
    -------
    labels : dst.labels.shape uint8, ids into ``src.class_names``
    """
    ov = overlap(dst, src)
    out = np.full(dst.labels.shape, fill, dtype=np.uint8)
    if not ov.empty:
        out[ov.a_slices] = src.labels[ov.b_slices]
    return out
