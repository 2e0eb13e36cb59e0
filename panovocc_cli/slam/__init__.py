"""A panoramic RGB-D SLAM front end: frame-to-keyframe tracking, loop closure, pose-graph optimisation.

``Tracker(width, height, SlamParams()).track(frame_id, depth)`` places one ERP frame and returns the
earlier frames an optimisation moved (revisions for a streaming ``Mapper``); :mod:`.run` couples it
with the mapper for ``panovocc map --poses slam``. A library: no files, no printing (docs/slam.md).
"""

from .tracker import LOST, SlamParams, Tracker, TrackStep

__all__ = ["LOST", "SlamParams", "Tracker", "TrackStep"]
