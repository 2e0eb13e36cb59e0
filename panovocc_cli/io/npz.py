"""Deterministic ``.npz`` writing: ``np.savez`` stamps the wall-clock time into each zip entry, so the
same arrays give different bytes. Here every entry has a fixed date, so equal inputs give equal files.
Files stay readable by ``np.load(path, allow_pickle=False)``."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Callable, Iterable, Mapping, NamedTuple

import numpy as np

from .atomic import atomic_path

_FIXED_DATE = (1980, 1, 1, 0, 0, 0)


class StreamedArray(NamedTuple):
    """An entry written piece by piece: its ``dtype`` and ``shape``, and ``pieces()``, an iterator of numpy
    arrays whose C-order bytes, one after the other, are the array's (any split). Written to the same bytes
    as the whole array (zlib's output does not depend on how its input is split), without holding it."""

    dtype: np.dtype
    shape: tuple
    pieces: Callable[[], Iterable[np.ndarray]]


def _write_streamed(f, name: str, arr: StreamedArray) -> None:
    dtype = np.dtype(arr.dtype)
    np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                             "shape": tuple(int(x) for x in arr.shape)})  # write_array's header
    want, got = int(np.prod(arr.shape, dtype=np.int64)) * dtype.itemsize, 0
    for piece in arr.pieces():
        piece = np.ascontiguousarray(piece)
        if piece.dtype != dtype:
            raise TypeError(f"write_npz: entry {name!r} got a {piece.dtype} piece, expected {dtype}")
        if piece.nbytes:
            f.write(memoryview(piece.reshape(-1)).cast("B"))
        got += piece.nbytes
    if got != want:
        raise ValueError(f"write_npz: entry {name!r} got {got} bytes, expected {want}")


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray], compress: bool = True,
              compresslevel: int | None = None) -> None:
    """Atomically write ``arrays`` to ``path`` as a ``.npz`` with byte-for-byte reproducible content.

    Object arrays are refused (nothing in the toolkit's files needs pickle). ``compresslevel`` (1-9, default
    zlib's 6) trades size for speed. A :class:`StreamedArray` value is written piece by piece.
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path, suffix=".npz") as tmp:
        with zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True, compresslevel=compresslevel) as zf:
            for name in sorted(arrays):
                arr = arrays[name] if isinstance(arrays[name], StreamedArray) else np.asanyarray(arrays[name])
                if np.dtype(arr.dtype).hasobject:
                    raise TypeError(f"write_npz: array {name!r} has object dtype")
                info = zipfile.ZipInfo(f"{name}.npy", date_time=_FIXED_DATE)
                info.compress_type = method
                # ZipFile.open(ZipInfo) ignores the archive's compresslevel: the entry carries its own
                # (``_compresslevel`` up to Python 3.12, ``compress_level`` from 3.13)
                setattr(info, "compress_level" if hasattr(info, "compress_level") else "_compresslevel", compresslevel)
                info.external_attr = 0o644 << 16
                with zf.open(info, "w", force_zip64=True) as f:
                    if isinstance(arr, StreamedArray):
                        _write_streamed(f, name, arr)
                    else:
                        np.lib.format.write_array(f, arr, allow_pickle=False)
