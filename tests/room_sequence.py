"""Sequences of the furnished box room (panovocc_cli.datasets.boxroom) for the mapping tests.

The room is rendered by the toolkit's own ray caster (rendering/raycast.py) and written without labels
(no semantic/ folder), so a map of it is geometry only unless a test asks for more.
"""

from pathlib import Path

import numpy as np

from panovocc_cli.datasets.boxroom import ROOM, room_scene, room_trajectory  # noqa: F401 (ROOM re-exported)
from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses
from panovocc_cli.rendering.raycast import RaycastRenderer


def write_room_sequence(seq, n_frames: int, width: int, furniture: bool = True) -> np.ndarray:
    """Render the room along :func:`room_trajectory` into the sequence folder ``seq``; return the poses
    (n_frames, 4, 4) float64 T_world_cam."""
    ren = RaycastRenderer(room_scene(furniture), width)
    poses = room_trajectory(n_frames)
    seq = Path(seq)
    for i, T in enumerate(poses):
        fr = ren.render(T)
        write_frame(seq, i, fr.rgb, fr.depth, None)
    write_meta(seq, SequenceMeta(width=width, height=width // 2, frames=n_frames))
    write_sequence_poses(seq, poses)
    return poses
