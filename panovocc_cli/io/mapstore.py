"""A map folder's files: the per-frame delta files, the memory file and the map's ``config.json``.

Layout (docs/mapping.md, "Output folder")::

    OUT/config.json        the resolved map configuration (JSON object)
    OUT/memory.npz         the memory: non-zero voxels in key order, integer channels, frames_done, poses
    OUT/deltas/NNNNNN.npz  one frame's sparse delta: keys, integer channels, the pose it was computed under
    OUT/poses.txt          the poses of the retained frames (NICE-SLAM form, :mod:`.poses`)

This module knows the bytes only; the meaning (a :class:`mapping.memory.Delta`, the reversible update)
lives in :mod:`panovocc_cli.mapping.rpu`. Every write is atomic and deterministic (fixed zip dates,
sorted entries), so equal contents give equal files.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping, NamedTuple

import numpy as np

from ..errors import PanovoccError
from .atomic import write_text
from .npz import write_npz
from .sequence import frame_stem

CONFIG_NAME = "config.json"
MEMORY_NAME = "memory.npz"
DELTAS_DIR = "deltas"
STAGED_SUFFIX = ".new"  # a revised delta waiting for the memory file that commits it
DELTA_COMPRESSLEVEL = 1  # zlib level of delta files (docs/mapping.md, "Delta store size")
MEMORY_COMPRESSLEVEL = 1  # zlib level of memory.npz (channels stored as for deltas: compact, sparse rows)


class SparseRows(NamedTuple):
    """A channel given by its possibly non-zero rows: ``values`` (m, width) at row positions ``rows`` (m,)
    int64 ascending of an (n, width) array that is zero elsewhere. Encoded to the same bytes as the dense
    array (:func:`_encode_channels`); what a memory with sparse semantic rows saves and loads, so neither
    makes the (n, width) array."""

    rows: np.ndarray
    values: np.ndarray
    n: int

    def dense(self) -> np.ndarray:
        out = np.zeros((self.n, self.values.shape[1]), np.int64)
        out[self.rows] = self.values
        return out


def delta_path(folder: str | Path, frame_id: int) -> Path:
    """``folder/deltas/NNNNNN.npz`` of frame ``frame_id``."""
    return Path(folder) / DELTAS_DIR / f"{frame_stem(int(frame_id))}.npz"


def staged_path(path: Path) -> Path:
    """The staging name of a delta file (``NNNNNN.npz.new``)."""
    return path.with_name(path.name + STAGED_SUFFIX)


def _compact(a: np.ndarray) -> np.ndarray:
    """Smallest signed integer dtype holding ``a`` (deterministic; read back as int64)."""
    if a.size == 0:
        return a.astype(np.int8)
    lo, hi = int(a.min()), int(a.max())
    for dt in (np.int8, np.int16, np.int32):
        if np.iinfo(dt).min <= lo and hi <= np.iinfo(dt).max:
            return a.astype(dt)
    return a


def _shuffled(arrays: dict, key: str, a: np.ndarray) -> None:
    """Store the 2-D integer array ``a`` under ``key``: as it is when its type has one byte, else as its
    byte planes (``(itemsize, a.size)`` uint8: every value's lowest byte, then every value's next byte...)
    with its shape under ``shape_`` + the name. The high planes of small values are runs of 0x00 or 0xff,
    which zlib compresses in passing: about a third less time and a fifth fewer bytes on the semantic
    channels than the values as they are (docs/mapping.md, "Delta store size")."""
    if a.dtype.itemsize == 1:
        arrays[key] = a
        return
    a = np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<"))
    arrays[key] = np.ascontiguousarray(a.reshape(-1).view(np.uint8).reshape(-1, a.dtype.itemsize).T)
    pre, name = key.split("ch_", 1)
    arrays[f"{pre}shape_{name}"] = np.array(a.shape, np.int64)


def _unshuffled(z, files, key: str) -> np.ndarray:
    """Inverse of :func:`_shuffled`: the stored array as int64."""
    a = np.asarray(z[key])
    pre, name = key.split("ch_", 1)
    if f"{pre}shape_{name}" in files:
        shape = tuple(int(x) for x in np.asarray(z[f"{pre}shape_{name}"]))
        a = np.ascontiguousarray(a.T).view(f"<i{a.shape[0]}").reshape(shape)
    return a.astype(np.int64)


def _encode_channels(arrays: dict, prefix: str, n: int, channels: Mapping[str, np.ndarray]) -> None:
    """Put ``channels`` ((n, width) integer arrays) into ``arrays`` as ``{prefix}ch_NAME``, each in the
    smallest signed integer type that holds it, stored as byte planes (:func:`_shuffled`). A channel that
    is zero on most rows is stored as its non-zero rows and their row indices as differences
    ``{prefix}rows_NAME``: zlib no longer spends its time on zeros."""
    for name, arr in channels.items():
        if isinstance(arr, SparseRows):
            nz = np.asarray(arr.values).any(axis=1)
            rows, vals = np.asarray(arr.rows, np.int64)[nz], np.asarray(arr.values)[nz]
            if 2 * len(rows) < n:
                _shuffled(arrays, f"{prefix}ch_{name}", _compact(vals))
                arrays[f"{prefix}rows_{name}"] = _compact(np.diff(rows, prepend=np.int64(0)))
                continue
            arr = SparseRows(rows, vals, n).dense()
        arr = np.asarray(arr)
        arr = arr.reshape(n, arr.shape[-1] if arr.ndim == 2 else -1) if n == 0 else arr.reshape(n, -1)
        rows = np.flatnonzero(arr.any(axis=1)) if n else np.zeros(0, np.int64)
        if 2 * len(rows) < n:
            _shuffled(arrays, f"{prefix}ch_{name}", _compact(arr[rows]))
            arrays[f"{prefix}rows_{name}"] = _compact(np.diff(rows, prepend=np.int64(0)))
        else:
            _shuffled(arrays, f"{prefix}ch_{name}", _compact(arr))


def _decode_channels(z, prefix: str, n: int, sparse: bool = False) -> dict:
    """Inverse of :func:`_encode_channels`: dict name -> (n, width) int64 (``sparse``: a channel stored as
    rows stays a :class:`SparseRows`)."""
    ch = {}
    head = f"{prefix}ch_"
    files = set(z.files if hasattr(z, "files") else z)
    for k in sorted(files):
        if not k.startswith(head):
            continue
        name = k[len(head):]
        vals = _unshuffled(z, files, k)
        if f"{prefix}rows_{name}" in files:  # sparse rows
            rows = np.cumsum(np.asarray(z[f"{prefix}rows_{name}"]).astype(np.int64))
            if sparse:
                ch[name] = SparseRows(rows, vals.reshape(len(rows), vals.shape[1] if vals.ndim == 2 else 1), n)
                continue
            full = np.zeros((n, vals.shape[1] if vals.ndim == 2 else 1), np.int64)
            full[rows] = vals.reshape(len(rows), full.shape[1])
            ch[name] = full
        else:
            ch[name] = vals if vals.ndim == 2 else vals.reshape(n, -1)
    return ch


def _part_prefix(i: int) -> str:
    return "" if i == 0 else f"p{i}_"


def write_delta(path: str | Path, parts, T_world_cam: np.ndarray) -> None:
    """Atomically write one frame's delta.

    Parameters
    ----------
    parts : sequence of (keys, channels), one per contributor (:class:`mapping.memory.FrameDelta`):
        keys (n,) int64 sorted unique voxel keys (``geometry.lattice.pack_keys``), stored as differences
        (first key, then gaps), which compress to almost nothing; channels dict name -> (n, width) int64
        (:func:`_encode_channels`). Part 0's arrays are ``keys_diff``, ``ch_NAME``, ``rows_NAME``; part i's
        carry the prefix ``p{i}_``.
    T_world_cam : (4, 4) float64, the pose the delta was computed under
    """
    arrays = {"T_world_cam": np.asarray(T_world_cam, np.float64)}
    for i, (keys, channels) in enumerate(parts):
        pre = _part_prefix(i)
        arrays[f"{pre}keys_diff"] = np.diff(np.asarray(keys, np.int64), prepend=np.int64(0))
        _encode_channels(arrays, pre, len(keys), channels)
    write_npz(path, arrays, compresslevel=DELTA_COMPRESSLEVEL)


def read_delta(path: str | Path) -> tuple[list, np.ndarray]:
    """Read a delta file: (parts, T_world_cam (4, 4)); parts a list of (keys (n,) int64, channels dict
    name -> (n, width) int64), in the order they were written."""
    path = Path(path)
    if not path.is_file():
        raise PanovoccError("delta file missing (the map folder is incomplete)", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            parts = []
            while f"{_part_prefix(len(parts))}keys_diff" in z.files:
                pre = _part_prefix(len(parts))
                keys = np.cumsum(z[f"{pre}keys_diff"].astype(np.int64))
                parts.append((keys, _decode_channels(z, pre, len(keys))))
            T = np.asarray(z["T_world_cam"], np.float64)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same failure
        raise PanovoccError(f"cannot read delta ({type(e).__name__}: {e})", path) from None
    if T.shape != (4, 4):
        raise PanovoccError(f"delta pose has shape {T.shape}, expected (4, 4)", path)
    return parts, T


def write_memory(folder: str | Path, arrays: Mapping[str, np.ndarray], frames_done: int, poses: np.ndarray,
                 frame_ids: np.ndarray | None = None) -> None:
    """Atomically write ``folder/memory.npz``.

    Parameters
    ----------
    arrays : the memory's canonical arrays (``VoxelMemory.to_arrays``)
    frames_done : int, frames the memory holds (a map run's checkpoint: frames 0..frames_done-1)
    poses : (n, 4, 4) float64, the poses the retained deltas were computed under, in frame-id order
    frame_ids : (n,) int64 or None; stored only when the ids are not ``0..n-1`` (a mapper that removed
        frames or was fed its own ids), so a plain map run's file keeps its historical bytes
    """
    out = {k: v for k, v in arrays.items() if not k.startswith("ch_")}
    n = len(arrays["keys"])
    _encode_channels(out, "", n, {k[3:]: v for k, v in arrays.items() if k.startswith("ch_")})
    out["keys"] = np.diff(np.asarray(arrays["keys"], np.int64), prepend=np.int64(0))  # as differences
    out["keys_are_diffs"] = np.int64(1)
    out["frames_done"] = np.int64(frames_done)
    out["poses"] = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    if frame_ids is not None:
        out["frame_ids"] = np.asarray(frame_ids, np.int64)
    write_npz(Path(folder) / MEMORY_NAME, out, compresslevel=MEMORY_COMPRESSLEVEL)


def read_memory(folder: str | Path, sparse: bool = False) -> tuple[dict, int, np.ndarray, np.ndarray | None]:
    """Read ``folder/memory.npz``: (memory arrays, frames_done, poses (n, 4, 4) float64, frame_ids or None);
    ``sparse``: channels stored as rows come as :class:`SparseRows`."""
    path = Path(folder) / MEMORY_NAME
    if not path.is_file():
        raise PanovoccError("memory.npz not found (not a panovocc map folder, or the run stopped before "
                            "its first checkpoint)", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if not k.startswith(("ch_", "rows_"))}
            keys = np.asarray(arrays["keys"], np.int64)
            if int(arrays.pop("keys_are_diffs", 0)):  # older memory files store the keys themselves
                keys = np.cumsum(keys)
            arrays["keys"] = keys
            arrays.update({f"ch_{k}": v for k, v in _decode_channels(z, "", len(keys), sparse).items()})
        frames_done = int(arrays.pop("frames_done"))
        poses = np.asarray(arrays.pop("poses"), np.float64)
        ids = arrays.pop("frame_ids", None)
    except PanovoccError:
        raise
    except Exception as e:  # noqa: BLE001
        raise PanovoccError(f"cannot read memory ({type(e).__name__}: {e})", path) from None
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise PanovoccError(f"poses have shape {poses.shape}, expected (n, 4, 4)", path)
    if ids is not None and (ids.shape != (len(poses),) or len(np.unique(ids)) != len(ids)):
        raise PanovoccError(f"frame_ids {ids.shape} do not match {len(poses)} poses", path)
    return arrays, frames_done, poses, None if ids is None else np.asarray(ids, np.int64)


def read_map_config(folder: str | Path) -> dict:
    """``folder/config.json`` as a dict."""
    path = Path(folder) / CONFIG_NAME
    if not path.is_file():
        raise PanovoccError("config.json not found (not a panovocc map folder)", path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise PanovoccError(f"invalid JSON ({type(e).__name__}: {e})", path) from None
    if not isinstance(d, dict):
        raise PanovoccError("expected a JSON object", path)
    return d


def write_map_config(folder: str | Path, config: dict) -> None:
    """Atomically write ``folder/config.json`` (indented JSON, key order kept)."""
    write_text(Path(folder) / CONFIG_NAME, json.dumps(config, indent=2) + "\n")
