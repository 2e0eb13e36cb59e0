"""Deflate codecs over a ``memory.npz``'s entries (docs/mapping.md, "Building revise, eighth pass").

Reads every entry of NPZ (raw ``.npy`` bytes), then compresses each as one raw deflate stream with zlib
level 1 (what ``memory.npz`` used before), ISA-L igzip levels 0-2, igzip level 1 fed in the fixed 1 MiB
calls ``write_npz(fast=True)`` uses (``io.npz._FixedFeed``), and zlib-ng levels 1-2 when the ``zlib_ng``
package is installed (it is not a dependency); then inflates the zip's entries with zlib and with ISA-L
(``io.npz.load_npz``'s way). One line a codec: process CPU seconds and compressed MB.

    python scripts/npz_codecs.py MAP/memory.npz
"""

from __future__ import annotations

import sys
import time
import zipfile
import zlib

from isal import isal_zlib

from panovocc_cli.io.npz import FAST_LEVEL, _FixedFeed


def main(path: str) -> None:
    with zipfile.ZipFile(path) as zf:
        raw = [zf.read(n) for n in zf.namelist()]
    print(f"{path}: {len(raw)} entries, {sum(map(len, raw)) / 1e6:.1f} MB raw")
    codecs = {"zlib 1": lambda: zlib.compressobj(1, zlib.DEFLATED, -15)}
    codecs.update({f"isal {lv}": (lambda lv=lv: isal_zlib.compressobj(lv, isal_zlib.DEFLATED, -15)) for lv in (0, 1, 2)})
    codecs[f"isal {FAST_LEVEL}, 1 MiB calls"] = lambda: _FixedFeed(isal_zlib.compressobj(FAST_LEVEL, isal_zlib.DEFLATED, -15))
    try:
        from zlib_ng import zlib_ng

        codecs.update({f"zlib-ng {lv}": (lambda lv=lv: zlib_ng.compressobj(lv, zlib_ng.DEFLATED, -15)) for lv in (1, 2)})
    except ImportError:
        pass
    for name, make in codecs.items():
        t, size = time.process_time(), 0
        for r in raw:
            c = make()
            size += len(c.compress(r)) + len(c.flush())
        print(f"{name:24s} {time.process_time() - t:6.2f} s CPU  {size / 1e6:8.1f} MB")
    with zipfile.ZipFile(path) as zf:
        for name, swap in (("inflate zlib", False), ("inflate isal", True)):
            t = time.process_time()
            for n in zf.namelist():
                with zf.open(n) as f:
                    if swap:
                        f._decompressor = isal_zlib.decompressobj(-15)
                    f.read()
            print(f"{name:24s} {time.process_time() - t:6.2f} s CPU (CRCs checked)")


if __name__ == "__main__":
    main(sys.argv[1])
