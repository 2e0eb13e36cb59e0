"""The component ablations of ``panovocc map``: without RPU, and the pose perturbation-and-correction schedule.

The paper's ablation (Sec. "Component Ablation") "reuses the same SLAM trajectory while introducing
predefined pose perturbations and corrections". Its schedule is not given in numbers; this is the one the
toolkit runs (seeded, documented in docs/baselines.md, "Ablations"):

* **perturbation**: a drifting copy ``D`` of the sequence's poses ``T`` (odometry-style random walk,
  :func:`drifted_poses`, seed ``drift_seed``; per-frame rotation drift ``drift_rot_deg`` and translation
  drift ``drift_trans_m`` per square-root frame);
* **correction**: the frames arrive in blocks of ``correct_every``; each frame is integrated under its
  drifted pose, re-anchored at the last correction (frame ``j`` of a block after correction point ``c``:
  ``T_c D_c^-1 D_j``, so drift restarts from the corrected pose, as after a SLAM loop closure); when a
  block's last frame has been integrated, the true poses of the block's frames arrive as revisions (the last
  block's at the end of the sequence);
* **with RPU** (default) each revision is :meth:`Mapper.revise`: the stale contribution is subtracted and
  the frame recomputed under the true pose, so the final map equals a map made with the true poses from
  the start (exactly: tests/baselines/test_ablation.py);
* **without RPU** (``--no-rpu``): the corrected frame is integrated again under its true pose, **on top of**
  the stale contribution, which stays (the copy's id is the frame's plus the number of frames).

Without drift (both drifts 0) no pose changes and the flags change nothing.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..config import DEFAULT_SEED, MAX_SEED, option, typed_from_json
from ..errors import PanovoccError


@dataclass(frozen=True)
class AblationParams:
    """Ablation switches of ``panovocc map`` (saved in ``OUT/config.json``, section ``ablation``)."""

    use_rpu: bool = option(True, flag="--no-rpu", negate=True,
                           help="Ablation: pose corrections (of the drift schedule) are added on top of the stale "
                                "contributions instead of replacing them.")
    drift_rot_deg: float = option(0.0, min=0, max=10, help="Ablation schedule: rotation drift per frame, degrees "
                                                            "(0 with --drift-trans-m 0: no perturbation).")
    drift_trans_m: float = option(0.0, min=0, max=1, help="Ablation schedule: translation drift per square-root "
                                                           "frame, metres.")
    drift_seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED, help="Ablation schedule: seed of the drift.")
    correct_every: int = option(10, min=1, help="Ablation schedule: true poses arrive as revisions after every K "
                                                "frames.")

    @property
    def perturbs(self) -> bool:
        """Whether the schedule moves any pose (a drift above 0)."""
        return self.drift_rot_deg > 0 or self.drift_trans_m > 0

    @classmethod
    def from_json(cls, d: dict | None) -> "AblationParams":
        """From a map config's ``ablation`` section (absent: the defaults, no ablation)."""
        return cls() if d is None else typed_from_json(cls, d, "ablation")


def drifted_poses(T_world_cam: np.ndarray, p: AblationParams) -> np.ndarray:
    """``D`` (n, 4, 4) float64: the seeded drifting copy of the true poses ``T_world_cam`` (n, 4, 4):
    :func:`panovocc_cli.geometry.drift.drift_trajectory` (odometry-style, ``D_0 = T_0``,
    ``D_i = D_{i-1} (T_{i-1}^-1 T_i) N_i``) with ``drift_rot_deg`` per frame, ``drift_trans_m`` per
    square-root frame, no per-metre term, seed ``drift_seed``."""
    from ..geometry.drift import drift_trajectory

    T = np.asarray(T_world_cam, np.float64)
    if len(T) < 2 or not p.perturbs:
        return T.copy()
    return drift_trajectory(T, trans_m_per_sqrt_frame=p.drift_trans_m, rot_deg_per_frame=p.drift_rot_deg,
                            seed=p.drift_seed)


class CorrectionSchedule:
    """Which pose each frame is integrated under, and when true poses arrive (module docstring).

    Parameters
    ----------
    T_true : (n, 4, 4) float64, the sequence's poses; p : AblationParams
    """

    def __init__(self, T_true: np.ndarray, p: AblationParams):
        self.T = np.asarray(T_true, np.float64)
        self.p = p
        self.n = len(self.T)
        self.D = drifted_poses(self.T, p) if p.perturbs else self.T.copy()

    def block_start(self, i: int) -> int:
        """First frame of frame ``i``'s block."""
        return (i // self.p.correct_every) * self.p.correct_every

    def integration_pose(self, i: int) -> np.ndarray:
        """(4, 4) pose frame ``i`` is first integrated under: drift since the last correction point."""
        b = self.block_start(i)
        if b == 0:
            return self.D[i].copy()
        c = b - 1  # the last frame of the previous block: corrected before frame i arrives
        return self.T[c] @ np.linalg.inv(self.D[c]) @ self.D[i]

    def corrections_after(self, i: int) -> list[int]:
        """Frames whose true pose arrives once frame ``i`` has been integrated (a whole block, or none)."""
        if not self.p.perturbs:
            return []
        if (i + 1) % self.p.correct_every == 0 or i == self.n - 1:
            return list(range(self.block_start(i), i + 1))
        return []

    def apply(self, mapper, frames, i: int) -> int:
        """Deliver the corrections due after frame ``i`` to ``mapper``; returns how many frames moved.

        With RPU: ``mapper.revise(j, T_j)``. Without: frame ``j`` (from ``frames(j)``) integrated again under
        ``T_j`` with id ``j + n``, the stale contribution kept.
        """
        moved = 0
        for j in self.corrections_after(i):
            if np.array_equal(self.T[j], mapper.pose(j)):
                continue
            if self.p.use_rpu:
                mapper.revise(j, self.T[j])
            else:
                frame = dataclasses.replace(frames(j), T_world_cam=self.T[j], index=j + self.n)
                mapper.integrate(frame)
            moved += 1
        return moved


def check_resumable(p: AblationParams, where) -> None:
    """Refuse ``--resume`` of a run with a perturbation schedule (its corrections are not checkpointed)."""
    if p.perturbs:
        raise PanovoccError("a map with a pose perturbation schedule (--drift-rot-deg / --drift-trans-m) cannot be "
                            "resumed; start it over with --overwrite", where)
