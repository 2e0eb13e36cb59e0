"""The live log of a mapping run (``panovocc map ... --rerun FILE.rrd`` / ``--rerun-connect``).

:class:`LiveLog` is the observer :func:`panovocc_cli.mapping.pipeline.run_map` calls after each frame
(``frame(i, frame, mapper, revisions)``) and once at the end (``finish(mapper, summary)``); the SLAM pose
source calls ``loops(i, edges)`` when it adds loop edges. On the ``frame`` timeline it logs each frame's
panorama and depth and its pose, every ``every`` frames (and after any revision) the map as it stands
(occupied voxels coloured by class) and the trajectory, the revisions (text and the revised cameras) and the
loop closures (lines between the two keyframes); at the end the final map and the run's summary.

The log is opened at the first frame (after the run's own checks), written to a temporary name and renamed
onto ``rrd`` by :meth:`close` when the run succeeded; a failed run leaves no ``.rrd`` behind.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..grid import OCCUPIED_UNKNOWN_CLASS
from . import rerun_log as rl

DEFAULT_EVERY = 10
"""Frames between two logs of the growing map (a map export each time)."""
DEFAULT_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where ``--rerun-connect`` streams by default: a viewer started with ``rerun`` on this machine."""


class LiveLog:
    """A run's live log to an ``.rrd`` file or a running viewer.

    Parameters
    ----------
    rrd : the ``.rrd`` file to write (checked by the caller; renamed into place by ``close(ok=True)``)
    connect : a viewer's gRPC URL to stream to instead (``""``: :data:`DEFAULT_URL`)
    every : frames between two logs of the map (>= 1)
    pano_width : panoramas and depth are subsampled to at most this width (0 = full size)
    """

    def __init__(self, rrd: str | Path | None = None, connect: str | None = None, every: int = DEFAULT_EVERY,
                 pano_width: int = 512):
        if (rrd is None) == (connect is None):
            raise ValueError("LiveLog needs exactly one of rrd, connect")
        if int(every) < 1:
            raise PanovoccError(f"--rerun-every must be >= 1, got {every}")
        rl.require_rerun()
        if rrd is not None and Path(rrd).suffix != ".rrd":
            raise PanovoccError("expected a .rrd file name (Rerun's recording format)", rrd)
        self.rrd = None if rrd is None else Path(rrd)
        self.connect = connect
        self.every = int(every)
        self.pano_width = int(pano_width)
        self.rec = None
        self._stack = contextlib.ExitStack()
        self._tmp: Path | None = None
        self.positions: dict[int, np.ndarray] = {}  # frame id -> camera centre, as revised
        self.loop_edges: list[tuple[int, int]] = []
        self.map_logs = 0
        self._dirty = False

    # -- the stream --------------------------------------------------------------------------------
    def _open(self):
        if self.rec is None:
            if self.rrd is not None:
                from ..io.atomic import atomic_path

                self._tmp = self._stack.enter_context(atomic_path(self.rrd))
                self.rec = rl.open_stream(rrd=self._tmp)
            else:
                self.rec = rl.open_stream(connect=self.connect or DEFAULT_URL)
        return self.rec

    def close(self, ok: bool) -> None:
        """Flush the log; with ``ok`` rename the ``.rrd`` into place, else drop it (nothing half-written)."""
        if self.rec is not None:
            self.rec.flush()
            self.rec.disconnect()
            self.rec = None
        if ok:
            self._stack.close()
        else:
            self._stack.__exit__(RuntimeError, RuntimeError("run failed"), None)
        self._stack = contextlib.ExitStack()

    # -- the observer ------------------------------------------------------------------------------
    def frame(self, i: int, frame, mapper, revisions=()) -> None:
        """After frame ``i`` was integrated (and ``revisions`` [(frame id, T_world_cam)] applied)."""
        rec = self._open()
        rec.set_time(rl.TIMELINE, sequence=int(i))
        T = np.asarray(frame.T_world_cam, np.float64)
        self.positions[int(i)] = T[:3, 3].copy()
        rl.log_camera(rec, T)
        rl.log_frame_images(rec, frame.rgb, frame.depth, max_width=self.pano_width)
        if revisions:
            revised = []
            for fid, Tr in revisions:
                self.positions[int(fid)] = np.asarray(Tr, np.float64)[:3, 3].copy()
                revised.append(self.positions[int(fid)])
            rl.log_text(rec, f"frame {i}: {len(revisions)} earlier frame(s) revised: "
                             + ", ".join(str(int(f)) for f, _ in revisions[:20]) + (", ..." if len(revisions) > 20 else ""))
            import rerun as rr

            rec.log("world/slam/revised", rr.Points3D(np.asarray(revised, np.float32), radii=0.05,
                                                      colors=[(255, 0, 255)]))
            self._dirty = True
        if self._dirty or (i + 1) % self.every == 0:
            self._log_state(mapper)

    def loops(self, i: int, edges) -> None:
        """Loop edges [(keyframe id, keyframe id)] the SLAM front end added at frame ``i``."""
        if not edges:
            return
        rec = self._open()
        rec.set_time(rl.TIMELINE, sequence=int(i))
        self.loop_edges.extend((int(a), int(b)) for a, b in edges)
        rl.log_text(rec, f"frame {i}: loop closure " + ", ".join(f"{a}-{b}" for a, b in edges))
        self._dirty = True

    def finish(self, mapper, summary: dict) -> None:
        """At the end of a finished run: the final map and the run's summary."""
        rec = self._open()
        self._log_state(mapper)
        shown = {k: v for k, v in summary.items() if isinstance(v, (int, float, str))}
        rl.log_text(rec, "run finished: " + ", ".join(f"{k}={v:.1f}" if isinstance(v, float) else f"{k}={v}"
                                                   for k, v in shown.items()))

    def _log_state(self, mapper) -> None:
        """The map as it stands (occupied voxels by class), the trajectory and the loop closures."""
        import rerun as rr

        rec = self.rec
        ex = mapper.export()
        names = ex.grid.class_names
        if self.map_logs == 0:
            rec.log("world/map", rl.annotation_context(names), static=True)
        ids = (np.full(len(ex.occupied_keys), OCCUPIED_UNKNOWN_CLASS, np.uint16) if ex.labels is None
               else np.where(ex.labels >= 0, ex.labels + 1, OCCUPIED_UNKNOWN_CLASS).astype(np.uint16))
        rec.log("world/map/occupied", rl.voxel_boxes(ex.centres(), ex.grid.voxel_size, class_ids=ids))
        order = sorted(self.positions)
        if order:
            rec.log("world/trajectory", rr.LineStrips3D([np.stack([self.positions[k] for k in order]).astype(np.float32)],
                                                        colors=[(255, 255, 255)]))
        rl.log_loop_closures(rec, self.loop_edges, self.positions)
        self.map_logs += 1
        self._dirty = False
