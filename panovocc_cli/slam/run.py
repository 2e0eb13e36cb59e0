"""``panovocc map SEQ OUT --poses slam``: the SLAM front end feeding the streaming mapper (a runner: it writes files).

:func:`run_map_slam` runs :func:`panovocc_cli.mapping.pipeline.run_map` with a :class:`SlamPoses` pose
source: each frame is placed by the :class:`~.tracker.Tracker` before it is integrated, and every
earlier frame a pose-graph optimisation moved is revised in the map at once (``Mapper.revise``), so
the memory is always the one a map built from the poses handed out so far would hold. Besides the
map's own files it writes::

    OUT/poses.txt        the estimated poses, NICE-SLAM form, one line a frame (Mapper.save writes it;
                         a frame the tracker could not place has the last placed frame's pose and an
                         empty observation in the map)
    OUT/trajectory.tum   the placed frames' poses in TUM form, timestamp = frame index
    OUT/slam.json        the front end's parameters, keyframes, loop closures, lost / relocalised /
                         unplaced frames and its time per frame

The sequence's own poses (SEQ/poses.txt) are never read.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ..mapping.config import POSES_SLAM, MapConfig
from .tracker import SlamParams, Tracker

SLAM_JSON = "slam.json"
TRAJECTORY_TUM = "trajectory.tum"


class SlamPoses:
    """A ``run_map`` pose source: ``SlamPoses(params)(seq)`` returns itself bound to a tracker for ``seq``'s
    size; calling it with ``(i, frame)`` places frame ``i`` and returns ``(T or None, revisions)``."""

    def __init__(self, params: SlamParams | None = None):
        self.params = params or SlamParams()
        self.tracker: Tracker | None = None
        self.steps: list = []
        self.revisions = 0  # frame revisions sent to the map
        self.on_loops = None  # optional callable (frame id, [(keyframe id, keyframe id)]): loop edges found

    def __call__(self, seq_or_index, frame=None):
        if frame is None:  # bind to a sequence
            self.tracker = Tracker(seq_or_index.meta.width, seq_or_index.meta.height, self.params)
            return self
        step = self.tracker.track(int(seq_or_index), frame.depth)
        self.steps.append((step.frame_id, step.status, step.fitness, step.reason))
        self.revisions += len(step.revisions)
        if step.loops and self.on_loops is not None:
            self.on_loops(step.frame_id, step.loops)
        return step.T_world_cam, step.revisions


def run_map_slam(cfg: MapConfig, overwrite: bool = False, progress: bool = True,
                 params: SlamParams | None = None, observer=None) -> dict:
    """Map ``cfg.seq`` with poses estimated online (``cfg.poses`` is set to ``"slam"``).

    Returns
    -------
    summary : run_map's summary plus ``slam`` (keyframes, loop closures, optimisations, lost,
        relocalised and unplaced frames) and ``track_ms_per_frame``

    observer : as for ``run_map``; its ``loops(frame id, edges)``, when it has one, hears of each loop closure
    """
    from ..io.atomic import write_text
    from ..io.poses import write_tum
    from ..mapping.pipeline import run_map

    cfg = dataclasses.replace(cfg, poses=POSES_SLAM)
    source = SlamPoses(params)
    source.on_loops = getattr(observer, "loops", None)
    summary = run_map(cfg, overwrite=overwrite, progress=progress, pose_source=source, observer=observer)
    out = Path(summary["out"])
    tr = source.tracker
    committed = tr.committed()
    ids = sorted(committed)
    if ids:
        write_tum(out / TRAJECTORY_TUM, np.stack([committed[i] for i in ids]), timestamps=np.array(ids, np.float64))
    else:
        write_text(out / TRAJECTORY_TUM, "")
    info = tr.summary() | {"frames": summary["frames"], "placed": len(ids), "revisions": source.revisions,
                           "unplaced_frames": summary.get("unplaced_frames", []),
                           "track_ms_per_frame": summary.get("track_ms_per_frame"),
                           "lost_reasons": {str(f): r for f, s, _, r in source.steps if r}}
    write_text(out / SLAM_JSON, json.dumps(info, indent=2) + "\n")
    summary["slam"] = info
    return summary


def run_slam_poses(seq: str | Path, out: str | Path, params: SlamParams | None = None) -> dict:
    """Only the poses: the front end over ``seq``'s depth frames, no map (what a pipeline that maps again
    with aligned poses needs, e.g. the benchmark's SLAM split: it skips the map's integration and revisions).

    Writes into the folder ``out`` (created): ``poses.txt`` (NICE-SLAM form, one line a frame; a frame the
    tracker could not place has the last placed frame's pose, identity before the first), the same file
    ``map --poses slam`` writes for the same sequence; ``trajectory.tum`` and ``slam.json`` as there
    (without the map's fields). SEQ/poses.txt is never read.

    Returns
    -------
    info : slam.json's content
    """
    import time

    from ..io.atomic import write_text
    from ..io.poses import write_poses, write_tum
    from ..io.sequence import Sequence, read_meta

    n = read_meta(seq).frames
    sq = Sequence(seq, poses=np.tile(np.eye(4), (n, 1, 1)))
    tracker = Tracker(sq.meta.width, sq.meta.height, params)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    poses, last = np.tile(np.eye(4), (n, 1, 1)), np.eye(4)
    unplaced, reasons, revisions, t_track = [], {}, 0, 0.0
    for i in range(n):
        depth = sq.depth(i)
        t0 = time.perf_counter()
        step = tracker.track(i, depth)
        t_track += time.perf_counter() - t0
        for fid, T in step.revisions:
            poses[fid] = T
        revisions += len(step.revisions)
        if step.placed:
            poses[i] = last = step.T_world_cam
        else:
            poses[i] = last
            unplaced.append(i)
        if step.reason:
            reasons[str(i)] = step.reason
    committed = tracker.committed()
    ids = sorted(committed)
    write_poses(out / "poses.txt", poses)
    if ids:
        write_tum(out / TRAJECTORY_TUM, np.stack([committed[i] for i in ids]), timestamps=np.array(ids, np.float64))
    else:
        write_text(out / TRAJECTORY_TUM, "")
    info = tracker.summary() | {"frames": n, "placed": len(ids), "revisions": revisions, "unplaced_frames": unplaced,
                                "track_ms_per_frame": 1e3 * t_track / max(n, 1), "lost_reasons": reasons}
    write_text(out / SLAM_JSON, json.dumps(info, indent=2) + "\n")
    return info
