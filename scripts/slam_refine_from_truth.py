"""Does the final refinement keep the truth? (docs/slam.md, "The corridors' stretch"): the front end tracks the
first ``--frames`` frames of SEQ (``SlamParams(**JSON)``), then every keyframe is put at its true
pose and every odometry edge at the true relative pose, and :meth:`Tracker.finish` refines from there (the
pairs registered from the truth, as the refinement registers them from its estimate). Prints the refinement's
edges' errors against the truth by the length of their step (mm, world frame: mean along the step, mean along
world x), then the keyframes' error after refining from the truth (RMS per world axis and the slope of the x
error along x, mm/m: a stretch of the walk along x). A control: the same graph with exact edges (each
registration replaced by the true relative pose; the loop edges the refinement keeps are the tracking's) stays
within a millimetre of the truth.

    python scripts/slam_refine_from_truth.py SEQ [--frames 1300] [--params JSON]
"""

from __future__ import annotations

import argparse
import copy
import json

import numpy as np

from panovocc_cli.runtime import setup


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("seq")
    ap.add_argument("--frames", type=int, default=1300)
    ap.add_argument("--params", default="{}", help="SlamParams fields as JSON")
    a = ap.parse_args()
    setup()
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.slam import SlamParams, Tracker
    from panovocc_cli.slam.registration import RegResult

    seq = Sequence(a.seq)
    P = seq.poses
    tr = Tracker(seq.meta.width, seq.meta.height, SlamParams(**json.loads(a.params)), T_world_first=P[0])
    for i in range(min(a.frames, len(P))):
        tr.track(i, seq.depth(i))  # the final refinement is Tracker.finish, called below
    for kf in tr.keyframes:
        kf.cloud.compact()  # no backend handles: the tracker can be copied
    tr._graph = None  # the batch solve rebuilds it

    def at_truth(t):
        t = copy.deepcopy(t)
        for kf in t.keyframes:
            kf.T_world = P[kf.frame_id].copy()
        t._edges = [(s, q, np.linalg.inv(P[t.keyframes[q].frame_id]) @ P[t.keyframes[s].frame_id] if not unc else T,
                     info, unc) for s, q, T, info, unc in t._edges]
        return t

    def report(tag, t):
        ids = [kf.frame_id for kf in t.keyframes]
        G = P[ids][:, :3, 3]
        e = np.array([kf.T_world[:3, 3] for kf in t.keyframes]) - G
        slope = np.linalg.lstsq(np.c_[np.ones(len(G)), G[:, 0], G[:, 1]], e[:, 0], rcond=None)[0][1]
        rms = 1e3 * np.sqrt((e ** 2).mean(axis=0))
        print(f"{tag}: {len(ids)} keyframes, error RMS x {rms[0]:.2f} y {rms[1]:.2f} z {rms[2]:.2f} mm, "
              f"x error along x {1e3 * slope:+.3f} mm/m", flush=True)

    # refined from the truth; the first pass's registrations (every edge from the truth) recorded on the way
    t = at_truth(tr)
    rec = []
    align = t.reg.align

    def recording(target, source, init, corr):
        r = align(target, source, init, corr)
        if t.refinements == 0:
            rec.append((np.asarray(init, float).copy(), r.T_target_source.copy()))
        return r

    t.reg.align = recording
    t.finish()
    rows = []
    for init, est in rec:
        step = init[:3, 3]
        L = float(np.linalg.norm(step))
        if L < 1e-6:
            continue
        d = est[:3, 3] - init[:3, 3]  # in the target keyframe's frame
        rows.append((L, float(d @ step) / L))
    R = np.array(rows)
    for lo, hi in ((0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 3.0)):
        k = (R[:, 0] >= lo) & (R[:, 0] < hi)
        if k.any():
            print(f"edges with a step of {lo:.1f}-{hi:.1f} m: {int(k.sum())}, error along the step: mean "
                  f"{1e3 * R[k, 1].mean():+.3f} mm (standard error {1e3 * R[k, 1].std() / np.sqrt(k.sum()):.3f})")

    exact = at_truth(tr)
    exact.reg.align = lambda target, source, init, corr: RegResult(np.asarray(init, float).copy(), 1.0, True)
    exact.finish()
    report("exact edges, refined from the truth (control)", exact)
    report("registered edges, refined from the truth", t)


if __name__ == "__main__":
    main()
