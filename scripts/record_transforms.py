"""Would a transform of a delta record's channels, a slower codec or a coarser support make records smaller?
(docs/mapping.md, "Delta store size", realistic depth noise). For every ``--every``-th record of MAP's delta
log, prints the mean Zstandard-3 kB a record of each stored channel as it is and after a transform (its
columns one after another, differences along the rows, zig-zagged differences, the values as they are
without byte planes); the whole record at Zstandard levels 3-19 and xz (with ms a record); and the support
A's kB with its low 4, 8, 12 bits dropped (a change of the map's fixed point, not an encoding).

    python scripts/record_transforms.py MAP [--every 3]
"""

from __future__ import annotations

import argparse
import collections
import lzma
import time
from pathlib import Path

import numpy as np

from panovocc_cli.io import mapstore


def planes(x: np.ndarray) -> bytes:
    x = mapstore._compact(x.reshape(-1))
    if x.dtype.itemsize == 1:
        return x.tobytes()
    return np.ascontiguousarray(x.view(np.uint8).reshape(-1, x.dtype.itemsize).T).tobytes()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map", type=Path)
    ap.add_argument("--every", type=int, default=3)
    a = ap.parse_args()
    zstd = mapstore._zstd()

    def size(b: bytes) -> int:
        return len(zstd.compress(b, level=3))

    log = mapstore.DeltaLog(a.map)
    locs = [loc for kind, _f, loc in log.records if kind == mapstore.PUT][::a.every]
    per = collections.defaultdict(collections.Counter)
    whole = collections.Counter()
    for loc in locs:
        payload = log.read(loc)
        arrs = mapstore.decode_arrays(payload)
        files = set(arrs)
        for k in sorted(files):
            if "ch_" not in k:
                continue
            v = mapstore._unshuffled(arrs, files, k)
            v = v.reshape(-1, 1) if v.ndim == 1 else v
            d = np.diff(v, axis=0, prepend=0)
            r = per[k]
            r["stored"] += size(np.ascontiguousarray(arrs[k]).tobytes())
            r["columns"] += size(planes(np.ascontiguousarray(v.T)))
            r["row diff"] += size(planes(d))
            r["zigzag diff"] += size(planes(np.ascontiguousarray(((d << 1) ^ (d >> 63)).T)))
            r["no planes"] += size(mapstore._compact(np.ascontiguousarray(v.T)).tobytes())
            if k == "ch_A":
                for s in (4, 8, 12):
                    r[f"A >> {s}"] += size(planes((v + (1 << s >> 1)) >> s))
        body = mapstore.payload_body(payload)
        for lv in (3, 9, 19):
            t = time.perf_counter()
            whole[f"zstd {lv}"] += len(zstd.compress(body, level=lv))
            whole[f"zstd {lv} ms"] += 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        whole["xz 6"] += len(lzma.compress(body, preset=6))
        whole["xz 6 ms"] += 1e3 * (time.perf_counter() - t)
    log.close()
    n = len(locs)
    print(f"{n} records")
    for k, r in sorted(per.items(), key=lambda x: -x[1]["stored"]):
        print(f"{k:20s} " + "  ".join(f"{m} {v / n / 1e3:.1f}" for m, v in r.items()))
    total = collections.Counter()
    for r in per.values():
        for m in ("stored", "columns", "row diff", "zigzag diff", "no planes"):
            total[m] += r[m]
    print("channels in all      " + "  ".join(f"{m} {v / n / 1e3:.1f}" for m, v in total.items()))
    print("whole record         " + "  ".join(f"{m} {v / n / (1 if 'ms' in m else 1e3):.1f}" for m, v in whole.items()))


if __name__ == "__main__":
    main()
