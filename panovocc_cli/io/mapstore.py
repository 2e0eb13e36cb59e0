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
from .npz import StreamedArray, load_npz, write_npz
from .record_kernels import (factor_rows, from_planes, key_gaps, keys_from_gaps, nonzero_rows, scatter_rows,
                             to_planes)
from .sequence import frame_stem

CONFIG_NAME = "config.json"
MEMORY_NAME = "memory.npz"
DELTAS_DIR = "deltas"
STAGED_SUFFIX = ".new"  # a revised delta waiting for the memory file that commits it
DELTA_COMPRESSLEVEL = 1  # zlib level of per-frame delta files (write_delta; docs/mapping.md, "Delta store size")
RECORD_ZSTD_LEVEL = 3  # Zstandard level of the delta log's records (encode_arrays; "Delta store size")
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"  # a Zstandard frame's first bytes; a zlib stream's first byte is 0x78
# memory.npz: channels stored as for deltas (compact, sparse rows), deflated by ISA-L (io.npz.write_npz ``fast``)


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


def _int_type(lo: int, hi: int) -> np.dtype:
    """The type :func:`_compact` gives an array whose values span ``lo..hi`` (0 included: no array's type
    depends on whether it holds a 0)."""
    lo, hi = min(int(lo), 0), max(int(hi), 0)
    for dt in (np.int8, np.int16, np.int32):
        if np.iinfo(dt).min <= lo and hi <= np.iinfo(dt).max:
            return np.dtype(dt)
    return np.dtype(np.int64)


def _compact(a: np.ndarray) -> np.ndarray:
    """Smallest signed integer dtype holding ``a`` (deterministic; read back as int64)."""
    if a.size == 0:
        return a.astype(np.int8)
    return a.astype(_int_type(a.min(), a.max()), copy=False)


def _row_any(a: np.ndarray) -> np.ndarray:
    """``a.any(axis=1)`` of an (m, width) array: column by column up to width 4 (numpy's reduction over a
    short axis costs ~100 ns a row; a channel's rows are read several times a save and a record)."""
    if a.ndim != 2 or a.shape[1] > 4 or a.shape[1] == 0:
        return a.any(axis=1)
    out = a[:, 0] != 0
    for c in range(1, a.shape[1]):
        out |= a[:, c] != 0
    return out


def _shuffled(arrays: dict, key: str, a: np.ndarray) -> None:
    """Store the 2-D integer array ``a`` under ``key``: as it is when its type has one byte, else as its
    byte planes (``(itemsize, a.size)`` uint8: every value's lowest byte, then every value's next byte...)
    with its shape under ``shape_`` + the name. The high planes of small values are runs of 0x00 or 0xff,
    which zlib compresses in passing: about a third less time and a fifth fewer bytes on the semantic
    channels than the values as they are (docs/mapping.md, "Delta store size")."""
    if a.dtype.itemsize == 1:
        arrays[key] = a
        return
    if a.dtype.kind == "i" and a.dtype.isnative and a.dtype.itemsize in (2, 4, 8):  # one compiled pass, the same bytes
        arrays[key] = to_planes(np.ascontiguousarray(a), a.dtype.itemsize)
    else:
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
        if a.ndim == 2 and a.dtype == np.uint8 and a.shape[0] in (2, 4, 8):  # one compiled pass, the same values
            return from_planes(np.ascontiguousarray(a)).reshape(shape)
        a = np.ascontiguousarray(a.T).view(f"<i{a.shape[0]}").reshape(shape)
    return a.astype(np.int64)


class StoredRows:
    """A memory file's channel as it is stored (its compact type, as byte planes or as it is, the quotients
    of its common divisor ``g``), (m, width) int64 when read: ``a[i:j]`` decodes rows i..j-1 only
    (``np.asarray(a)``: all of them). What :func:`read_memory` gives with ``sparse``, so a load adds a
    file to the memory a chunk of rows at a time without an int64 copy of every channel beside it."""

    ndim = 2
    dtype = np.dtype(np.int64)

    def __init__(self, raw: np.ndarray, shape: tuple, planes: bool, g: int):
        self._raw, self.shape, self._planes, self._g = raw, (int(shape[0]), int(shape[1])), planes, int(g)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        if not isinstance(key, slice) or key.step not in (None, 1):
            raise TypeError("StoredRows reads slices of rows")
        a, b, _ = key.indices(self.shape[0])
        b, w = max(a, b), self.shape[1]
        if self._planes and self._raw.dtype == np.uint8 and self._raw.shape[0] in (2, 4, 8):
            x = from_planes(self._raw[:, a * w:b * w]).reshape(b - a, w)  # one compiled pass, a new int64 array
        else:
            if self._planes:
                x = np.ascontiguousarray(self._raw[:, a * w:b * w].T).view(f"<i{self._raw.shape[0]}")
            else:
                x = self._raw.reshape(-1)[a * w:b * w]
            x = x.reshape(b - a, w).astype(np.int64)
        if self._g > 1:
            x *= self._g
        return x

    def __array__(self, dtype=None, copy=None):
        x = self[:]
        return x if dtype is None else x.astype(dtype)


def _stored_rows(z, files, prefix: str, name: str, n: int, m: int | None) -> StoredRows:
    """:class:`StoredRows` of channel ``name`` (m rows; None: n rows, or as the shape entry says)."""
    raw = np.asarray(z[f"{prefix}ch_{name}"])
    planes = f"{prefix}shape_{name}" in files
    if planes:
        shape = tuple(int(x) for x in np.asarray(z[f"{prefix}shape_{name}"]))
    else:
        rows = n if m is None else m
        shape = (rows, raw.size // max(rows, 1) if raw.ndim != 2 else raw.shape[1])
    g = int(np.asarray(z[f"{prefix}gcd_{name}"]).reshape(-1)[0]) if f"{prefix}gcd_{name}" in files else 1
    return StoredRows(raw, shape, planes, g)


def _factored(channels: Mapping[str, np.ndarray], factors: Mapping[str, tuple] | None, n: int) -> tuple[dict, dict]:
    """The channels with each one that factors as ``factor * m / denominator`` (``factors``: name ->
    (factor channel, denominator)) replaced by the integer array m, and the factorisations that held.
    A hint that does not hold exactly on every row (m not an integer, or the channel non-zero where its
    factor is 0) leaves that channel as it is."""
    out, used = dict(channels), {}
    for name, (fname, den) in (factors or {}).items():
        if name not in channels or fname not in channels or fname in (factors or {}) or isinstance(
                channels[name], SparseRows) or isinstance(channels[fname], SparseRows):
            continue
        x = np.asarray(channels[name], np.int64).reshape(n, -1)
        f = np.asarray(channels[fname], np.int64).reshape(n, -1)
        if f.shape[1] != 1:
            continue
        # m = x den // f where f != 0, else 0; it holds when m f == x den (int64 wrapping as numpy's)
        ok, m = factor_rows(np.ascontiguousarray(x), np.ascontiguousarray(f[:, 0]), np.int64(den))
        if ok:
            out[name], used[name] = m, (fname, int(den))
    return out, used


def _encode_channels(arrays: dict, prefix: str, n: int, channels: Mapping[str, np.ndarray],
                     factors: Mapping[str, tuple] | None = None) -> None:
    """Put ``channels`` ((n, width) integer arrays) into ``arrays`` as ``{prefix}ch_NAME``, each in the
    smallest signed integer type that holds it, stored as byte planes (:func:`_shuffled`).

    * A channel that is zero on most rows is stored as its non-zero rows and their row indices as
      differences ``{prefix}rows_NAME``: zlib no longer spends its time on zeros.
    * A channel of width >= 4 whose kept rows are mostly zeros (a class distribution over a vocabulary)
      is stored as its non-zero entries, with the bit mask of where they are (``{prefix}nz_NAME``, packed
      bits, shape ``{prefix}nzshape_NAME``).
    * A channel that factors (``factors``, :func:`_factored`) is stored as the integer m of
      ``channel = factor * m / denominator``, with ``{prefix}fac_NAME`` = the denominator and
      ``{prefix}facby_NAME`` = the factor channel's name (UTF-8 bytes).
    """
    channels, used = _factored(channels, factors, n)
    for name, (fname, den) in used.items():
        arrays[f"{prefix}fac_{name}"] = np.array([den], np.int64)
        arrays[f"{prefix}facby_{name}"] = np.frombuffer(fname.encode(), np.uint8).copy()
    for name, arr in channels.items():
        if isinstance(arr, SparseRows):
            nz = _row_any(np.asarray(arr.values))
            rows, vals = np.asarray(arr.rows, np.int64)[nz], np.asarray(arr.values)[nz]
            if 2 * len(rows) < n:
                _put_values(arrays, prefix, name, _compact(vals))
                arrays[f"{prefix}rows_{name}"] = _compact(np.diff(rows, prepend=np.int64(0)))
                continue
            arr = SparseRows(rows, vals, n).dense()
        arr = np.asarray(arr)
        arr = arr.reshape(n, arr.shape[-1] if arr.ndim == 2 else -1) if n == 0 else arr.reshape(n, -1)
        if not n:
            rows = np.zeros(0, np.int64)
        elif arr.dtype in (np.int64, np.int32):  # one compiled pass: np.flatnonzero(_row_any(arr))
            rows = nonzero_rows(arr)
        else:
            rows = np.flatnonzero(_row_any(arr))
        if 2 * len(rows) < n:
            _put_values(arrays, prefix, name, _compact(arr[rows]))
            arrays[f"{prefix}rows_{name}"] = _compact(np.diff(rows, prepend=np.int64(0)))
        else:
            _put_values(arrays, prefix, name, _compact(arr))


_GCD_BLOCK = 1 << 12  # values in the first block common_divisor reads (then 4x more each block, up to _GCD_MAX)
_GCD_MAX = 1 << 22  # values a block holds at most (no int64 copy of a whole large channel)


def _gcd_reduce(a: np.ndarray):
    return np.gcd.reduce(a)


def common_divisor(a: np.ndarray) -> int:
    """The greatest common divisor of the values of the integer array ``a`` (any shape; 0 when it has no
    value other than 0): ``np.gcd.reduce(np.abs(a.astype(np.int64)), axis=None)``, read block by block
    (growing) and stopped once it is 1, which the first block of most channels settles (a memory
    channel's 16.7 M values cost ~0.15-0.5 s CPU in one reduction)."""
    flat = np.asarray(a).reshape(-1)
    g, start, step = 0, 0, _GCD_BLOCK
    while start < flat.size and g != 1:
        g = int(np.gcd(g, _gcd_reduce(np.abs(flat[start:start + step].astype(np.int64)))))
        start += step
        step = min(4 * step, _GCD_MAX)
    return g


def _put_values(arrays: dict, prefix: str, name: str, a: np.ndarray) -> None:
    """A channel's kept rows ``a`` (m, width): as byte planes, or, when wide and mostly zeros, as its
    non-zero entries and their bit mask; values with a common divisor g > 1 as the quotients and g
    (``{prefix}gcd_NAME``) (:func:`_encode_channels`)."""
    g = common_divisor(a)
    if g > 1:
        arrays[f"{prefix}gcd_{name}"] = np.array([g], np.int64)
        a = _compact(a // a.dtype.type(g))  # exact: g divides every value (in a's own type: no int64 copy)
    if a.ndim == 2 and a.shape[1] >= 4:
        mask = a != 0
        k = int(mask.sum())
        if 3 * k < a.size:
            arrays[f"{prefix}nz_{name}"] = np.packbits(mask, axis=None)
            arrays[f"{prefix}nzshape_{name}"] = np.array(a.shape, np.int64)
            a = a[mask].reshape(k, 1)
    _shuffled(arrays, f"{prefix}ch_{name}", a)


def _decode_channels(z, prefix: str, n: int, sparse: bool = False) -> dict:
    """Inverse of :func:`_encode_channels`: dict name -> (n, width) int64 (``sparse``: a channel stored as
    rows stays a :class:`SparseRows`, and a channel stored without a mask or factor is a :class:`StoredRows`,
    decoded when sliced)."""
    ch = {}
    head = f"{prefix}ch_"
    files = set(z.files if hasattr(z, "files") else z)
    for k in sorted(files):
        if not k.startswith(head):
            continue
        name = k[len(head):]
        if sparse and f"{prefix}nz_{name}" not in files and f"{prefix}fac_{name}" not in files:
            rows = np.cumsum(np.asarray(z[f"{prefix}rows_{name}"]).astype(np.int64)) if f"{prefix}rows_{name}" in \
                files else None
            vals = _stored_rows(z, files, prefix, name, n, None if rows is None else len(rows))
            ch[name] = vals if rows is None else SparseRows(rows, vals, n)  # decoded a slice at a time
            continue
        vals = _unshuffled(z, files, k)
        if f"{prefix}gcd_{name}" in files:
            vals = vals * int(np.asarray(z[f"{prefix}gcd_{name}"]).reshape(-1)[0])
        if f"{prefix}nz_{name}" in files:  # non-zero entries and their mask
            shape = tuple(int(x) for x in np.asarray(z[f"{prefix}nzshape_{name}"]))
            mask = np.unpackbits(np.asarray(z[f"{prefix}nz_{name}"], np.uint8),
                                 count=int(np.prod(shape, dtype=np.int64))).astype(bool).reshape(shape)
            full = np.zeros(shape, np.int64)
            full[mask] = vals.reshape(-1)
            vals = full
        if f"{prefix}rows_{name}" in files:  # sparse rows
            gaps = np.asarray(z[f"{prefix}rows_{name}"]).astype(np.int64)
            if not sparse:  # one compiled pass: zeros, then the rows at the running sum of their gaps
                w = vals.shape[1] if vals.ndim == 2 else 1
                ok, ch[name] = scatter_rows(n, gaps.reshape(-1), np.ascontiguousarray(vals.reshape(len(gaps), w)))
                if not ok:
                    raise IndexError(f"channel {name}: a row outside 0..{n - 1}")
                continue
            rows = np.cumsum(gaps)
            ch[name] = SparseRows(rows, vals.reshape(len(rows), vals.shape[1] if vals.ndim == 2 else 1), n)
        else:
            ch[name] = vals if vals.ndim == 2 else vals.reshape(n, -1)
    for name in [k[len(prefix) + 4:] for k in sorted(files) if k.startswith(f"{prefix}fac_")]:
        den = int(np.asarray(z[f"{prefix}fac_{name}"]).reshape(-1)[0])
        fname = bytes(np.asarray(z[f"{prefix}facby_{name}"], np.uint8)).decode()
        f = ch[fname]
        f = f.dense() if isinstance(f, SparseRows) else f
        m = ch[name]
        m = m.dense() if isinstance(m, SparseRows) else m
        ch[name] = (m * f) // den
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


def _nonzero_rows(v, start: int) -> tuple[np.ndarray, np.ndarray]:
    """One chunk of a channel (rows ``start..``, (m, width), or :class:`SparseRows` over the whole order)
    -> (positions of its non-zero rows in the whole order, their values)."""
    if isinstance(v, SparseRows):
        vals = np.asarray(v.values)
        nz = _row_any(vals)
        rows = np.asarray(v.rows, np.int64)
        return (rows, vals) if nz.all() else (rows[nz], vals[nz])  # a row is rarely all zeros: no copy then
    v = np.asarray(v)
    nz = np.flatnonzero(_row_any(v))
    return start + nz, (v if len(nz) == len(v) else v[nz])


def _all_rows(v, start: int, m: int) -> np.ndarray:
    """One chunk of a channel as its m rows (zeros where a :class:`SparseRows` has none)."""
    if isinstance(v, SparseRows):
        out = np.zeros((m, v.values.shape[1]), v.values.dtype)
        out[np.asarray(v.rows, np.int64) - start] = v.values
        return out
    return np.asarray(v)


class _StreamPlan(NamedTuple):
    """How :func:`_encode_channels` stores one channel, found by one pass over the chunks."""

    rows: bool  # stored as its non-zero rows (and their gaps ``rows_``)
    m: int  # rows kept
    width: int
    g: int  # common divisor (> 1: the quotients are stored)
    dtype: np.dtype  # of the stored values
    mask: bool  # as its non-zero entries and their bit mask
    k: int  # non-zero entries
    gap_type: np.dtype


_GCD_ROWS = 1 << 14  # rows of a chunk whose common divisor a streamed save takes at a time


def _stream_plans(source, n: int, widths: Mapping[str, int]) -> dict:
    st = {name: [0, 0, 0, 0, 0, 0, 0] for name in widths}  # nz rows, lo, hi, gcd, entries, max gap, last row
    for start, _, ch in source.chunks(list(widths), keys=False):
        for name, s in st.items():
            rows, vals = _nonzero_rows(ch[name], start)
            if not len(rows):
                continue
            s[0] += len(rows)
            s[1], s[2] = min(s[1], int(vals.min())), max(s[2], int(vals.max()))
            for a in range(0, len(vals) if s[3] != 1 else 0, _GCD_ROWS):  # int64 copies of a few rows at a time
                s[3] = int(np.gcd(s[3], common_divisor(vals[a:a + _GCD_ROWS])))
                if s[3] == 1:
                    break
            s[4] += int(np.count_nonzero(vals))
            s[5] = max(s[5], int(rows[0] - s[6]), int(np.diff(rows).max()) if len(rows) > 1 else 0)
            s[6] = int(rows[-1])
    plans = {}
    for name, (nz, lo, hi, g, k, gap, _) in st.items():
        rows = 2 * nz < n
        m, w = (nz if rows else n), int(widths[name])
        dtype = _int_type(lo // g, hi // g) if g > 1 else _int_type(lo, hi)
        plans[name] = _StreamPlan(rows, m, w, g, dtype, w >= 4 and 3 * k < m * w, k, _int_type(0, gap))
    return plans


def _streamed_channels(out: dict, source, n: int, widths: Mapping[str, int]) -> None:
    """:func:`_encode_channels` of ``source``'s channels (no factors) as :class:`~.npz.StreamedArray`
    entries read chunk by chunk: the same entries, the same bytes, one chunk held at a time."""
    for name, p in _stream_plans(source, n, widths).items():
        def values(name=name, p=p):  # the stored values, chunk by chunk, in their stored type
            for start, keys, ch in source.chunks([name], keys=False):
                v = _nonzero_rows(ch[name], start)[1] if p.rows else _all_rows(ch[name], start, len(keys))
                if p.g > 1:
                    v = v // v.dtype.type(p.g)  # exact
                v = v.astype(p.dtype)
                yield v[v != 0] if p.mask else v

        shape = (p.k, 1) if p.mask else (p.m, p.width)
        if p.g > 1:
            out[f"gcd_{name}"] = np.array([p.g], np.int64)
        if p.mask:
            out[f"nz_{name}"] = StreamedArray(np.uint8, ((p.m * p.width + 7) // 8,), lambda name=name, p=p: _packed(
                source, name, p))
            out[f"nzshape_{name}"] = np.array((p.m, p.width), np.int64)
        if p.rows:
            out[f"rows_{name}"] = StreamedArray(p.gap_type, (p.m,), lambda name=name, p=p: _gaps(source, name, p))
        size = p.dtype.itemsize
        if size == 1:
            out[f"ch_{name}"] = StreamedArray(p.dtype, shape, values)
        else:
            total = int(np.prod(shape))
            out[f"ch_{name}"] = StreamedArray(np.uint8, (size, total), lambda values=values, p=p, total=total: _planes(
                values, p.dtype, total))
            out[f"shape_{name}"] = np.array(shape, np.int64)


def _planes(values, dtype: np.dtype, total: int, piece: int = 1 << 22):
    """The byte planes of :func:`_shuffled` (byte b of every value, b = 0, 1, ...) of the ``total`` values
    ``values()`` yields: the channel is gathered once in its stored type (one channel, not every channel in
    int64; reading the memory again for each plane cost more than the encoding), then given a piece of a
    plane at a time."""
    size = dtype.itemsize
    whole, at = np.empty(total, dtype.newbyteorder("<")), 0
    for v in values():
        v = v.reshape(-1)
        whole[at:at + len(v)] = v
        at += len(v)
    planes = whole.view(np.uint8).reshape(-1, size)
    for b in range(size):
        for a in range(0, total, piece):
            yield np.ascontiguousarray(planes[a:a + piece, b])


def _gaps(source, name: str, p: _StreamPlan):
    last = 0
    for start, _, ch in source.chunks([name], keys=False):
        rows = _nonzero_rows(ch[name], start)[0]
        if len(rows):
            yield np.diff(rows, prepend=np.int64(last)).astype(p.gap_type)
            last = int(rows[-1])


def _packed(source, name: str, p: _StreamPlan):
    """``np.packbits`` of the kept rows' non-zero mask, chunk by chunk (the bits past a whole byte carried)."""
    carry = np.zeros(0, np.bool_)
    for start, keys, ch in source.chunks([name], keys=False):
        v = _nonzero_rows(ch[name], start)[1] if p.rows else _all_rows(ch[name], start, len(keys))
        bits = np.concatenate([carry, (v != 0).reshape(-1)])
        whole = len(bits) // 8 * 8
        yield np.packbits(bits[:whole])
        carry = bits[whole:]
    if len(carry):
        yield np.packbits(carry)


def _streamed_keys(source):
    last = 0
    for _, keys, _ in source.chunks():
        if len(keys):
            yield np.diff(keys, prepend=np.int64(last))
            last = int(keys[-1])


def write_memory(folder: str | Path, arrays, frames_done: int, poses: np.ndarray,
                 frame_ids: np.ndarray | None = None) -> None:
    """Atomically write ``folder/memory.npz``.

    Parameters
    ----------
    arrays : the memory's canonical arrays (``VoxelMemory.to_arrays``), or the same read a key range at a
        time (``VoxelMemory.chunked()``: ``header``, ``n``, ``chunks(names)``), written as a stream to the
        same bytes without holding every voxel's keys and channels (docs/mapping.md, "Memory layout")
    frames_done : int, frames the memory holds (a map run's checkpoint: frames 0..frames_done-1)
    poses : (n, 4, 4) float64, the poses the retained deltas were computed under, in frame-id order
    frame_ids : (n,) int64 or None; stored only when the ids are not ``0..n-1`` (a mapper that removed
        frames or was fed its own ids), so a plain map run's file keeps its historical bytes
    """
    if hasattr(arrays, "chunks"):
        out = dict(arrays.header)
        widths = {str(k): int(w) for k, w in zip(out["channel_names"], out["channel_widths"])}
        _streamed_channels(out, arrays, arrays.n, widths)
        out["keys"] = StreamedArray(np.int64, (arrays.n,), lambda: _streamed_keys(arrays))  # as differences
    else:
        out = {k: v for k, v in arrays.items() if not k.startswith("ch_")}
        n = len(arrays["keys"])
        _encode_channels(out, "", n, {k[3:]: v for k, v in arrays.items() if k.startswith("ch_")})
        out["keys"] = np.diff(np.asarray(arrays["keys"], np.int64), prepend=np.int64(0))  # as differences
    out["keys_are_diffs"] = np.int64(1)
    out["frames_done"] = np.int64(frames_done)
    out["poses"] = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    if frame_ids is not None:
        out["frame_ids"] = np.asarray(frame_ids, np.int64)
    write_npz(Path(folder) / MEMORY_NAME, out, threaded=True, fast=True)


def read_memory(folder: str | Path, sparse: bool = False) -> tuple[dict, int, np.ndarray, np.ndarray | None]:
    """Read ``folder/memory.npz``: (memory arrays, frames_done, poses (n, 4, 4) float64, frame_ids or None);
    ``sparse``: channels stored as rows come as :class:`SparseRows`."""
    path = Path(folder) / MEMORY_NAME
    if not path.is_file():
        raise PanovoccError("memory.npz not found (not a panovocc map folder, or the run stopped before "
                            "its first checkpoint)", path)
    try:
        with load_npz(path) as z:
            arrays = {k: z[k] for k in z.files if not k.startswith(("ch_", "rows_", "nz_", "nzshape_", "fac", "gcd_"))}
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


# ---------------------------------------------------------------------------------------------
# the sharded delta log (deltas/shard-NNNNNN.pvd, deltas/commits.pvj)
#
# A map's deltas are records appended to a few large shard files, not one file a frame. Record: a
# 32-byte header (magic b"PVD1", kind u8, 3 zero bytes, frame id i64, payload length u64, payload
# CRC-32 u32, 4 zero bytes), then the payload. Kinds: PUT (a frame's delta and pose: :func:`encode_delta`)
# and DROP (the frame is taken out; empty payload). A shard is closed when it passes SHARD_BYTES; a record
# never spans two shards. The commit journal ``commits.pvj`` lists checkpoints as 24-byte entries (magic
# b"PVC1", shard i64, end offset i64, CRC-32 of the first 20 bytes u32): what a map holds is
# the effect of the records up to the last valid entry; anything after it (a killed run's last frames, a
# torn record) is cut off when the log is opened. A finished save leaves the journal one entry long, so
# the folder's bytes do not depend on how often the run checkpointed (unless a checkpoint compacted the
# log). Compaction (:meth:`panovocc_cli.mapping.rpu.DeltaStore.commit`) appends a closed shard's live
# records again, commits, then deletes the shard: shard numbers may start above 0 and have gaps.

import os
import struct
import zlib

SHARD_BYTES = 256 * 2 ** 20
RECORD_MAGIC = b"PVD1"
COMMIT_MAGIC = b"PVC1"
JOURNAL_NAME = "commits.pvj"
PUT, DROP = 1, 2
_HEADER = struct.Struct("<4sB3xqQI4x")
RECORD_HEADER_BYTES = _HEADER.size
_ENTRY = struct.Struct("<4sqqI")  # magic, shard, end, CRC-32 of the 20 bytes before it


def shard_path(folder: str | Path, shard: int) -> Path:
    """``folder/deltas/shard-NNNNNN.pvd``."""
    return Path(folder) / DELTAS_DIR / f"shard-{int(shard):06d}.pvd"


def shard_ids(folder: str | Path) -> list[int]:
    """The shard numbers present in ``folder/deltas``, ascending."""
    out = []
    for p in (Path(folder) / DELTAS_DIR).glob("shard-*.pvd"):
        try:
            out.append(int(p.stem.split("-", 1)[1]))
        except ValueError:
            continue
    return sorted(out)


def _zstd():
    """The Zstandard module: the standard library's from Python 3.14, else its backport (a dependency)."""
    try:
        from compression import zstd
    except ImportError:
        from backports import zstd
    return zstd


def encode_arrays(arrays: Mapping[str, np.ndarray], level: int = RECORD_ZSTD_LEVEL) -> bytes:
    """Arrays (sorted by name) as one Zstandard frame: a JSON table (name, dtype, shape) and the raw bytes
    (little-endian). Deterministic: equal arrays give equal bytes (one Zstandard version, one level).

    Zstandard, not zlib (before 2026-12-04): on the 1,200-frame house's records level 3 takes 2.7 ms a
    record against zlib level 1's 7.1, reads back in 1.0 ms against 2.4, and is 10 % smaller
    (``scripts/record_codecs.py``; docs/mapping.md, "Delta store size"). :func:`decode_arrays` reads both."""
    names = sorted(arrays)
    arrs = []
    for n in names:
        a = np.asarray(arrays[n])
        if a.dtype.hasobject:
            raise TypeError(f"array {n!r} has object dtype")
        arrs.append(np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")))
    table = json.dumps([[n, a.dtype.str, list(a.shape)] for n, a in zip(names, arrs)],
                       separators=(",", ":")).encode()
    # fed to the compressor array by array, as views: no copy of the record's raw bytes (twice its size, on
    # the delta writer's thread beside the next frame's working set)
    zstd = _zstd()
    z = zstd.ZstdCompressor(level=level)
    out = [z.compress(struct.pack("<I", len(table)) + table)]
    out += [z.compress(a.reshape(-1).view(np.uint8)) for a in arrs]
    out.append(z.flush())
    return b"".join(out)


def payload_body(payload: bytes) -> bytes:
    """The uncompressed bytes of an :func:`encode_arrays` payload (a Zstandard frame, or the zlib stream of a
    record written before 2026-12-04)."""
    return _zstd().decompress(payload) if payload[:4] == ZSTD_MAGIC else zlib.decompress(payload)


def decode_arrays(payload: bytes) -> dict:
    """Inverse of :func:`encode_arrays`."""
    body = payload_body(payload)
    (n,) = struct.unpack_from("<I", body, 0)
    table = json.loads(body[4:4 + n])
    out, off = {}, 4 + n
    for name, dt, shape in table:
        dtype = np.dtype(dt)
        count = int(np.prod(shape, dtype=np.int64))
        out[name] = np.frombuffer(body, dtype, count=count, offset=off).reshape(shape)
        off += count * dtype.itemsize
    if off != len(body):
        raise ValueError("payload longer than its table")
    return out


_GAP_MAX = 32767  # key gaps stored in int16; larger ones (rare: a new row of voxels) as int64 apart
_GAP_JUMP = -32768  # the int16 marking a gap stored apart


def delta_arrays(parts, T_world_cam: np.ndarray, observation: Mapping[str, np.ndarray] | None = None) -> dict:
    """One frame's delta as named arrays (the layout :func:`write_delta` documents). ``parts``: (keys,
    channels) or (keys, channels, factors) per contributor (factors: :func:`_encode_channels`);
    ``observation``: arrays kept with the delta as ``obs_NAME`` (a frame's semantic observation)."""
    arrays = {"T_world_cam": np.asarray(T_world_cam, np.float64)}
    for i, part in enumerate(parts):
        keys, channels = part[0], part[1]
        pre = _part_prefix(i)
        keys = np.asarray(keys, np.int64)
        # the first key apart; gaps in int16, the few larger ones (a new row) apart
        arrays[f"{pre}keys_diff"], arrays[f"{pre}keys_jumps"] = key_gaps(np.ascontiguousarray(keys.reshape(-1)),
                                                                          _GAP_MAX, _GAP_JUMP)
        arrays[f"{pre}keys_first"] = keys[:1]
        _encode_channels(arrays, pre, len(keys), channels, part[2] if len(part) > 2 else None)
    for name, a in (observation or {}).items():
        arrays[f"obs_{name}"] = np.asarray(a)
    return arrays


class DeltaRecord(NamedTuple):
    """A decoded PUT record: parts (keys (n,) int64, channels dict name -> (n, width) int64) per
    contributor, the pose (4, 4) float64, and the observation arrays (None when the record has none)."""

    parts: list
    T_world_cam: np.ndarray
    observation: dict | None


def arrays_record(z: Mapping[str, np.ndarray]) -> DeltaRecord:
    """Inverse of :func:`delta_arrays`."""
    parts = []
    while f"{_part_prefix(len(parts))}keys_diff" in z:
        pre = _part_prefix(len(parts))
        if f"{pre}keys_jumps" in z and f"{pre}keys_first" in z:  # one compiled pass (a record since shards)
            ok, keys = keys_from_gaps(np.asarray(z[f"{pre}keys_first"], np.int64).reshape(-1),
                                      np.asarray(z[f"{pre}keys_diff"]).reshape(-1),
                                      np.asarray(z[f"{pre}keys_jumps"], np.int64).reshape(-1), _GAP_JUMP)
            if not ok:
                raise ValueError("key gaps and jumps disagree")
            parts.append((keys, _decode_channels(z, pre, len(keys))))
            continue
        gaps = np.asarray(z[f"{pre}keys_diff"]).astype(np.int64)
        if f"{pre}keys_jumps" in z:
            jump = gaps == _GAP_JUMP
            gaps[jump] = np.asarray(z[f"{pre}keys_jumps"], np.int64)
        if f"{pre}keys_first" in z:  # the first key, then the gaps
            gaps = np.concatenate([np.asarray(z[f"{pre}keys_first"], np.int64).reshape(-1), gaps])
        keys = np.cumsum(gaps)
        parts.append((keys, _decode_channels(z, pre, len(keys))))
    # The pose and the observation are copies: the arrays of a decoded payload are views of its whole body (about
    # 1.2 MB at 512x256), which a kept pose (a resumed run's replay, 128 bytes a frame) or a kept observation (a
    # RAM store) would otherwise hold alive, one body a frame.
    T = np.array(z["T_world_cam"], np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"delta pose has shape {T.shape}, expected (4, 4)")
    obs = {k[4:]: np.array(v) for k, v in z.items() if k.startswith("obs_")}
    return DeltaRecord(parts, T, obs or None)


def arrays_delta(z: Mapping[str, np.ndarray]) -> tuple[list, np.ndarray]:
    """Inverse of :func:`delta_arrays`: (parts, T_world_cam (4, 4))."""
    rec = arrays_record(z)
    return rec.parts, rec.T_world_cam


def encode_delta(parts, T_world_cam: np.ndarray, observation: Mapping[str, np.ndarray] | None = None) -> bytes:
    """A PUT record's payload (:func:`delta_arrays`)."""
    return encode_arrays(delta_arrays(parts, T_world_cam, observation))


def decode_record(payload: bytes, where=None) -> DeltaRecord:
    """A PUT record's payload -> :class:`DeltaRecord`."""
    try:
        return arrays_record(decode_arrays(payload))
    except Exception as e:  # noqa: BLE001 - any unreadable payload is the same failure
        raise PanovoccError(f"cannot read delta ({type(e).__name__}: {e})", where) from None


def decode_delta(payload: bytes, where=None) -> tuple[list, np.ndarray]:
    """A PUT record's payload -> (parts, T_world_cam)."""
    rec = decode_record(payload, where)
    return rec.parts, rec.T_world_cam


def _entry(shard: int, end: int) -> bytes:
    head = struct.pack("<4sqq", COMMIT_MAGIC, int(shard), int(end))
    return head + struct.pack("<I", zlib.crc32(head))


def _pos_key(pos) -> tuple[int, int]:
    return int(pos[0]), int(pos[1])


class DeltaLog:
    """The append-only shard files and the commit journal of one map folder (block comment above).

    Locations are ``(shard, offset, length)`` of a record's payload. Opening reads the journal's last
    valid entry (the committed end), cuts everything after it and lists in :attr:`records` the records
    between ``start`` (where a memory snapshot is; ``(0, 0)``: the log's beginning) and that end, as
    (kind, frame id, location). A ``start`` beyond the committed end is refused (:class:`PanovoccError`):
    the caller then rebuilds from the beginning.

    A journal entry the shards no longer reach (a shard file truncated below it) is refused
    (:class:`PanovoccError`), unless ``roll_back``: then the log is rolled back to the last entry they reach,
    as a killed run's uncommitted tail is (``map --resume`` maps the frames after it again). The journal's
    entries after the committed end (a torn entry, or those rolled back) are cut too.
    """

    def __init__(self, folder: str | Path, start: tuple[int, int] = (0, 0), roll_back: bool = False):
        self.folder = Path(folder)
        (self.folder / DELTAS_DIR).mkdir(parents=True, exist_ok=True)
        self.journal = self.folder / DELTAS_DIR / JOURNAL_NAME
        self.records: list[tuple[int, int, tuple[int, int, int]]] = []
        self._f = None
        self.committed = self._committed_end(roll_back)
        self._cut(*self.committed)
        if _pos_key(start) > self.committed:
            raise PanovoccError(f"the memory snapshot is at {list(start)} in the delta log, past its last commit "
                                f"{list(self.committed)}", self.folder / DELTAS_DIR)
        self.shard, self.end = self.committed
        self.records = self._scan(_pos_key(start), self.committed)

    # -- reading ---------------------------------------------------------------------------------
    def _committed_end(self, roll_back: bool = False) -> tuple[int, int]:
        """The last valid journal entry whose position the shards reach ((0, 0) without any); the journal
        is cut after it. An entry they do not reach is refused unless ``roll_back``."""
        if not self.journal.is_file():
            return 0, 0
        data = self.journal.read_bytes()
        best, valid = (0, 0), 0
        for i in range(0, len(data) - _ENTRY.size + 1, _ENTRY.size):
            e = data[i:i + _ENTRY.size]
            magic, shard, end, crc = _ENTRY.unpack(e)
            if magic != COMMIT_MAGIC or crc != zlib.crc32(e[:20]):
                break
            p = shard_path(self.folder, shard)
            if end > 0 and (not p.is_file() or p.stat().st_size < end):
                if roll_back:
                    break
                raise PanovoccError(f"the delta log ends before its commit at shard {shard} byte {end} (the map "
                                    "folder was truncated or changed)", p)
            best, valid = (int(shard), int(end)), valid + 1
        if len(data) > valid * _ENTRY.size:  # later entries would be read again once new records reach them
            with open(self.journal, "r+b") as f:
                f.truncate(valid * _ENTRY.size)
        return best

    def _scan(self, start: tuple[int, int], stop: tuple[int, int], payloads: bool = True) -> list:
        """Records from ``start`` to ``stop`` (each checked: a damaged one is refused; ``payloads=False``: their
        headers only, the payloads' CRCs checked when they are read)."""
        out = []
        for s in [s for s in shard_ids(self.folder) if start[0] <= s <= stop[0]]:
            path = shard_path(self.folder, s)
            pos = start[1] if s == start[0] else 0
            limit = stop[1] if s == stop[0] else path.stat().st_size
            with open(path, "rb") as f:
                while pos < limit:
                    f.seek(pos)
                    head = f.read(_HEADER.size)
                    ok = len(head) == _HEADER.size
                    if ok:
                        magic, kind, fid, length, crc = _HEADER.unpack(head)
                        ok = magic == RECORD_MAGIC and kind in (PUT, DROP) and pos + _HEADER.size + length <= limit
                    if ok and payloads:
                        payload = f.read(length)
                        ok = zlib.crc32(payload) == crc
                    if not ok:
                        raise PanovoccError(f"delta record at byte {pos} is damaged (the map folder was changed)", path)
                    out.append((kind, fid, (s, pos + _HEADER.size, length)))
                    pos += _HEADER.size + length
        return out

    def _cut(self, shard: int, offset: int) -> None:
        """Drop everything after (shard, offset): the uncommitted tail of a killed or failed run."""
        for s in shard_ids(self.folder):
            p = shard_path(self.folder, s)
            if s > shard or (s == shard and offset == 0 and s > 0):
                p.unlink()
            elif s == shard and p.stat().st_size > offset:
                with open(p, "r+b") as f:
                    f.truncate(offset)

    def read(self, loc: tuple[int, int, int]) -> bytes:
        """A record's payload, its CRC checked."""
        s, off, length = (int(v) for v in loc)
        path = shard_path(self.folder, s)
        try:
            with open(path, "rb") as f:
                f.seek(off - _HEADER.size)
                head = f.read(_HEADER.size)
                payload = f.read(length)
        except OSError as e:
            raise PanovoccError(f"cannot read delta ({e.strerror or e})", path) from None
        if len(head) < _HEADER.size or len(payload) < length or _HEADER.unpack(head)[0] != RECORD_MAGIC \
                or zlib.crc32(payload) != _HEADER.unpack(head)[4]:
            raise PanovoccError(f"delta record at byte {off} is damaged (the map folder was changed)", path)
        return payload

    def shard_sizes(self) -> dict[int, int]:
        """Bytes of each shard file the log holds, by shard number (the current shard's: its end)."""
        out = {s: shard_path(self.folder, s).stat().st_size for s in shard_ids(self.folder)}
        if self.shard in out or self.end:
            out[self.shard] = self.end
        return out

    def headers(self, shard: int) -> list[tuple[int, int, tuple[int, int, int]]]:
        """A shard's records up to the log's end as (kind, frame id, location), from their headers alone."""
        limit = self.end if shard == self.shard else shard_path(self.folder, shard).stat().st_size
        return self._scan((shard, 0), (shard, limit), payloads=False)

    def roll(self) -> None:
        """Close the current shard: the next record starts a new one (a compaction that rewrites every shard)."""
        if self.end:
            if self._f is not None:
                os.fsync(self._f.fileno())
            self.close()
            self.shard, self.end = self.shard + 1, 0

    def cut_to(self, pos: tuple[int, int]) -> None:
        """Cut what was appended after ``pos`` (a position reached since the last commit: a failed
        compaction's copies)."""
        self.close()
        self._cut(*pos)
        self.shard, self.end = _pos_key(pos)

    def remove_shards(self, shards) -> None:
        """Delete shard files whose every live record was rewritten at the log's end (and committed)."""
        for s in shards:
            if s >= self.shard:
                raise ValueError(f"shard {s} is not closed")
            shard_path(self.folder, s).unlink(missing_ok=True)

    def append(self, kind: int, frame_id: int, payload: bytes) -> tuple[int, int, int]:
        """Append one record; its location. A failed write is cut off again and re-raised."""
        if self._f is None or self.end >= SHARD_BYTES:
            self._open_next()
        start = self.end
        try:
            self._f.seek(start)
            self._f.write(_HEADER.pack(RECORD_MAGIC, kind, int(frame_id), len(payload), zlib.crc32(payload)))
            self._f.write(payload)
            self._f.flush()
        except OSError:
            try:
                self._f.truncate(start)
            except OSError:
                pass
            raise
        self.end = start + _HEADER.size + len(payload)
        return self.shard, start + _HEADER.size, len(payload)

    def _open_next(self) -> None:
        if self._f is not None and self.end >= SHARD_BYTES:
            os.fsync(self._f.fileno())  # the next commit fsyncs only the shard it ends in
            self._f.close()
            self._f, self.shard, self.end = None, self.shard + 1, 0
        if self._f is None:
            path = shard_path(self.folder, self.shard)
            self._f = open(path, "r+b" if path.exists() else "w+b")

    def commit(self, compact: bool = False) -> tuple[int, int]:
        """Make everything appended so far committed: the shard fsync'd, then a journal entry (fsync'd);
        ``compact``: the journal is replaced by its one last entry (atomically). Returns the position."""
        if self._f is not None:
            os.fsync(self._f.fileno())
        entry = _entry(self.shard, self.end)
        if compact:
            from .atomic import atomic_path

            with atomic_path(self.journal) as tmp:
                tmp.write_bytes(entry)
        else:
            with open(self.journal, "ab") as f:
                f.write(entry)
                f.flush()
                os.fsync(f.fileno())
        self.committed = (self.shard, self.end)
        return self.committed

    def rollback(self) -> None:
        """Cut what was appended since the last commit (a command that failed changes nothing)."""
        self.cut_to(self.committed)

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None
