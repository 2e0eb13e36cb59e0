"""What iSAM2's relinearisation settings cost on a long walk (docs/slam.md, "Where a building keyframe's time
goes"): tracks the first N frames of SEQ with the default ``SlamParams`` while recording every call the
tracker makes to its incremental pose graph (``posegraph.IncrementalGraph``: the graph's creation, each
keyframe's update with its new poses and edges, each read-back), then replays that record into fresh graphs
with other settings, one after another in this process, and prints one line per setting: the median update
(ms) over the updates of frames 10-20 % and of the last 10 % of the record, the total, and how far each
read-back lies from the first setting's (largest translation difference over all read-backs, and at the last).

    python scripts/slam_isam_replay.py SEQ N

Settings: relinearisation threshold 1e-4 considered at every update (what the tracker did before
``isam_skip``); 1e-3 and 1e-2 at every update; 1e-4 every 10th update with plain read-backs; and 1e-4 every
5th, 10th (the default) and 25th update with the read-backs' updates forced to relinearise.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    setup()
    import gtsam

    from panovocc_cli.benchmark.scale import early_late
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker
    from panovocc_cli.slam import posegraph as PG

    seq, n = Sequence(sys.argv[1]), int(sys.argv[2])
    record = []  # ("init", args, kwargs) | ("add", poses, edges) | ("estimate", converge)
    init, add, estimate = PG.IncrementalGraph.__init__, PG.IncrementalGraph.add, PG.IncrementalGraph.estimate

    def rec_init(g, *a, **k):
        record.append(("init", a, k))
        init(g, *a, **k)

    def rec_add(g, poses, edges):
        record.append(("add", [np.array(P) for P in poses], list(edges)))
        add(g, poses, edges)

    def rec_estimate(g, converge=True):
        record.append(("estimate", converge))
        return estimate(g, converge)

    PG.IncrementalGraph.__init__, PG.IncrementalGraph.add, PG.IncrementalGraph.estimate = rec_init, rec_add, rec_estimate
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(), T_world_first=seq.poses[0])
    for i in range(n):
        tr.track(i, seq.depth(i))
    PG.IncrementalGraph.__init__, PG.IncrementalGraph.add, PG.IncrementalGraph.estimate = init, add, estimate

    def read_back(g, converge, force):
        if converge:
            for _ in range(g.iterations):
                if g.isam.update(force_relinearize=force).getVariablesRelinearized() == 0:
                    break
        return PG._anchored(g.isam.calculateEstimate(), g.nodes)

    def replay(threshold, skip, force):
        g, ms, out = None, [], []
        for item in record:
            if item[0] == "init":
                g = PG.IncrementalGraph(*item[1], **item[2])
                p = gtsam.ISAM2Params()
                p.setRelinearizeThreshold(threshold)
                p.relinearizeSkip = skip
                g.isam = gtsam.ISAM2(p)
            elif item[0] == "add":
                t = time.perf_counter()
                add(g, item[1], item[2])
                ms.append(1e3 * (time.perf_counter() - t))
            else:
                out.append(read_back(g, item[1], force))
        return np.array(ms), out

    base = None
    for threshold, skip, force in [(1e-4, 1, False), (1e-3, 1, False), (1e-2, 1, False), (1e-4, 10, False),
                                   (1e-4, 5, True), (1e-4, 10, True), (1e-4, 25, True)]:
        ms, est = replay(threshold, skip, force)
        early, late = early_late(len(ms))
        line = (f"threshold {threshold:g} skip {skip}{' forced read-back' if force else ''}: {len(ms)} updates, "
                f"median {np.median(ms[early]):.2f} / {np.median(ms[late]):.2f} ms (frames 10-20 % / last 10 %), "
                f"total {ms.sum() / 1e3:.1f} s")
        if base is None:
            base = est
        elif est:
            d = [float(np.abs(a[:, :3, 3] - b[:, :3, 3]).max()) for a, b in zip(base, est)]
            line += f"; read-backs {len(est)}, largest difference {max(d):.2e} m, at the last {d[-1]:.2e} m"
        print(line, flush=True)


if __name__ == "__main__":
    main()
