"""``Mapper.revise_many`` (one new delta computed at a time, beside the swap) against a variant that computes two
new deltas at once on two threads, in one process on one loaded map (docs/mapping.md, "Building revise,
eleventh pass"): alternating rounds, each revising the first N changed frames to the other pose file, the
revisions' wall and CPU time per frame. Not kept in the toolkit; the variant's memory equals the default's
(the same calls in the same order). Nothing is saved: the map folder keeps its committed state (the rounds'
records are uncommitted and cut off when it is next opened).

    python scripts/revise_workers_ab.py MAP POSES_NOW POSES_OTHER [N] [ROUNDS]

MAP's frames must be at POSES_NOW (e.g. the bench-scale map and its two pose files, in the right order).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import panovocc_cli.runtime as rt
from panovocc_cli.io.poses import frame_poses
from panovocc_cli.io.sequence import read_meta
from panovocc_cli.mapping import Mapper
from panovocc_cli.mapping.pipeline import (SequenceFrames, _open_sequence, concurrent_kernels_safe, load_config,
                                           prefetched)


def two_at_once(m: Mapper, revisions) -> int:
    """The variant: each frame's kept delta read ahead, new deltas on two threads (three queued), swaps in order."""
    reader = ThreadPoolExecutor(1, thread_name_prefix="revise-read")
    deltas = ThreadPoolExecutor(2, thread_name_prefix="revise-delta")
    swapper = ThreadPoolExecutor(1, thread_name_prefix="revise")
    window, pending, count = deque(), None, 0

    def advance():
        nonlocal pending, count
        job = window.popleft().result()
        if pending is not None:
            pending.result()
            count += 1
            pending = None
        if job is not None:
            pending = swapper.submit(m._swap, *job)

    try:
        for fid, T, frame in revisions:
            while len(window) >= (3 if concurrent_kernels_safe() else 1):
                advance()
            ahead = reader.submit(m._rpu.store.get, int(fid))
            window.append(deltas.submit(m._revision, int(fid), T, frame, ahead))
        while window:
            advance()
        if pending is not None:
            pending.result()
            count += 1
    finally:
        for p in (reader, deltas, swapper):
            p.shutdown(wait=True)
    return count


def main() -> None:
    out, p_now, p_other = sys.argv[1], sys.argv[2], sys.argv[3]
    n = int(sys.argv[4]) if len(sys.argv) > 4 else 200
    rounds = int(sys.argv[5]) if len(sys.argv) > 5 else 6
    rt.setup()
    cfg = load_config(out)
    frames = read_meta(cfg.seq).frames
    A, B = frame_poses(p_now, frames), frame_poses(p_other, frames)
    m = Mapper.load(out)
    ids = [i for i in m.frame_ids if not np.array_equal(A[i], B[i])][:n]
    if not all(np.array_equal(m.pose(i), A[i]) for i in ids):
        raise SystemExit(f"{out}: its frames are not at {p_now}")
    read = SequenceFrames(_open_sequence(dataclasses.replace(cfg, poses=p_now), A)).read
    impl = {"one at a time (revise_many)": m.revise_many, "two at once": lambda it: two_at_once(m, it)}
    res = {k: [] for k in impl}
    at = A
    for r in range(rounds):
        for name in (list(impl) if r % 2 == 0 else list(impl)[::-1]):
            to = B if at is A else A
            w, c = time.perf_counter(), time.process_time()
            assert impl[name]((i, to[i], f) for i, f in prefetched(read, ids)) == len(ids)
            m.flush()
            res[name].append((time.perf_counter() - w, time.process_time() - c))
            at = to
    for name, v in res.items():
        w, c = np.array(v).T * 1e3 / len(ids)
        print(f"{name}: wall {np.round(w, 1).tolist()} ms a frame, median {np.median(w):.2f}; "
              f"CPU median {np.median(c):.2f}")
    m.close()


if __name__ == "__main__":
    main()
