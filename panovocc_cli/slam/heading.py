"""The Manhattan heading of a keyframe: the direction of the walls it sees, about the vertical (opt-in prior of
the final refinement, ``SlamParams.heading_prior``); and its vertical: the normal of the floors and ceilings it
sees (``SlamParams.level_prior``).

Indoor scenes are mostly built on two perpendicular wall directions. A keyframe's downsampled points give
their normals (Open3D, from the 0.25 m neighbourhood); the horizontal ones (within ``HORIZONTAL`` of the
horizontal plane) have azimuths that cluster every 90°. :func:`wall_heading` takes their mean modulo 90° (the
circular mean of 4θ), then trims it three times to the normals within 10°, 4° and 2° of it: furniture at odd
angles, noisy normals and corners drop out. On the building's frames with their true poses the heading scatters
by 0.014° (one standard deviation; 0.036° on a furnished house), against the 0.05-0.09° a walk up one storey of
stairs leaves uncorrected (docs/slam.md, "The building's heading").

:func:`floor_vertical` does the same for the floors and ceilings: the normals within ``VERTICAL_DEG`` of the up
axis, turned upwards, averaged, then trimmed to those within 4, 2, 1 and 0.5 degrees of the mean (the last trim
takes out the normals that the corners of floors and walls bend: with the true poses the building's verticals
scatter by 0.002 deg with it and 0.007 deg without, every 80th frame; a noisy house's by 0.014-0.018 deg against
0.022-0.030 deg; docs/slam.md "The building's tilt"). Floors and ceilings
are level in nearly every building, so a keyframe's vertical fixes its roll and pitch absolutely; a walk along
a 94 m corridor otherwise leaves a floor tilted by 0.01-0.02 deg, tens of millimetres at its far end (docs/slam.md,
"The building's tilt"). Maths only: no files, no printing.
"""

from __future__ import annotations

import numpy as np

HORIZONTAL = np.sin(np.radians(11.5))  # |n . up| below this: a wall's normal (cos 78.5 deg)
TRIMS_DEG = (10.0, 4.0, 2.0)
VERTICAL_DEG = 10.0  # |angle(n, up)| below this: a floor's or ceiling's normal
VERTICAL_TRIMS_DEG = (4.0, 2.0, 1.0, 0.5)


def horizontal_basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane perpendicular to ``up`` (3,): the world axis least along ``up``
    projected into it, and ``up`` x that."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    a = np.eye(3)[int(np.argmin(np.abs(up)))]
    e1 = a - (a @ up) * up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def wall_heading(normals_world: np.ndarray, up: np.ndarray) -> tuple[float, float]:
    """(heading in radians in [-pi/4, pi/4), share of the horizontal normals within the last trim of it) of
    unit normals (n, 3) in the world; (nan, 0.0) when fewer than 50 normals are horizontal."""
    e1, e2 = horizontal_basis(up)
    n = np.asarray(normals_world, np.float64)
    u = n @ (np.asarray(up, np.float64) / np.linalg.norm(up))
    n = n[np.abs(u) < HORIZONTAL]
    if len(n) < 50:
        return float("nan"), 0.0
    th = np.arctan2(n @ e2, n @ e1)
    phi = quarter_mean(th)
    inside = np.ones(len(th), bool)
    for cut in np.radians(TRIMS_DEG):
        r = wrap_quarter(th - phi)
        inside = np.abs(r) < cut
        if inside.sum() < 20:
            return float("nan"), 0.0
        phi = float(wrap_quarter(phi + r[inside].mean()))
    return phi, float(inside.mean())


def floor_vertical(normals_world: np.ndarray, up: np.ndarray) -> tuple[np.ndarray | None, float]:
    """(unit vertical (3,) in the world, share of the near-vertical normals within the last trim of it) of unit
    normals (n, 3) in the world, from those within ``VERTICAL_DEG`` of ``up`` either way (floors and ceilings,
    turned to point along ``up``); (None, 0.0) when fewer than 50 are."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    n = np.asarray(normals_world, np.float64)
    u = n @ up
    keep = np.abs(u) > np.cos(np.radians(VERTICAL_DEG))
    if keep.sum() < 50:
        return None, 0.0
    n = n[keep] * np.sign(u[keep])[:, None]
    v = n.mean(axis=0)
    v /= np.linalg.norm(v)
    inside = np.ones(len(n), bool)
    for cut in np.radians(VERTICAL_TRIMS_DEG):
        inside = n @ v > np.cos(cut)
        if inside.sum() < 20:
            return None, 0.0
        v = n[inside].mean(axis=0)
        v /= np.linalg.norm(v)
    return v, float(inside.mean())


def tilt_between(v: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The smallest rotation vector (3,) turning unit ``v`` onto unit ``ref`` (its norm the angle, radians)."""
    v = np.asarray(v, np.float64)
    ref = np.asarray(ref, np.float64)
    axis = np.cross(v, ref)
    s = float(np.linalg.norm(axis))
    if s == 0.0:
        return np.zeros(3)
    return axis / s * float(np.arctan2(s, float(v @ ref)))


def quarter_mean(a) -> float:
    """The circular mean of angles (radians) modulo 90 degrees (the mean direction of 4a, over 4)."""
    return float(np.angle(np.exp(4j * np.asarray(a, np.float64)).sum()) / 4)


def wrap_quarter(a):
    """Angles (radians) to [-pi/4, pi/4): directions modulo 90 degrees."""
    return (np.asarray(a, np.float64) + np.pi / 4) % (np.pi / 2) - np.pi / 4


def cloud_normals(points_cam: np.ndarray, radius: float, threads: int = 1) -> np.ndarray:
    """Unit normals (n, 3) float64 of a keyframe's downsampled points (camera frame): Open3D's PCA over the
    neighbours within ``radius`` (at most 20)."""
    import open3d as o3d

    from .registration import open3d_threads

    with open3d_threads(threads):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points_cam, np.float64)))
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=20))
    return np.asarray(pc.normals)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis`` (any length; :func:`..geometry.drift.so3_exp`)."""
    from ..geometry.drift import so3_exp

    k = np.asarray(axis, np.float64)
    return so3_exp(k / np.linalg.norm(k) * float(angle))
