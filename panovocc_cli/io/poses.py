"""Trajectory files: NICE-SLAM ``traj.txt`` (16 floats a line, T_world_cam row-major) and TUM
(``t tx ty tz qx qy qz qw``). Foreign conventions are converted here, at the file boundary."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..config import MATCH_MAX_DIFF, MAX_POSITION_M
from ..errors import PanovoccError
from ..geometry.poses import check_rigid, clearly_rigid, quat_to_rot, rot_to_quat
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
    return read_trajectory(path)[1]


def read_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray, str]:
    """Read a trajectory with its timestamps.

    Returns
    -------
    stamps : (N,) float64
        TUM: the file's first column (seconds, or frame indices as ``write_tum`` writes them);
        NICE-SLAM: the line's position 0 .. N-1 (a frame index).
    T_world_cam : (N, 4, 4) float64, each checked rigid, camera coordinates within
        :data:`~panovocc_cli.config.MAX_POSITION_M` metres
    form : ``"tum"`` or ``"nice-slam"``

    Raises
    ------
    PanovoccError
        One line naming the file and line: not numbers, a ragged line, a bad quaternion, a pose that is not
        rigid, a coordinate beyond ``MAX_POSITION_M``, or a TUM timestamp given twice (which pose would be
        that time's?).
    """
    path = Path(path)
    rows = _rows(path)
    width = len(rows[0][1])
    if width not in (16, 8):
        raise PanovoccError(
            f"line {rows[0][0]}: {width} numbers; expected 16 (T_world_cam row-major, NICE-SLAM form) "
            "or 8 (TUM form: t tx ty tz qx qy qz qw)", path)
    poses, stamps, line_of, lines = [], [], {}, []
    try:
        _parse_rows(path, rows, width, poses, stamps, line_of, lines)
    except PanovoccError:
        _checked_poses(poses, lines, path)  # a pose before the bad line that is not rigid is named first,
        raise                               # as the lines are read in order
    return np.array(stamps, np.float64), _checked_poses(poses, lines, path), ("tum" if width == 8 else "nice-slam")


def _parse_rows(path: Path, rows, width: int, poses: list, stamps: list, line_of: dict, lines: list) -> None:
    """:func:`read_trajectory`'s lines as numbers: each line's 4x4 pose appended to ``poses`` (not checked rigid
    yet), its timestamp to ``stamps``, its line number to ``lines``; one line naming the file otherwise."""
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
            if not np.isfinite(vals[0]):
                raise PanovoccError(f"line {n}: timestamp {parts[0]} is not a finite number", path)
            if vals[0] in line_of:
                raise PanovoccError(f"line {n}: timestamp {parts[0]} repeats line {line_of[vals[0]]}; expected "
                                    "one pose per timestamp", path)
            line_of[vals[0]] = n
        stamps.append(vals[0] if width == 8 else float(len(stamps)))
        poses.append(T)
        lines.append(n)


def _checked_poses(poses: list, lines: list, path: Path) -> np.ndarray:
    """The poses (a list of (4, 4)) stacked, each checked as :func:`_checked_pose` checks it; the first that fails
    raises its error. All at once first: a pose :func:`~..geometry.poses.clearly_rigid` accepts with its camera
    within ``MAX_POSITION_M`` is not checked again one by one, the others are, in order, by :func:`_checked_pose`
    itself (the same test and message; a pose file of 7,661 lines was 0.21 s of checks one by one)."""
    if not poses:
        return np.zeros((0, 4, 4), np.float64)
    T = np.stack(poses).astype(np.float64, copy=False)
    with np.errstate(invalid="ignore"):
        clear = clearly_rigid(T) & (np.abs(T[:, :3, 3]).max(axis=1) <= MAX_POSITION_M)
    for i in np.flatnonzero(~clear):
        T[i] = _checked_pose(T[i], path, f"line {lines[i]}")
    return T


def _checked_pose(T: np.ndarray, path: Path, where: str) -> np.ndarray:
    """``T`` (4, 4) checked rigid, its camera within :data:`~panovocc_cli.config.MAX_POSITION_M` metres of the
    origin; one line naming the file and ``where`` (``line 3``) otherwise."""
    T = check_rigid(T, what=f"{path}: {where}")
    if np.abs(T[:3, 3]).max() > MAX_POSITION_M:
        raise PanovoccError(f"{where}: camera position {T[:3, 3].tolist()} m is beyond {MAX_POSITION_M:g} m "
                            "of the origin (expected metres)", path)
    return T


def read_first_pose(path: str | Path, stamp: float = 0.0, max_diff: float | None = None) -> np.ndarray:
    """The pose of a sequence's first frame from a file (``map --poses slam --first-pose FILE``).

    Accepted forms: a 4x4 matrix (4 lines of 4 numbers, T_world_cam row-major); a NICE-SLAM file (its first
    line is frame 0; further lines are ignored, so a sequence's ``poses.txt`` will do); a TUM file, whose pose
    with the timestamp nearest ``stamp`` (frame 0's, by default the frame index 0) within ``max_diff``
    (default :data:`~panovocc_cli.config.MATCH_MAX_DIFF`) is used, as :func:`frame_poses` matches frames.

    Returns
    -------
    T_world_cam : (4, 4) float64, checked rigid, the camera within ``MAX_POSITION_M`` metres of the origin

    Raises
    ------
    PanovoccError
        One line naming the file: missing, empty, not one of the forms, a pose that is not rigid, no TUM
        pose near ``stamp``.
    """
    path = Path(path)
    rows = _rows(path)
    width = len(rows[0][1])
    if width == 4:
        return _matrix(path, rows)
    if width not in (16, 8):
        raise PanovoccError(f"line {rows[0][0]}: {width} numbers; expected a 4x4 matrix (4 lines of 4 numbers), "
                            "16 numbers a line (NICE-SLAM form) or 8 (TUM form: t tx ty tz qx qy qz qw)", path)
    t, T, form = read_trajectory(path)
    if form == "nice-slam":
        return T[0]
    max_diff = MATCH_MAX_DIFF if max_diff is None else max_diff
    ia, ib = match_timestamps(np.array([stamp], np.float64), t, max_diff)
    if len(ib) == 0:
        raise PanovoccError(f"no pose within {max_diff} of the first frame's timestamp {stamp:g} (TUM timestamps "
                            f"{t.min():.6g} .. {t.max():.6g}; frame i has timestamp i)", path)
    return T[int(ib[0])]


def read_transform(path: str | Path) -> np.ndarray:
    """A rigid transform from a file of a 4x4 matrix (4 lines of 4 numbers, row-major): ``merge --transform``.
    One line naming the file otherwise (missing, not 4x4, not rigid)."""
    path = Path(path)
    return _matrix(path, _rows(path))


def _matrix(path: Path, rows) -> np.ndarray:
    """A file's rows as one rigid 4x4 matrix (4 lines of 4 numbers, row-major), checked."""
    if len(rows) != 4 or any(len(parts) != 4 for _, parts in rows):
        raise PanovoccError(f"a 4x4 matrix: {len(rows)} lines of {[len(p) for _, p in rows]} numbers; expected "
                            "4 lines of 4 numbers (T_world_cam row-major)", path)
    return _checked_pose(np.stack([_floats(path, n, parts) for n, parts in rows]), path, "4x4 matrix")


def frame_poses(path: str | Path, n_frames: int, stamps=None, max_diff: float | None = None) -> np.ndarray:
    """One pose per frame of a sequence from a trajectory file, timestamps matched to frames.

    A NICE-SLAM file must hold exactly ``n_frames`` poses (line ``i`` = frame ``i``). A TUM file's
    timestamps are matched to the frames' (``stamps``, default the frame indices 0 .. n-1, as
    ``write_tum`` writes them) by nearest time within ``max_diff`` (default
    :data:`panovocc_cli.config.MATCH_MAX_DIFF`); extra poses are ignored, and a frame
    without a pose is an error listing the first such frames. A TUM file whose stamps match no frame at
    all (clock seconds) is refused, even with one pose per frame: which pose is which frame is never guessed.

    Returns
    -------
    T_world_cam : (n_frames, 4, 4) float64
    """
    path = Path(path)
    t, T, form = read_trajectory(path)
    if form == "nice-slam":
        if len(T) != n_frames:
            raise PanovoccError(f"{len(T)} poses for {n_frames} frames (NICE-SLAM form: one line a frame)", path)
        return T
    frame_t = np.arange(n_frames, dtype=np.float64) if stamps is None else np.asarray(stamps, np.float64)
    ia, ib = match_timestamps(frame_t, t, MATCH_MAX_DIFF if max_diff is None else max_diff)
    max_diff = MATCH_MAX_DIFF if max_diff is None else max_diff
    if len(ia) == 0 and n_frames:
        what = "frame indices 0..N-1" if stamps is None else "frame timestamps"
        raise PanovoccError(f"TUM timestamps ({t.min():.6g} .. {t.max():.6g}) match none of the {what}: no pose "
                            f"within {max_diff} of any (clock times?); write the trajectory with the frames' "
                            "timestamps, or in NICE-SLAM form (one line a frame)", path)
    if len(ia) < n_frames:
        missing = sorted(set(range(n_frames)) - set(ia.tolist()))
        shown = ", ".join(map(str, missing[:8])) + (", ..." if len(missing) > 8 else "")
        raise PanovoccError(f"no pose within {max_diff} of the timestamps "
                            f"of {len(missing)} of {n_frames} frames ({shown}); TUM timestamps are matched to "
                            "frame indices 0..N-1", path)
    out = np.empty((n_frames, 4, 4))
    out[ia] = T[ib]
    return out


def format_poses(T_world_cam: np.ndarray) -> str:
    """NICE-SLAM text: one line of 16 numbers a pose (row-major, full float64 precision)."""
    return "".join(" ".join(repr(float(x)) for x in T.reshape(-1)) + "\n" for T in np.asarray(T_world_cam))


def write_poses(path: str | Path, T_world_cam: np.ndarray) -> None:
    """Atomically write poses (N, 4, 4) in NICE-SLAM form."""
    write_text(path, format_poses(T_world_cam))


def write_tum(path: str | Path, T_world_cam: np.ndarray, timestamps=None) -> None:
    """Atomically write poses (N, 4, 4) in TUM form (quaternion x y z w)."""
    write_text(path, format_tum(T_world_cam, timestamps))


def format_tum(T_world_cam: np.ndarray, timestamps=None) -> str:
    """TUM text: one line ``t tx ty tz qx qy qz qw`` a pose (N, 4, 4); timestamps default to 0 .. N-1."""
    T_world_cam = np.asarray(T_world_cam)
    ts = np.arange(len(T_world_cam), dtype=np.float64) if timestamps is None else np.asarray(timestamps)
    lines = []
    for t, T in zip(ts, T_world_cam):
        q = rot_to_quat(T[:3, :3])
        lines.append(" ".join(repr(float(x)) for x in [t, *T[:3, 3], *q]) + "\n")
    return "".join(lines)


def match_timestamps(stamps_a, stamps_b, max_diff: float = MATCH_MAX_DIFF) -> tuple[np.ndarray, np.ndarray]:
    """Indices of matched timestamps: each of ``stamps_a`` paired with the nearest of ``stamps_b`` within
    ``max_diff`` (evo's ``matching_time_indices``: a tie goes to the earlier stamp; unmatched are dropped).

    Parameters
    ----------
    stamps_a, stamps_b : (n,), (m,) float, seconds (or frame indices)

    Returns
    -------
    ia, ib : (k,) int64 indices into ``stamps_a`` and ``stamps_b``
    """
    a = np.asarray(stamps_a, np.float64)
    b = np.asarray(stamps_b, np.float64)
    if b.size == 0 or a.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not np.all(np.diff(b) >= 0):
        order = np.argsort(b, kind="stable")
        ia, ib = match_timestamps(a, b[order], max_diff)
        return ia, order[ib]
    j = np.clip(np.searchsorted(b, a, side="right"), 0, len(b) - 1)
    ub = b[j] - a
    lb = np.where(j > 0, a - b[np.maximum(j - 1, 0)], np.inf)
    take_ub = (ub <= max_diff) & (ub < lb)
    take_lb = ~take_ub & (lb <= max_diff) & (lb <= ub)
    ok = (take_ub | take_lb) & (a >= b[0] - max_diff) & (a <= b[-1] + max_diff)
    ib = np.where(take_ub, j, j - 1)
    return np.nonzero(ok)[0].astype(np.int64), ib[ok].astype(np.int64)
