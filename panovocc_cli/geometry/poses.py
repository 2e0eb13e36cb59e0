"""Rigid poses ``T_world_cam`` (4x4 float64, camera-to-world) and quaternion conversions."""

from __future__ import annotations

import numpy as np

from ..config import RIGID_TOL
from ..errors import PanovoccError


def check_rigid(T, what: str = "pose", tol: float = RIGID_TOL) -> np.ndarray:
    """Return ``T`` as (4, 4) float64 after checking it is a rigid transform.

    Raises :class:`PanovoccError` naming ``what`` when the shape is wrong, an entry is not finite,
    the last row is not [0 0 0 1], or the rotation is not orthonormal with determinant +1.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise PanovoccError(f"{what}: expected a 4x4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise PanovoccError(f"{what}: contains NaN or infinite values")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol):
        raise PanovoccError(f"{what}: last row is {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > tol or np.linalg.det(R) < 0:
        raise PanovoccError(f"{what}: not rigid (rotation part is not orthonormal with det +1; error {err:.2e})")
    return T


def clearly_rigid(T, tol: float = RIGID_TOL) -> np.ndarray:
    """Which of the poses ``T`` (n, 4, 4) :func:`check_rigid` accepts with a margin, all at once: (n,) bool, True
    where every entry is finite, the last row is within ``tol / 2`` of [0 0 0 1] and the rotation orthonormal
    within ``tol / 10`` with det > 0.5. A pose marked False may still pass: check it with :func:`check_rigid`
    itself, which then gives its error (the margins keep a pose near a bound away from float differences
    between this batched test and that one)."""
    T = np.asarray(T, dtype=np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        R = T[:, :3, :3]
        err = np.abs(np.einsum("nij,nkj->nik", R, R) - np.eye(3)).max(axis=(1, 2))
        return (np.isfinite(T).all(axis=(1, 2)) & (np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= tol / 2)
                & (err <= tol / 10) & (np.linalg.det(np.where(np.isfinite(R), R, 0.0)) > 0.5))


def quat_to_rot(q_xyzw) -> np.ndarray:
    """Rotation matrix (3, 3) from a unit quaternion in TUM order (x, y, z, w)."""
    x, y, z, w = np.asarray(q_xyzw, dtype=np.float64) / np.linalg.norm(q_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rot_to_quat(R) -> np.ndarray:
    """Unit quaternion (x, y, z, w), w >= 0, of a rotation matrix (3, 3)."""
    R = np.asarray(R, dtype=np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def look_at(position, forward, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera at ``position`` looking along ``forward`` with world ``up``."""
    z = np.asarray(forward, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        raise PanovoccError("look_at: forward is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, np.asarray(position, dtype=np.float64)
    return T
