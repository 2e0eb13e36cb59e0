"""``panovocc map`` with its frame pipeline's overlaps changed, to measure what each costs in peak RSS and buys
in time (docs/mapping.md, "The house's peak, seventh pass"). Not kept in the toolkit: the variants patch
it for this process only, and the map they make is the same bytes as the default's.

    PK_MODE=MODES python scripts/map_overlap_variants.py map SEQ OUT [map options...]

MODES, joined by any separator (e.g. ``gate+mallinfo``):

* ``base``: the default (nothing patched);
* ``noreader``: no prefetching thread (frame i + 1 is read and segmented after frame i is integrated);
* ``syncwriter``: every delta record encoded, compressed and appended before the next frame (no writer overlap);
* ``gate``: one lock that the reading thread holds while it segments a frame and makes its observation, and the
  mapping thread while it computes a frame's delta (the two largest working sets never overlap; the PNG
  decoding still does);
* ``gatewriter`` (with ``gate``): the writer thread holds the same lock while it encodes a record's arrays;
* ``zreuse``: one Zstandard compressor a thread, reused for every record (the same record bytes);
* ``readonly``: the prefetching thread only reads and decodes the frame's images; the segmenter and the
  observation run on the mapping thread, before the frame's delta (docs/mapping.md, "The house's peak, ninth
  pass");
* ``syncencode``: a record is encoded and compressed on the mapping thread, and the writer thread only appends
  its bytes (the previous frame's record, not its delta, is what waits beside the next frame);
* ``mallinfo``: after frames 0, 1, 2, 10, 100, 600 and 1,199, print glibc's main heap (``mallinfo2``: its
  size, the bytes in use and free) and the resident memory, MiB;
* ``trim`` / ``trimN``: glibc's ``malloc_trim(0)`` after every frame / every N-th frame on the mapping thread
  (the heap's free pages handed back, as ``runtime.release_freed_heap`` does once before the export).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import struct
import sys
import threading

import numpy as np

import panovocc_cli.io.mapstore as ms
import panovocc_cli.mapping.mapper as mp
import panovocc_cli.mapping.pipeline as pl
import panovocc_cli.mapping.rpu as rpu

MODE = os.environ.get("PK_MODE", "base")
GATE = threading.Lock()


def _noreader():
    pl.concurrent_kernels_safe = lambda: False


def _syncwriter():
    put = rpu.DeltaStore.put

    def synced(self, *a, **k):
        put(self, *a, **k)
        self.flush()

    rpu.DeltaStore.put = synced


def _segmented(frames, mapper, frame, i):
    """Frame ``i`` as read, segmented and observed as ``pipeline.observed`` gives it: (frame without its logits,
    its observation)."""
    if frames.segmenter is None:
        return frame, None
    s = frames.stride
    rgb = frame.rgb[::s, ::s] if s > 1 else frame.rgb
    frame.logits = frames.segmenter.logits(rgb, frames.vocab, frame_id=i)
    observation = mapper.observe(frame)
    return dataclasses.replace(frame, logits=None, features=None), observation


def _gate(writer: bool):
    def observed(frames, mapper):
        def read(i):
            frame = frames.seq.frame(i)
            with GATE:
                return _segmented(frames, mapper, frame, i)

        return read

    pl.observed = observed
    delta = mp.Mapper._delta

    def gated(self, *a, **k):
        with GATE:
            return delta(self, *a, **k)

    mp.Mapper._delta = gated
    if writer:
        def append_put(self, fid, held, T):
            with GATE:
                payload = rpu.encode_record(held[0], T)
                held[0] = payload
            self._locs[fid] = self._log.append(ms.PUT, fid, payload)

        rpu.DeltaStore._append_put = append_put


def _readonly():
    prefetched = pl.prefetched

    class Source:  # what pl.observed gives the loop here: the frame source and the mapper, unread
        def __init__(self, frames, mapper):
            self.frames, self.mapper = frames, mapper

    def segmented(source, ids):
        frames = source.frames
        for i, frame in prefetched(lambda i: frames.seq.frame(i), ids):
            yield i, _segmented(frames, source.mapper, frame, i)

    pl.observed = Source
    pl.prefetched = segmented


def _syncencode():
    submit, append = rpu.DeltaStore._submit, rpu.DeltaStore._append_put

    def encoded_first(self, fn, *args):
        if getattr(fn, "__func__", None) is appended:  # the record made here; the writer appends its bytes
            fid, held, T = args
            held[0] = rpu.encode_record(held[0], T)
        return submit(self, fn, *args)

    def appended(self, fid, held, T):
        if isinstance(held[0], bytes):
            self._locs[fid] = self._log.append(ms.PUT, fid, held[0])
        else:
            append(self, fid, held, T)

    rpu.DeltaStore._submit, rpu.DeltaStore._append_put = encoded_first, appended


def _zreuse():
    local = threading.local()

    def encode_arrays(arrays, level=ms.RECORD_ZSTD_LEVEL):
        names = sorted(arrays)
        arrs = [np.ascontiguousarray(np.asarray(arrays[n]), dtype=np.asarray(arrays[n]).dtype.newbyteorder("<"))
                for n in names]
        table = json.dumps([[n, a.dtype.str, list(a.shape)] for n, a in zip(names, arrs)],
                           separators=(",", ":")).encode()
        z = getattr(local, "z", None)
        if z is None:
            z = local.z = ms._zstd().ZstdCompressor(level=level)
        out = [z.compress(struct.pack("<I", len(table)) + table)]
        out += [z.compress(a.reshape(-1).view(np.uint8)) for a in arrs]
        out.append(z.flush())
        return b"".join(out)

    ms.encode_arrays = encode_arrays


def _mallinfo():
    import ctypes

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in
                    "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()]

    libc = ctypes.CDLL("libc.so.6")
    libc.mallinfo2.restype = MallInfo2
    integrate = mp.Mapper.integrate

    def sampled(self, frame, *a, **k):
        r = integrate(self, frame, *a, **k)
        if frame.index in (0, 1, 2, 10, 100, 600, 1199):
            mi = libc.mallinfo2()
            print(f"frame {frame.index}: heap {mi.arena / 2 ** 20:.1f} MiB, in use {mi.uordblks / 2 ** 20:.1f}, "
                  f"free {mi.fordblks / 2 ** 20:.1f}; resident {pl.resident_mb():.1f}", flush=True)
        return r

    mp.Mapper.integrate = sampled


def _trim(every: int):
    import ctypes

    libc = ctypes.CDLL("libc.so.6")
    integrate = mp.Mapper.integrate

    def trimmed(self, frame, *a, **k):
        r = integrate(self, frame, *a, **k)
        if frame.index % every == 0:
            libc.malloc_trim(0)
        return r

    mp.Mapper.integrate = trimmed


def apply() -> None:
    """Patch the toolkit for the modes of ``PK_MODE`` (``scripts/map_rss_phases.py`` calls it too)."""
    if "noreader" in MODE:
        _noreader()
    if "syncwriter" in MODE:
        _syncwriter()
    if "gate" in MODE:
        _gate("gatewriter" in MODE)
    if "readonly" in MODE:
        _readonly()
    if "syncencode" in MODE:
        _syncencode()
    if "zreuse" in MODE:
        _zreuse()
    if "mallinfo" in MODE:
        _mallinfo()
    m = re.search(r"trim(\d*)", MODE)
    if m:
        _trim(int(m.group(1) or 1))


def main() -> None:
    apply()
    from panovocc_cli.cli import main as cli

    sys.argv[0] = "panovocc"
    cli()


if __name__ == "__main__":
    main()
