"""The global voxel lattice: voxel n covers [n h, (n + 1) h) on each axis (CONVENTIONS.md).

Every grid and the mapper share it, so two grids of the same voxel size compare voxel by voxel.
Keys pack a voxel index (i, j, k) into one int64 (21 bits a signed axis), for hashing and sorting. This
module is the one definition of that layout, :func:`pack_index` / :func:`unpack_index`: numpy code calls
them through :func:`pack_keys` / :func:`unpack_keys` (which check the range), numba kernels (the
memory's block hash, the PSVF extraction, the semantic evidence) compile the same two functions
(``numba.njit(inline="always")(pack_index)``; this module imports no numba, so ``--help`` stays light).
A map keys its voxels relative to its own origin (:func:`local_origin`, stored in the map's
``config.json``), so the range below is a range around the map's origin, not around the world's.
"""

from __future__ import annotations

import numpy as np

from ..config import LATTICE_TOL
from ..errors import PanovoccError

_BITS = 21  # a signed axis, stored offset by _OFFSET: k in bits 0-20, j in 21-41, i in 42-62
_OFFSET = 1 << (_BITS - 1)
_MASK = (1 << _BITS) - 1
KEY_RANGE = _OFFSET  # |index| must stay below this (about 84 km at 8 cm)


def pack_index(i, j, k):
    """The key of voxel ``(i, j, k)`` (int64 scalars or arrays of one shape), unchecked: an index outside
    ``|index| < KEY_RANGE`` wraps (:func:`pack_keys` refuses it). Keys sort x-major, then y, then z."""
    return (((i + _OFFSET) & _MASK) << (2 * _BITS)) | (((j + _OFFSET) & _MASK) << _BITS) | ((k + _OFFSET) & _MASK)


def unpack_index(key):
    """Inverse of :func:`pack_index`: the ``(i, j, k)`` of int64 key(s)."""
    return ((key >> (2 * _BITS)) & _MASK) - _OFFSET, ((key >> _BITS) & _MASK) - _OFFSET, (key & _MASK) - _OFFSET


def point_to_index(points, voxel_size: float) -> np.ndarray:
    """Integer voxel index ``(..., 3)`` int64 of points ``(..., 3)`` metres (world frame)."""
    return np.floor(np.asarray(points, dtype=np.float64) / voxel_size).astype(np.int64)


def index_to_center(index, voxel_size: float) -> np.ndarray:
    """World coordinates ``(..., 3)`` float64 of voxel centres ``(index + 0.5) h``."""
    return (np.asarray(index, dtype=np.float64) + 0.5) * voxel_size


def origin_to_index(origin, voxel_size: float) -> np.ndarray:
    """Lattice index of a grid origin (the centre of its voxel [0, 0, 0]); checks it lies on the lattice."""
    o = np.asarray(origin, dtype=np.float64) / voxel_size - 0.5
    n = np.round(o)
    if not np.allclose(o, n, atol=LATTICE_TOL):
        raise PanovoccError(
            f"grid origin {np.asarray(origin).tolist()} is not on the global lattice of voxel size {voxel_size} "
            "(origin / voxel_size - 0.5 must be whole)"
        )
    return n.astype(np.int64)


def pack_keys(index) -> np.ndarray:
    """Pack voxel indices ``(n, 3)`` int into ``(n,)`` int64 keys; ordering of keys is x-major."""
    idx = np.asarray(index, dtype=np.int64)
    if idx.size and (np.abs(idx).max() >= _OFFSET):
        raise PanovoccError(f"voxel index out of the lattice's range (|index| < {_OFFSET})")
    return pack_index(idx[..., 0], idx[..., 1], idx[..., 2])


def unpack_keys(keys) -> np.ndarray:
    """Inverse of :func:`pack_keys`: ``(n,)`` int64 -> ``(n, 3)`` int64 voxel indices."""
    return np.stack(unpack_index(np.asarray(keys, dtype=np.int64)), axis=-1)


def bounds_to_grid(lo, hi, voxel_size: float):
    """Dense grid covering the box [lo, hi] (metres) on the global lattice.

    Returns
    -------
    index0 : (3,) int64, lattice index of voxel [0, 0, 0]
    shape : (3,) int64, number of voxels per axis
    origin : (3,) float64, centre of voxel [0, 0, 0]
    """
    i0 = point_to_index(lo, voxel_size)
    i1 = point_to_index(hi, voxel_size)
    shape = (i1 - i0 + 1).astype(np.int64)
    return i0, shape, index_to_center(i0, voxel_size)


def local_origin(position, voxel_size: float) -> np.ndarray:
    """The lattice index (3,) int64 of the voxel holding ``position`` (3,) metres, world: a map's origin.

    A map made with this origin keys voxel ``n`` of the world lattice as ``n - origin``; its world
    placement is unchanged (the origin is a whole number of voxels)."""
    p = np.asarray(position, np.float64).reshape(3)
    if not np.all(np.isfinite(p)):
        raise PanovoccError(f"origin {p.tolist()} is not finite")
    o = np.floor(p / voxel_size)
    if np.any(np.abs(o) >= 2.0 ** 62):
        raise PanovoccError(f"origin {p.tolist()} m is beyond any lattice index at voxel size {voxel_size} m")
    return o.astype(np.int64)


def key_reach(voxel_size: float) -> float:
    """Metres from a map's origin, per axis, that its keys can hold (voxel centres strictly inside)."""
    return (KEY_RANGE - 2) * float(voxel_size)

