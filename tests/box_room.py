"""A closed-form box room for the mapping tests."""

import numpy as np

from panovocc_cli.geometry.erp import ray_directions

LO, HI = np.array([-2.0, -1.5, -1.2]), np.array([2.0, 1.5, 1.6])  # walls, metres, world frame


def box_depth(W, T=np.eye(4), lo=LO, hi=HI):
    """(W/2, W) float32 radial depth of the walls of the box [lo, hi] seen from pose T (ray-plane distances)."""
    d = ray_directions(W) @ T[:3, :3].T
    o = T[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (hi - o) / d, (lo - o) / d)
    t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
    return t.min(axis=-1).astype(np.float32)


def turned_pose(yaw=0.3, t=(0.3, -0.2, 0.1)):
    """(4, 4) float64 camera pose turned by ``yaw`` radians about z and shifted by t, metres."""
    T = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = t
    return T
