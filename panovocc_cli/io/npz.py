"""Deterministic ``.npz`` writing: ``np.savez`` stamps the wall-clock time into each zip entry, so the
same arrays give different bytes. Here every entry has a fixed date, so equal inputs give equal files.
Files stay readable by ``np.load(path, allow_pickle=False)``."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Mapping

import numpy as np

from .atomic import atomic_path

_FIXED_DATE = (1980, 1, 1, 0, 0, 0)


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray], compress: bool = True,
              compresslevel: int | None = None) -> None:
    """Atomically write ``arrays`` to ``path`` as a ``.npz`` with byte-for-byte reproducible content.

    Object arrays are refused (nothing in the toolkit's files needs pickle). ``compresslevel`` (1-9, default
    zlib's 6) trades size for speed.
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path, suffix=".npz") as tmp:
        with zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True, compresslevel=compresslevel) as zf:
            for name in sorted(arrays):
                arr = np.asanyarray(arrays[name])
                if arr.dtype.hasobject:
                    raise TypeError(f"write_npz: array {name!r} has object dtype")
                info = zipfile.ZipInfo(f"{name}.npy", date_time=_FIXED_DATE)
                info.compress_type = method
                # ZipFile.open(ZipInfo) ignores the archive's compresslevel: the entry carries its own
                # (``_compresslevel`` up to Python 3.12, ``compress_level`` from 3.13)
                setattr(info, "compress_level" if hasattr(info, "compress_level") else "_compresslevel", compresslevel)
                info.external_attr = 0o644 << 16
                with zf.open(info, "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, arr, allow_pickle=False)
