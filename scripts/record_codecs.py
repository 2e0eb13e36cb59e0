"""What the delta log's record compression costs (docs/mapping.md, "Delta store size"): decodes every
``--every``-th record of MAP's delta log to the bytes ``encode_arrays`` compresses (``payload_body``), and
prints, per codec (zlib 1, Zstandard 1 / 2 / 3, lz4), the mean compressed MB a record and the mean ms to
compress and to decompress one (one thread).

    python scripts/record_codecs.py MAP [--every 25]
"""

from __future__ import annotations

import argparse
import time
import zlib
from pathlib import Path

from panovocc_cli.io import mapstore


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("--every", type=int, default=25)
    a = ap.parse_args()
    log = mapstore.DeltaLog(a.map)
    raws = []
    for kind, _fid, loc in log.records[::a.every]:
        if kind != mapstore.PUT:
            continue
        raws.append(mapstore.payload_body(log.read(loc)))
    log.close()
    zstd = mapstore._zstd()
    codecs = {"zlib 1": (lambda r: zlib.compress(r, 1), zlib.decompress)}
    for level in (1, 2, 3):
        codecs[f"zstd {level}"] = (lambda r, lv=level: zstd.compress(r, level=lv), zstd.decompress)
    try:
        import lz4.frame

        codecs["lz4"] = (lz4.frame.compress, lz4.frame.decompress)
    except ImportError:
        pass
    n = len(raws)
    print(f"{n} records, {sum(map(len, raws)) / n / 1e6:.3f} MB raw a record")
    for name, (comp, decomp) in codecs.items():
        t = time.perf_counter()
        packed = [comp(r) for r in raws]
        tc = time.perf_counter() - t
        t = time.perf_counter()
        for p in packed:
            decomp(p)
        td = time.perf_counter() - t
        print(f"{name:7s} {sum(map(len, packed)) / n / 1e6:.4f} MB  compress {1e3 * tc / n:.2f} ms  "
              f"decompress {1e3 * td / n:.2f} ms")


if __name__ == "__main__":
    main()
