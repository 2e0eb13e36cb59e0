"""Synthetic ERP frames with known answers for the semantics tests: a furnished box room, ray-cast."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from panovocc_cli.geometry.erp import ray_directions

CLASS_NAMES = ["unlabeled", "wall", "floor", "ceiling", "window", "door", "curtain", "chair", "sofa", "table",
               "bed", "tv-screen", "lamp", "pillow", "rug", "cabinet", "indoor-plant", "blinds"]

# Room [-2.5, 2.5] x [-3, 3] x [0, 2.6] metres, +Z up.
ROOM_LO = np.array([-2.5, -3.0, 0.0])
ROOM_HI = np.array([2.5, 3.0, 2.6])
BOXES = [  # name, lo, hi (axis-aligned, world frame)
    ("rug", (-1.2, -1.0, 0.0), (1.2, 1.0, 0.01)),
    ("bed", (-2.5, 0.8, 0.0), (-0.6, 3.0, 0.55)),
    ("pillow", (-2.3, 2.4, 0.55), (-0.8, 2.9, 0.7)),
    ("sofa", (0.8, -2.9, 0.0), (2.5, -1.2, 0.8)),
    ("chair", (-1.6, -2.2, 0.0), (-1.0, -1.6, 0.9)),
    ("table", (-0.6, -2.4, 0.0), (0.5, -1.6, 0.75)),
    ("cabinet", (1.9, 1.0, 0.0), (2.5, 2.2, 1.1)),
    ("tv-screen", (2.45, -0.9, 1.0), (2.5, 0.6, 1.8)),
    ("window", (-1.0, 2.97, 0.9), (0.8, 3.0, 2.1)),
    ("curtain", (0.8, 2.85, 0.2), (1.5, 3.0, 2.5)),
    ("blinds", (-2.5, -2.6, 1.0), (-2.47, -1.2, 2.0)),
    ("door", (-0.5, -3.0, 0.0), (0.5, -2.97, 2.1)),
    ("lamp", (-0.3, -0.3, 2.45), (0.3, 0.3, 2.6)),
    ("indoor-plant", (1.9, 2.4, 0.0), (2.4, 2.9, 1.2)),
]
# OpenCV camera axes (x right, y down, z forward) in the world: forward = +Y, down = -Z.
R_WORLD_CAM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def pose(position=(0.0, 0.0, 1.5), yaw: float = 0.0) -> np.ndarray:
    """T_world_cam (4, 4) float64 of a level camera at ``position`` turned by ``yaw`` about +Z."""
    c, s = np.cos(yaw), np.sin(yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = rz @ R_WORLD_CAM
    T[:3, 3] = position
    return T


def render_room(width: int = 256, T_world_cam: np.ndarray | None = None):
    """Ray-cast the furnished room.

    Returns
    -------
    labels : (H, W) int64 ids into CLASS_NAMES
    depth : (H, W) float32 radial metres
    rgb : (H, W, 3) uint8, a flat colour per class
    """
    T = pose() if T_world_cam is None else T_world_cam
    rays = ray_directions(width)
    d = rays @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t_lo = (ROOM_LO - o) * inv
        t_hi = (ROOM_HI - o) * inv
        t_exit_axes = np.maximum(t_lo, t_hi)
        axis = np.argmin(t_exit_axes, axis=-1)
        t_best = np.min(t_exit_axes, axis=-1)
        up = d[..., 2] > 0
        labels = np.where(axis == 2, np.where(up, 3, 2), 1).astype(np.int64)
        for name, lo, hi in BOXES:
            a = (np.asarray(lo) - o) * inv
            b = (np.asarray(hi) - o) * inv
            t_in = np.max(np.minimum(a, b), axis=-1)
            t_out = np.min(np.maximum(a, b), axis=-1)
            hit = (t_in <= t_out) & (t_in > 0) & (t_in < t_best)
            t_best = np.where(hit, t_in, t_best)
            labels[hit] = CLASS_NAMES.index(name)
    rng = np.random.default_rng(len(CLASS_NAMES))
    palette = rng.integers(0, 256, (len(CLASS_NAMES), 3)).astype(np.uint8)
    return labels, t_best.astype(np.float32), palette[labels]


def circle_poses(n: int) -> np.ndarray:
    """``n`` camera poses (n, 4, 4) on an ellipse around the room's centre, 1.4 m high, turning as they go."""
    return np.stack([pose((0.8 * np.sin(2 * np.pi * i / n), 1.0 * np.cos(2 * np.pi * i / n), 1.4), yaw=0.9 * i)
                     for i in range(n)])


def write_labelled_room(seq, width: int, n: int):
    """Render the furnished, labelled room from :func:`circle_poses` into a sequence folder ``seq``."""
    from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses

    poses = circle_poses(n)
    for i, T in enumerate(poses):
        lab, d, rgb = render_room(width, T)
        write_frame(seq, i, rgb, d, lab)
    write_meta(seq, SequenceMeta(width=width, height=width // 2, frames=n, class_names=CLASS_NAMES))
    write_sequence_poses(seq, poses)
    return seq


@contextmanager
def room_feature_map(root, encoder, width: int = 128, frames: int = 6):
    """The furnished room at ``width`` x ``width / 2``, ``frames`` frames, mapped with the one-word vocabulary
    ``object`` and ``--features`` (D = 64) into ``root / "m"``: the room's words are known to the map only through
    its features. The simulated segmenter's text model is replaced by ``encoder()`` (no torch) until the context
    ends. Yields (map folder, sequence folder)."""
    import pytest

    from panovocc_cli.mapping.config import SemanticParams
    from panovocc_cli.mapping.pipeline import MapConfig, run_map
    from panovocc_cli.semantics.simulated import SimulatedSegmenter

    seq = write_labelled_room(root / "room", width, frames)
    mp = pytest.MonkeyPatch()
    mp.setattr(SimulatedSegmenter, "text_encoder", lambda self: encoder())
    try:
        run_map(MapConfig(seq=str(seq), out=str(root / "m"), checkpoint_every=0,
                          semantic=SemanticParams(vocab="object", features=True, feature_dim=64)), progress=False)
        yield root / "m", seq
    finally:
        mp.undo()
