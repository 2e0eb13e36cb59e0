"""What the memory's per-frame kernels cost on a map's own frames (docs/mapping.md, "Speed": the memory's add
without a call at every row).

    python scripts/memory_add_cost.py MAP [--frames 40] [--frame 20] [--calls 20]

MAP: a map folder (its ``config.json`` names the sequence and the mapper's settings). The first ``--frames`` frames'
deltas are computed once (read, segmented, observed as ``map`` does); then, each as the mean of ``--calls`` calls:

* ``add``: every delta added into a fresh memory, per frame (the geometric and the semantic part);
* ``_add_dense``: frame ``--frame``'s geometric rows added (and taken out again) into the memory of all the frames;
* ``nonzero``: ``VoxelMemory.nonzero`` of that memory;
* ``_locate``: the slots of frame ``--frame``'s keys, in key order and shuffled (seeded).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import panovocc_cli.runtime as runtime


def mean_ms(fn, calls: int) -> float:
    fn()  # compiled / warm
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    return 1e3 * (time.perf_counter() - t0) / calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("map")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--frame", type=int, default=20)
    ap.add_argument("--calls", type=int, default=20)
    a = ap.parse_args()
    runtime.setup()
    import panovocc_cli.mapping.memory as memory
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping.mapper import Mapper
    from panovocc_cli.mapping.pipeline import load_config, observed, sequence_frames

    cfg = load_config(a.map)
    seq = Sequence(cfg.seq)
    frames = sequence_frames(cfg, seq)
    mapper = Mapper(cfg.mapper_config())
    read = observed(frames, mapper)
    deltas = [mapper.delta(*read(i)) for i in range(min(a.frames, len(seq)))]

    def add_all():
        mem = Mapper(cfg.mapper_config()).memory
        for d in deltas:
            mem.add(d, 1)
        return mem

    print(f"add: {mean_ms(add_all, max(1, a.calls // 10)) / len(deltas):.2f} ms a frame ({len(deltas)} frames)")
    mem = add_all()
    part = deltas[a.frame].parts[0]
    keys = np.ascontiguousarray(part.keys)
    vals, cols = mem._values(part)
    lo, hi = memory._I32 if mem._geo.dtype == np.int32 else (np.iinfo(np.int64).min, np.iinfo(np.int64).max)
    signs = iter(np.tile(np.array([1, -1], np.int64), a.calls + 1))

    def dense():
        st = memory._add_dense(mem._table_keys, mem._table_slots, mem._block_keys, mem.n_blocks, mem._geo, keys,
                               vals, cols, next(signs), 0, lo, hi)
        assert st[0] == 0

    print(f"_add_dense: {mean_ms(dense, a.calls):.2f} ms for frame {a.frame}'s {len(keys):,} geometric rows")

    def nonzero():
        mem._nonzero = None
        return mem.nonzero()

    print(f"nonzero: {mean_ms(nonzero, a.calls):.2f} ms for {len(nonzero()[0]):,} voxels")
    loc = np.empty(len(keys), np.int64)
    shuffled = np.ascontiguousarray(np.random.default_rng(0).permutation(keys))
    print(f"_locate: {mean_ms(lambda: memory._locate(mem._table_keys, mem._table_slots, keys, loc), a.calls):.2f} ms "
          f"in key order, {mean_ms(lambda: memory._locate(mem._table_keys, mem._table_slots, shuffled, loc), a.calls):.2f}"
          " ms shuffled")


if __name__ == "__main__":
    main()
