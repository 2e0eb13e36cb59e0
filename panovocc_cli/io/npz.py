"""Deterministic ``.npz`` writing: ``np.savez`` stamps the wall-clock time into each zip entry, so the
same arrays give different bytes. Here every entry has a fixed date, so equal inputs give equal files.
Files stay readable by ``np.load(path, allow_pickle=False)``."""

from __future__ import annotations

import threading
import zipfile
from collections import deque
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Mapping, NamedTuple

import numpy as np

from ..errors import PanovoccError
from .atomic import atomic_path

_FIXED_DATE = (1980, 1, 1, 0, 0, 0)
FAST_LEVEL = 1  # ISA-L igzip level of a ``fast`` archive's entries (write_npz; levels 0-3)
FAST_FEED = 1 << 20  # bytes handed to the igzip compressor a call (its output depends on how its input is split)


class _FixedFeed:
    """A compressor object (``compress``, ``flush``) that hands ``inner`` its input in calls of exactly
    :data:`FAST_FEED` bytes (the last call the rest), whatever pieces it is given. ISA-L's output depends on
    how its input is split into calls, zlib's does not: fed this way, an entry's bytes depend on its content
    only, as a streamed ``memory.npz`` (pieces cut where the memory's allocated blocks fall) needs."""

    def __init__(self, inner):
        self._inner, self._buf = inner, bytearray()

    def compress(self, data) -> bytes:
        mv = memoryview(data).cast("B")
        out = []
        if self._buf:  # complete the held call first
            need = FAST_FEED - len(self._buf)
            self._buf += mv[:need]
            mv = mv[need:]
            if len(self._buf) < FAST_FEED:
                return b""
            out.append(self._inner.compress(self._buf))
            self._buf = bytearray()
        n = len(mv) // FAST_FEED * FAST_FEED
        out.extend(self._inner.compress(mv[a:a + FAST_FEED]) for a in range(0, n, FAST_FEED))
        if n < len(mv):
            self._buf += mv[n:]
        return b"".join(out)

    def flush(self) -> bytes:
        out = (self._inner.compress(bytes(self._buf)) if self._buf else b"") + self._inner.flush()
        self._buf = bytearray()
        return out


def _open_entry(zf: zipfile.ZipFile, info: zipfile.ZipInfo, fast: bool):
    """``zf.open(info, "w")``; with ``fast``, the entry's deflate stream made by ISA-L's igzip (``isal``) at
    :data:`FAST_LEVEL` instead of zlib, fed in fixed-size calls (:class:`_FixedFeed`): still a raw deflate
    stream (ZIP_DEFLATED), read by any zip reader and ``np.load``. On the 448 MB of a building map's
    ``memory.npz`` entries: 0.47 s of CPU for 119.5 MB against zlib level 1's 2.99 s for 121.4 MB
    (docs/mapping.md, "Building revise, eighth pass"). The bytes are those of the pinned ``isal`` version, as zlib's are those of
    the zlib build. Python's zip writer keeps an entry's compressor in ``_compressor`` (3.8-3.14); where it
    does not, the entry is deflated by zlib."""
    f = zf.open(info, "w", force_zip64=True)
    if fast and getattr(f, "_compressor", None) is not None:
        from isal import isal_zlib

        f._compressor = _FixedFeed(isal_zlib.compressobj(FAST_LEVEL, isal_zlib.DEFLATED, -15))
    return f


ZIP_STARTS = (b"PK\x03\x04", b"PK\x05\x06")  # a zip's first entry, or an empty archive's end record


def check_npz(path: str | Path, expected: str) -> None:
    """Refuse in one line a file that is not a zip archive before ``np.load`` reads it: numpy takes any other
    file for a pickle and says that it "contains pickled (object) data" (a text file, an ``.npy`` array).
    ``expected`` says what the file should be."""
    with open(path, "rb") as f:
        start = f.read(4)
    if start not in ZIP_STARTS:
        kind = "an .npy array" if start.startswith(b"\x93NUM") else "empty" if not start else "not a zip archive"
        raise PanovoccError(f"not an .npz file ({kind}); expected {expected}", path)


@contextmanager
def load_npz(path: str | Path):
    """``np.load(path, allow_pickle=False)`` whose deflated entries are inflated by ISA-L (``isal``): any raw
    deflate stream, zlib's as well as :func:`write_npz`'s ``fast`` ones, to the same bytes, in about half
    zlib's CPU (0.70 s against 1.26 s, CRC checks included, for a building map's ``memory.npz``). Where Python's
    zip reader keeps no ``_decompressor`` on an entry, zlib inflates it."""
    from isal import isal_zlib

    with np.load(path, allow_pickle=False) as z:
        zip_open = z.zip.open

        def open_entry(name, *args, **kwargs):
            f = zip_open(name, *args, **kwargs)
            if (getattr(f, "_compress_type", None) == zipfile.ZIP_DEFLATED
                    and getattr(f, "_decompressor", None) is not None):
                f._decompressor = isal_zlib.decompressobj(-15)
            return f

        z.zip.open = open_entry
        yield z


class StreamedArray(NamedTuple):
    """An entry written piece by piece: its ``dtype`` and ``shape``, and ``pieces()``, an iterator of numpy
    arrays whose C-order bytes, one after the other, are the array's (any split). Written to the same bytes
    as the whole array (zlib's output does not depend on how its input is split), without holding it."""

    dtype: np.dtype
    shape: tuple
    pieces: Callable[[], Iterable[np.ndarray]]


PIPE_BYTES = 1 << 24  # bytes a threaded write_npz holds queued for its writer thread at most (16 MiB)


class _EntryPipe:
    """The zip entries of one archive opened, filled and closed on a second thread, in the order given:
    the caller produces an entry's bytes (numpy work that holds the GIL) while this thread computes the
    CRC, compresses and writes the ones before (zlib and file writes release the GIL). At most
    ``limit`` bytes wait in the queue (one piece more if a single piece is larger). The archive is the
    same, byte for byte, as entries written in the caller's thread: the same calls, in the same order.
    A failure on the writer thread is raised by the next call (or :meth:`finish`)."""

    def __init__(self, zf: zipfile.ZipFile, limit: int = PIPE_BYTES, fast: bool = False):
        self._zf, self._limit, self._fast = zf, int(limit), bool(fast)
        self._jobs: deque = deque()
        self._queued = 0
        self._done = False
        self._error: BaseException | None = None
        self._cv = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="write_npz", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        f = None
        while True:
            with self._cv:
                while not self._jobs and not self._done:
                    self._cv.wait()
                if not self._jobs:
                    break
                kind, data, size = self._jobs[0]
            try:
                if self._error is None:
                    if kind == "open":
                        f = _open_entry(self._zf, data, self._fast)
                    elif kind == "write":
                        f.write(data)
                    else:
                        f, g = None, f
                        g.close()
            except BaseException as e:  # noqa: BLE001 - re-raised in the caller's thread
                self._error = e
            with self._cv:
                self._jobs.popleft()
                self._queued -= size
                self._cv.notify_all()
        if f is not None:  # an abandoned archive: its open entry is closed so that the archive can be
            try:  # closed too (and the caller's error raised, not zipfile's)
                f.close()
            except BaseException:  # noqa: BLE001 - the archive is being abandoned
                pass

    def _put(self, kind: str, data=None, size: int = 0) -> None:
        with self._cv:
            while self._queued > 0 and self._queued + size > self._limit and self._error is None:
                self._cv.wait()
            self._raise()
            self._jobs.append((kind, data, size))
            self._queued += size
            self._cv.notify_all()

    def _raise(self) -> None:
        if self._error is not None:
            raise self._error

    def open(self, info: zipfile.ZipInfo) -> None:
        self._put("open", info)

    def write(self, data) -> None:
        """Queue ``data`` (bytes, or a buffer that nothing changes afterwards) for the open entry."""
        self._put("write", data, memoryview(data).nbytes)

    def close_entry(self) -> None:
        self._put("close")

    def finish(self, ok: bool = True) -> None:
        """Wait for the queued jobs (``ok=False``: drop them, the archive is being abandoned), stop the
        thread and raise its failure if any."""
        with self._cv:
            if not ok:
                self._jobs = deque(self._jobs and [self._jobs[0]])  # the job in progress finishes
            self._done = True
            self._cv.notify_all()
        self._thread.join()
        if ok:
            self._raise()


def _array_buffers(f_write, arr: np.ndarray) -> None:
    """``np.lib.format.write_array(f, arr)``'s bytes for a C-contiguous array, given to ``f_write`` as
    slices of the array's own memory (no copy): its 1.0 header, then the data in pieces of
    :data:`_PIECE` bytes."""
    f_write(_header(np.lib.format.header_data_from_array_1_0(arr)))
    data = arr.reshape(-1).view(np.uint8)
    for a in range(0, len(data), _PIECE):
        f_write(data[a:a + _PIECE])


_PIECE = 1 << 22  # bytes of an array's data given to the writer thread at a time


def _header(d: dict) -> bytes:
    """The ``.npy`` 1.0 header of ``d`` (descr, fortran_order, shape): what ``np.lib.format.write_array``
    writes first."""
    from io import BytesIO

    head = BytesIO()
    np.lib.format.write_array_header_1_0(head, d)
    return head.getvalue()


def _write_streamed(write, name: str, arr: StreamedArray) -> None:
    dtype = np.dtype(arr.dtype)
    write(_header({"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                   "shape": tuple(int(x) for x in arr.shape)}))
    want, got = int(np.prod(arr.shape, dtype=np.int64)) * dtype.itemsize, 0
    for piece in arr.pieces():
        piece = np.ascontiguousarray(piece)
        if piece.dtype != dtype:
            raise TypeError(f"write_npz: entry {name!r} got a {piece.dtype} piece, expected {dtype}")
        if piece.nbytes:
            write(memoryview(piece.reshape(-1)).cast("B"))
        got += piece.nbytes
    if got != want:
        raise ValueError(f"write_npz: entry {name!r} got {got} bytes, expected {want}")


def write_npz(path: str | Path, arrays: Mapping[str, np.ndarray], compress: bool = True,
              compresslevel: int | None = None, threaded: bool = False, fast: bool = False) -> None:
    """Atomically write ``arrays`` to ``path`` as a ``.npz`` with byte-for-byte reproducible content.

    Object arrays are refused (nothing in the toolkit's files needs pickle). ``compresslevel`` (1-9, default
    zlib's 6) trades size for speed. A :class:`StreamedArray` value is written piece by piece (its pieces
    must not be changed once yielded). ``threaded``: the entries are compressed and written on a second
    thread while the next ones' data are produced (:class:`_EntryPipe`; at most :data:`PIPE_BYTES` queued),
    to the same bytes. ``fast``: the entries deflated by ISA-L's igzip (:func:`_open_entry`; ``compresslevel``
    then unused): several times less CPU than zlib for about the same size, on large archives (``memory.npz``).
    """
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path, suffix=".npz") as tmp:
        with zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True, compresslevel=compresslevel) as zf:
            pipe = _EntryPipe(zf, fast=fast) if threaded else None
            try:
                for name in sorted(arrays):
                    arr = arrays[name] if isinstance(arrays[name], StreamedArray) else np.asanyarray(arrays[name])
                    if np.dtype(arr.dtype).hasobject:
                        raise TypeError(f"write_npz: array {name!r} has object dtype")
                    info = zipfile.ZipInfo(f"{name}.npy", date_time=_FIXED_DATE)
                    info.compress_type = method
                    # ZipFile.open(ZipInfo) ignores the archive's compresslevel: the entry carries its own
                    # (``_compresslevel`` up to Python 3.12, ``compress_level`` from 3.13)
                    setattr(info, "compress_level" if hasattr(info, "compress_level") else "_compresslevel",
                            compresslevel)
                    info.external_attr = 0o644 << 16
                    if pipe is None:
                        with _open_entry(zf, info, fast) as f:
                            if isinstance(arr, StreamedArray):
                                _write_streamed(f.write, name, arr)
                            else:
                                np.lib.format.write_array(f, arr, allow_pickle=False)
                        continue
                    pipe.open(info)
                    if isinstance(arr, StreamedArray):
                        _write_streamed(pipe.write, name, arr)
                    elif type(arr) is np.ndarray and arr.flags.c_contiguous:
                        _array_buffers(pipe.write, arr)  # the array's own memory: no copy
                    else:  # write_array's own pieces (copies) of an array in another layout
                        np.lib.format.write_array(_Forward(pipe.write), arr, allow_pickle=False)
                    pipe.close_entry()
            except BaseException:
                if pipe is not None:
                    pipe.finish(ok=False)
                raise
            if pipe is not None:
                pipe.finish()


class _Forward:
    """A write-only file object that hands what it is given to ``write``."""

    def __init__(self, write):
        self.write = write
