"""Trajectory files: NICE-SLAM ``traj.txt`` (16 floats a line, T_world_cam row-major) and TUM
(``t tx ty tz qx qy qz qw``). Foreign conventions are converted here, at the file boundary."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import PanovoccError
from ..geometry.poses import check_rigid, quat_to_rot, rot_to_quat
from .atomic import write_text


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    if not path.is_file():
        raise PanovoccError("trajectory file not found", path)
    out = []
    for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        s = line.strip()
        if s and not s.startswith("#"):
            out.append((n, s.replace(",", " ").split()))
    if not out:
        raise PanovoccError("trajectory file is empty", path)
    return out


def _floats(path: Path, n: int, parts: list[str]) -> np.ndarray:
    try:
        return np.array([float(x) for x in parts], dtype=np.float64)
    except ValueError:
        raise PanovoccError(f"line {n}: not a list of numbers", path) from None


def read_poses(path: str | Path) -> np.ndarray:
    """Read a trajectory, NICE-SLAM (16 numbers a line) or TUM (8 numbers a line) form.

    Returns
    -------
    T_world_cam : (N, 4, 4) float64, each checked rigid.
    """
    path = Path(path)
    rows = _rows(path)
    width = len(rows[0][1])
    if width not in (16, 8):
        raise PanovoccError(
            f"line {rows[0][0]}: {width} numbers; expected 16 (T_world_cam row-major, NICE-SLAM form) "
            "or 8 (TUM form: t tx ty tz qx qy qz qw)", path)
    poses = []
    for n, parts in rows:
        if len(parts) != width:
            raise PanovoccError(f"line {n}: {len(parts)} numbers, expected {width} like line {rows[0][0]}", path)
        vals = _floats(path, n, parts)
        if width == 16:
            T = vals.reshape(4, 4)
        else:
            q = vals[4:8]
            norm = float(np.sqrt(np.sum(q * q))) if np.all(np.isfinite(q)) else float("nan")
            if not (np.isfinite(norm) and norm > 1e-6):
                raise PanovoccError(f"line {n}: quaternion qx qy qz qw = {' '.join(parts[4:8])} has "
                                    f"{'zero' if norm == 0 else 'no finite'} norm; expected a rotation "
                                    "(unit quaternion)", path)
            T = np.eye(4)
            T[:3, :3] = quat_to_rot(q)
            T[:3, 3] = vals[1:4]
        poses.append(check_rigid(T, what=f"{path}: line {n}"))
    return np.stack(poses)


def format_poses(T_world_cam: np.ndarray) -> str:
    """NICE-SLAM text: one line of 16 numbers a pose (row-major, full float64 precision)."""
    return "".join(" ".join(repr(float(x)) for x in T.reshape(-1)) + "\n" for T in np.asarray(T_world_cam))


def write_poses(path: str | Path, T_world_cam: np.ndarray) -> None:
    """Atomically write poses (N, 4, 4) in NICE-SLAM form."""
    write_text(path, format_poses(T_world_cam))


def write_tum(path: str | Path, T_world_cam: np.ndarray, timestamps=None) -> None:
    """Atomically write poses (N, 4, 4) in TUM form (quaternion x y z w)."""
    T_world_cam = np.asarray(T_world_cam)
    ts = np.arange(len(T_world_cam), dtype=np.float64) if timestamps is None else np.asarray(timestamps)
    lines = []
    for t, T in zip(ts, T_world_cam):
        q = rot_to_quat(T[:3, :3])
        lines.append(" ".join(repr(float(x)) for x in [t, *T[:3, 3], *q]) + "\n")
    write_text(path, "".join(lines))
