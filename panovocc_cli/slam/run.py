"""``panovocc map SEQ OUT --poses slam``: the SLAM front end feeding the streaming mapper (a runner: it writes files).

:func:`run_map_slam` runs :func:`panovocc_cli.mapping.pipeline.run_map` with a :class:`SlamPoses` pose
source: each frame is placed by the :class:`~.tracker.Tracker` before it is integrated, and every
earlier frame a pose-graph optimisation moved is revised in the map at once (``Mapper.revise``), so
the memory is always the one a map built from the poses handed out so far would hold. Besides the
map's own files it writes::

    OUT/poses.txt        the estimated poses, NICE-SLAM form, one line a frame (Mapper.save writes it;
                         a frame the tracker could not place has the last placed frame's pose and an
                         empty observation in the map)
    OUT/trajectory.tum   the placed frames' poses in TUM form, timestamp = frame index (a first comment
                         line says which world)
    OUT/slam.json        the front end's parameters, keyframes, loop closures, lost / relocalised /
                         unplaced frames, its time per frame and its world (``world``)

**World.** By default the first placed frame, levelled, at the origin (:data:`.tracker.LEVEL_FIRST`). With
``--first-pose FILE|reference`` (``MapConfig.first_pose``) the first placed frame gets that pose as it is (no
levelling on top: the pose already says where the camera looks and which way is up) and every frame follows,
``T_world_cam(i) = T_first · T_slam(k)⁻¹ · T_slam(i)`` (k the first placed frame): the map is in the file's
or the reference's world. With ``--poses-align se3`` (``MapConfig.poses_align``) the run starts as with
``--first-pose reference`` (the first placed frame at the reference's pose), and after the final refinement the
placed frames' poses are fitted to the reference trajectory's (``--poses-reference``, default SEQ/poses.txt) by
one rigid motion (Umeyama, SE(3), over every placed frame; ``--poses-align se3-pose``: fitted to the whole poses,
orientations too, :func:`~..evaluation.trajectory.fit_poses`) and every placed frame is revised to its fitted pose:
the map, ``poses.txt`` and ``trajectory.tum`` are in the reference's world, placed by the whole trajectory rather
than by its first pose (what a capture whose own poses carry per-frame noise wants: docs/slam.md, "The front end
placed by a noisy trajectory"). The sequence's own poses (SEQ/poses.txt) are never read, except as the default
reference of ``--first-pose reference`` and ``--poses-align se3`` / ``se3-pose``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from ..mapping.config import FIRST_POSE_REFERENCE, POSES_SLAM, RIGID, MapConfig, frame_ids
from .tracker import PRESETS, SlamParams, Tracker

SLAM_JSON = "slam.json"
TRAJECTORY_TUM = "trajectory.tum"


class SlamPoses:
    """A ``run_map`` pose source: ``SlamPoses(params)(seq)`` returns itself bound to a tracker for ``seq``'s
    size; calling it with ``(i, frame)`` places frame ``i`` and returns ``(T or None, revisions)``.

    first_pose : the run's ``--first-pose`` (None: the levelled first frame). When set, the tracker's world is
        ``seq.poses``, the placeholders :func:`~..mapping.pipeline.slam_first_poses` gave the sequence.
    """

    def __init__(self, params: SlamParams | None = None, first_pose: str | None = None, frames: str | None = None,
                 align: str | None = None):
        self.params = params or SlamParams()
        self.first_pose = first_pose
        # --poses-align se3 / se3-pose: how the final poses are fitted to the reference (the sequence's placeholder
        # poses are the reference's); None: no fit
        self.align = align
        self.align_to: np.ndarray | None = None  # (n, 4, 4), the reference, once bound
        self.alignment = np.eye(4)  # the rigid motion applied to the tracker's poses (identity until the last frame)
        self.frames = frames  # the run's --frames (its last frame ends the sequence: the final refinement)
        self.last: int | None = None
        self.tracker: Tracker | None = None
        self.steps: list = []
        self.revisions = 0  # frame revisions sent to the map
        self.on_loops = None  # optional callable (frame id, [(keyframe id, keyframe id)]): loop edges found

    def __call__(self, seq_or_index, frame=None):
        if frame is None:  # bind to a sequence
            anchored = self.first_pose is not None or self.align is not None  # the placeholders hold a world
            self.tracker = Tracker(seq_or_index.meta.width, seq_or_index.meta.height, self.params,
                                   T_world_first=seq_or_index.poses if anchored else None)
            self.align_to = np.asarray(seq_or_index.poses, np.float64) if self.align is not None else None
            ids = frame_ids(self.frames, len(seq_or_index))
            self.last = int(ids[-1]) if len(ids) else None
            return self
        step = self.tracker.track(int(seq_or_index), frame.depth)
        self.steps.append((step.frame_id, step.status, step.fitness, step.reason))
        T, revisions = step.T_world_cam, step.revisions
        if step.frame_id == self.last:  # the end of the sequence: the final refinement moves earlier frames
            T, revisions = finish(self.tracker, step.frame_id, T, revisions)
            if self.align_to is not None:
                T, revisions = self._aligned(step.frame_id, T)
        self.revisions += len(revisions)
        if step.loops and self.on_loops is not None:
            self.on_loops(step.frame_id, step.loops)
        return T, revisions

    def _aligned(self, fid: int, T) -> tuple:
        """After the final refinement: the rigid motion that fits the placed frames' final poses to ``align_to``'s
        (:func:`~..evaluation.trajectory.align_trajectory`, SE(3) by :attr:`align`), kept in
        :attr:`alignment`; returns the last frame's pose and every other placed frame's fitted pose as revisions
        (each placed frame moves)."""
        from ..evaluation.trajectory import align_trajectory

        committed = self.tracker.committed()
        if not committed:
            return T, []
        ids = sorted(committed)
        _, R, t, _ = align_trajectory(np.stack([committed[i] for i in ids]), self.align_to[ids], self.align)
        self.alignment = np.eye(4)
        self.alignment[:3, :3], self.alignment[:3, 3] = R, t
        moved = {i: self.alignment @ committed[i] for i in ids}
        if T is not None:
            T = moved.pop(fid)
        return T, sorted(moved.items())


def slam_params(text: str, params: SlamParams | None = None) -> SlamParams:
    """``params`` (default :class:`SlamParams`) with the fields of ``--slam-params``' JSON object ``text``
    replaced: each name a field of :class:`SlamParams`, each value of its type (an int where a float is
    expected is taken); one line naming --slam-params otherwise, before any work."""
    from ..errors import PanovoccError

    d = json.loads(text)
    base = params or SlamParams()
    fields = {f.name for f in dataclasses.fields(SlamParams)}
    unknown = sorted(set(d) - fields)
    if unknown:
        raise PanovoccError(f"--slam-params: unknown front-end parameter(s) {', '.join(unknown)} (the fields of "
                            "panovocc_cli.slam.SlamParams, docs/slam.md)")
    for name, v in d.items():
        want = type(getattr(base, name))
        if want is float and type(v) is int:  # JSON's 1 for 1.0 (a bool is not an int here)
            v = float(v)
        if type(v) is not want:
            raise PanovoccError(f"--slam-params: {name} must be {want.__name__}, got {v!r}")
        d[name] = v
    try:
        return dataclasses.replace(base, **d).check()
    except ValueError as e:
        raise PanovoccError(f"--slam-params: {e}") from None


def finish(tracker: Tracker, fid: int, T, revisions: list) -> tuple:
    """After the last frame ``fid`` (placed at ``T``, or None, with ``revisions``): :meth:`Tracker.finish`'s
    refinement; returns the last frame's pose and the revisions of the others, each frame once (its final
    pose)."""
    moved = dict(revisions) | dict(tracker.finish())
    if T is not None:
        T = moved.pop(fid, T)
    return T, sorted(moved.items())


def run_map_slam(cfg: MapConfig, overwrite: bool = False, progress: bool = True,
                 params: SlamParams | None = None, observer=None) -> dict:
    """Map ``cfg.seq`` with poses estimated online (``cfg.poses`` is set to ``"slam"``).

    Returns
    -------
    summary : run_map's summary plus ``slam`` (keyframes, loop closures, optimisations, lost,
        relocalised and unplaced frames) and ``track_ms_per_frame``

    observer : as for ``run_map``; its ``loops(frame id, edges)``, when it has one, hears of each loop closure
    """
    from ..mapping.pipeline import run_map

    cfg = dataclasses.replace(cfg, poses=POSES_SLAM)
    if cfg.slam_preset != "default":  # --slam-preset NAME, then --slam-params on top of it
        params = dataclasses.replace(params or SlamParams(), **PRESETS[cfg.slam_preset]).check()
    if cfg.slam_params is not None:  # --slam-params JSON (the flags below take precedence)
        params = slam_params(cfg.slam_params, params)
    if cfg.revise_per_frame:  # --revise-per-frame K
        params = dataclasses.replace(params or SlamParams(), revise_per_frame=int(cfg.revise_per_frame))
    if cfg.heading_prior:  # --heading-prior
        params = dataclasses.replace(params or SlamParams(), heading_prior=True)
    source = SlamPoses(params, first_pose=cfg.first_pose, frames=cfg.frames,
                       align=cfg.poses_align if cfg.poses_align in RIGID and cfg.first_pose is None else None)
    source.on_loops = getattr(observer, "loops", None)
    summary = run_map(cfg, overwrite=overwrite, progress=progress, pose_source=source, observer=observer)
    summary["slam"] = _write_slam_outputs(
        Path(summary["out"]), source.tracker, frames=summary["frames"], revisions=source.revisions,
        unplaced_frames=summary.get("unplaced_frames", []), track_ms_per_frame=summary.get("track_ms_per_frame"),
        lost_reasons={str(f): r for f, s, _, r in source.steps if r}, first_pose=cfg.first_pose,
        aligned_to=None if source.align_to is None else str(cfg.reference_path()), alignment=source.alignment)
    return summary


def world_of(tracker: Tracker, first_pose: str | None, aligned_to: str | None = None,
             alignment: np.ndarray | None = None) -> dict:
    """slam.json's ``world``: ``first_pose`` (the ``--first-pose`` given: a file's path, ``reference``, or None
    for the levelled first frame), ``first_frame`` (the first placed frame, None when none was) and
    ``T_world_first`` (its pose, 4 rows of 4; the pose graph keeps it fixed) and a sentence ``frame``."""
    if aligned_to is not None:
        words = f"the reference trajectory's world ({aligned_to}): the final poses fitted to it (--poses-align)"
    elif first_pose is None:
        words = "the first placed frame's camera, levelled (world +Z = its up), at the origin"
    elif first_pose == FIRST_POSE_REFERENCE:
        words = "the reference trajectory's world (--first-pose reference): the first placed frame at its pose there"
    else:
        words = f"the first placed frame at the pose in {first_pose} (--first-pose)"
    first = tracker.keyframes[0].frame_id if tracker.keyframes else None
    T = tracker.T_world_first if tracker.T_world_first.ndim == 2 or first is None else tracker.T_world_first[first]
    out = {"first_pose": first_pose, "first_frame": first, "T_world_first": None if first is None else T.tolist(),
           "frame": words}
    if aligned_to is not None:  # the tracker's world moved into the reference's: T_world_cam = alignment · T_slam
        out.update(aligned_to=aligned_to, alignment=np.asarray(alignment, np.float64).tolist())
    return out


def _write_slam_outputs(out: Path, tracker: Tracker, frames: int, revisions: int, unplaced_frames: list,
                        track_ms_per_frame, lost_reasons: dict, first_pose: str | None = None,
                        aligned_to: str | None = None, alignment: np.ndarray | None = None) -> dict:
    """Write ``out/trajectory.tum`` (a comment line naming the world, then the placed frames' committed poses,
    timestamp = frame index; only the comment when none was placed) and ``out/slam.json`` (the tracker's
    summary, the run's figures and :func:`world_of`); return slam.json's content."""
    from ..io.atomic import write_text
    from ..io.poses import format_tum

    committed = tracker.committed()
    ids = sorted(committed)
    world = world_of(tracker, first_pose, aligned_to, alignment)
    A = np.eye(4) if alignment is None else np.asarray(alignment, np.float64)
    poses = np.stack([A @ committed[i] for i in ids]) if ids else np.zeros((0, 4, 4))
    write_text(out / TRAJECTORY_TUM, f"# world: {world['frame']}\n"
               + format_tum(poses, timestamps=np.array(ids, np.float64)))
    info = tracker.summary() | {"frames": frames, "placed": len(ids), "revisions": revisions,
                                "unplaced_frames": unplaced_frames, "track_ms_per_frame": track_ms_per_frame,
                                "lost_reasons": lost_reasons, "world": world}
    write_text(out / SLAM_JSON, json.dumps(info, indent=2) + "\n")
    return info


def run_slam_poses(seq: str | Path, out: str | Path, params: SlamParams | None = None,
                   first_pose: str | None = None, poses_reference: str | None = None,
                   frame_times: str | Path | None = None) -> dict:
    """Only the poses: the front end over ``seq``'s depth frames, no map (what a pipeline that maps again
    with aligned poses needs, e.g. the benchmark's SLAM split: it skips the map's integration and revisions).

    Writes into the folder ``out`` (created): ``poses.txt`` (NICE-SLAM form, one line a frame; a frame the
    tracker could not place has the last placed frame's pose, the world's first pose before the first), the
    same file ``map --poses slam [--first-pose ...]`` writes for the same sequence; ``trajectory.tum`` and
    ``slam.json`` as there (without the map's fields). ``first_pose`` and ``poses_reference`` as for the map
    (``--first-pose FILE|reference``, ``--poses-reference``); SEQ/poses.txt is read only as the default
    reference of ``first_pose="reference"``. ``frame_times``: also write this CSV, one row a frame:
    ``frame,t_s,track_ms,keyframes,points_bytes,held_bytes,rss_mb`` (seconds since the first frame, the
    tracker's wall time for the frame, the last frame's including the final refinement; the keyframe store
    after it, :meth:`.Tracker.memory`; the process's resident memory), for the front end's cost over a long walk.

    Returns
    -------
    info : slam.json's content
    """
    import time

    from ..io.atomic import write_text
    from ..io.poses import write_poses
    from ..io.sequence import Sequence, read_meta
    from ..mapping.pipeline import resident_mb, slam_first_poses

    n = read_meta(seq).frames
    first = slam_first_poses(MapConfig(seq=str(seq), out=str(out), poses=POSES_SLAM, first_pose=first_pose,
                                       poses_reference=poses_reference), n)
    sq = Sequence(seq, poses=first)
    tracker = Tracker(sq.meta.width, sq.meta.height, params, T_world_first=None if first_pose is None else first)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    poses, last = first.copy(), first[0].copy() if n else np.eye(4)
    unplaced, reasons, revisions, t_track, rows = [], {}, 0, 0.0, []
    t_start = time.perf_counter()
    for i in range(n):
        depth = sq.depth(i)
        t0 = time.perf_counter()
        step = tracker.track(i, depth)
        T, moved = finish(tracker, i, step.T_world_cam, step.revisions) if i == n - 1 else (step.T_world_cam, step.revisions)
        t1 = time.perf_counter()
        t_track += t1 - t0
        if frame_times is not None:
            m = tracker.memory()
            rows.append(f"{i},{t1 - t_start:.4f},{1e3 * (t1 - t0):.3f},{m['keyframes']},{m['points']},"
                        f"{m['held_bytes']},{resident_mb():.1f}\n")
        for fid, Tr in moved:
            poses[fid] = Tr
        revisions += len(moved)
        if step.placed:
            poses[i] = last = T
        else:
            poses[i] = last
            unplaced.append(i)
        if step.reason:
            reasons[str(i)] = step.reason
    write_poses(out / "poses.txt", poses)
    if frame_times is not None:
        write_text(Path(frame_times), "frame,t_s,track_ms,keyframes,points_bytes,held_bytes,rss_mb\n" + "".join(rows))
    return _write_slam_outputs(out, tracker, frames=n, revisions=revisions, unplaced_frames=unplaced,
                               track_ms_per_frame=1e3 * t_track / max(n, 1), lost_reasons=reasons,
                               first_pose=first_pose)
