"""The allocations alive at the high-water mark of a ``memray`` capture, the memory's reserved address space
left out (docs/mapping.md, "The house's peak, fourth pass"). ``VoxelMemory`` reserves gigabytes of address
space it touches a block at a time (``memory._reserve``), which memray counts as allocated; this replays the
capture without those reservations, finds the peak of what stays and prints it grouped by the top three
frames of the allocating stack (MB). Needs ``pip install memray`` (not a dependency of the toolkit).

    python -m memray run -o CAP.bin .venv/bin/panovocc map SEQ OUT
    python scripts/memray_high_water.py CAP.bin [--top 25]
"""

from __future__ import annotations

import argparse
import collections

import memray
from memray import AllocatorType

FREES = {AllocatorType.FREE, AllocatorType.MUNMAP}
RESERVE_MIN = 1 << 20  # allocations this large are checked for memory._reserve in their stack


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture")
    ap.add_argument("--top", type=int, default=25)
    a = ap.parse_args()
    reserve: dict = {}
    live: dict = {}
    cur = peak = 0
    snapshot: dict = {}
    for rec in memray.FileReader(a.capture).get_allocation_records():
        if rec.allocator in FREES:
            s = live.pop(rec.address, None)
            cur -= 0 if s is None else s[0]
            continue
        key = (rec.stack_id, rec.tid)
        if rec.size >= RESERVE_MIN:
            if key not in reserve:
                reserve[key] = any(f[0] == "_reserve" for f in rec.stack_trace(max_stacks=3))
            if reserve[key]:
                continue
        live[rec.address] = (rec.size, key)
        cur += rec.size
        if cur > peak:
            peak = cur
            if rec.size > 100_000 or not snapshot:  # a new peak worth keeping (small ones move it little)
                snapshot = dict(live)
    by_key = collections.Counter()
    for size, key in snapshot.values():
        by_key[key] += size
    where = collections.Counter()
    need = set(by_key)
    for rec in memray.FileReader(a.capture).get_allocation_records():
        key = (rec.stack_id, rec.tid)
        if key in need and rec.allocator not in FREES:
            st = rec.stack_trace(max_stacks=4)
            where[" < ".join(f"{f[0]}:{f[1].split('/')[-1]}:{f[2]}" for f in st[:3])] += by_key[key]
            need.discard(key)
            if not need:
                break
    print(f"peak {peak / 1e6:.1f} MB (reservations left out)")
    for loc, size in where.most_common(a.top):
        print(f"{size / 1e6:8.2f} MB  {loc}")


if __name__ == "__main__":
    main()
