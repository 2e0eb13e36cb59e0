"""``run_traj_eval`` and ``run_traj_perturb``: the trajectory commands' runners (read files, call the maths
of :mod:`.trajectory` and :mod:`panovocc_cli.geometry.drift`, write results).

``panovocc traj eval EST GT``: the poses of both files are matched by timestamp (evo's nearest-time
association: each pose of the file with fewer poses is paired with the nearest of the other within
``--max-diff``), the estimate is aligned (``--align se3 | sim3 | none``) and its ATE and RPE computed as
evo does. ``--plot PNG`` draws both trajectories from above (x-y plane, world +Z up); ``--json FILE``
writes :meth:`TrajectoryResult.summary`. NICE-SLAM files count their lines as timestamps 0, 1, 2, ... (a
frame index, as ``write_tum`` writes TUM stamps), so the two forms can be mixed.

``panovocc traj perturb GT OUT``: a seeded perturbed copy of GT: drift accumulated along the path
(:func:`~panovocc_cli.geometry.drift.drift_trajectory`), then independent per-frame jitter
(:func:`~panovocc_cli.geometry.drift.jitter_trajectory`), written as TUM when OUT ends in ``.tum`` (GT's
timestamps kept), else in NICE-SLAM form.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import DEFAULT_SEED, MATCH_MAX_DIFF, MAX_SEED, option, validate_config
from ..errors import PanovoccError, printable
from .trajectory import ALIGNMENTS, TrajectoryResult, evaluate_trajectory


@dataclass
class TrajEvalConfig:
    """``panovocc traj eval``: accuracy of an estimated trajectory against a reference."""

    est: str = option(cli_type=Path, parse=str, argument=True, metavar="EST",
                      help="Estimated trajectory (TUM or NICE-SLAM form).")
    gt: str = option(cli_type=Path, parse=str, argument=True, metavar="GT",
                     help="Reference (ground-truth) trajectory (TUM or NICE-SLAM form).")
    align: str = option("se3", choices=ALIGNMENTS, help="Alignment before ATE: se3 (rigid Umeyama) | sim3 "
                                                        "(with scale) | none.")
    delta: int = option(1, min=1, help="RPE: frames between the two poses of a pair.")
    max_diff: float = option(MATCH_MAX_DIFF, min=0, help="Largest timestamp difference of matched poses "
                                                        "(seconds, or frames for NICE-SLAM files).")
    plot: str | None = option(None, cli_type=Path, parse=str, help="Write a top view of both trajectories "
                                                                    "(PNG; metres, x-y plane).")
    json_path: str | None = option(None, cli_type=Path, parse=str, flag="--json",
                                   help="Write the numbers as JSON to this file.")


def _parse_offset(text: str) -> tuple[float, float, float]:
    """``--offset X,Y,Z`` (``datasets.synth.parse_offset``, imported when an offset is given)."""
    from ..datasets.synth import parse_offset

    return parse_offset(text)


@dataclass
class TrajPerturbConfig:
    """``panovocc traj perturb``: a seeded perturbed copy of a trajectory (geometry/drift.py's models): drift
    along the path, then per-frame jitter, then a rigid offset of every position."""

    gt: str = option(cli_type=Path, parse=str, argument=True, metavar="GT",
                     help="Trajectory to perturb (TUM or NICE-SLAM form).")
    out: str = option(cli_type=Path, parse=str, argument=True, metavar="OUT",
                      help="Output trajectory: TUM when it ends in .tum, else NICE-SLAM form.")
    drift: float = option(0.0, min=0, max=100, help="Translation random walk: std per axis of each step's error, "
                                          "metres per sqrt(frame).")
    drift_per_m: float = option(0.0, min=0, max=100, help="Translation error per metre travelled: std per axis of "
                                                "each step's error / step length (0.01 = 1 %).")
    rot_drift_deg: float = option(0.0, min=0, max=180, help="Rotation random walk: std per axis of each step's "
                                                  "rotation error, degrees per frame.")
    jitter: float = option(0.0, min=0, max=100, help="Per-frame translation jitter: std per camera axis of each "
                                                     "frame's own error, metres (not accumulated).")
    rot_jitter_deg: float = option(0.0, min=0, max=180, help="Per-frame rotation jitter: std per camera axis of "
                                                             "each frame's own rotation error, degrees.")
    seed: int = option(DEFAULT_SEED, min=0, max=MAX_SEED,
                       help="Seed of the drift and the jitter; the same seed gives the same file.")
    offset: tuple[float, float, float] | None = option(
        None, cli_type=str, parse=_parse_offset, metavar="X,Y,Z",
        help="X,Y,Z metres added to every camera position after the drift and the jitter: the whole trajectory "
             "moved rigidly (where a map of it sits against the voxel lattice).")



def associate(stamps_est, stamps_ref, max_diff: float) -> tuple[np.ndarray, np.ndarray]:
    """evo's association of two trajectories: index pairs (est, ref), matched from the shorter one."""
    from ..io.poses import match_timestamps

    if len(stamps_ref) > len(stamps_est):
        ie, ir = match_timestamps(stamps_est, stamps_ref, max_diff)
    else:
        ir, ie = match_timestamps(stamps_ref, stamps_est, max_diff)
    return ie, ir


def evaluate_files(est: str | Path, gt: str | Path, align: str = "se3", delta: int = 1,
                   max_diff: float = MATCH_MAX_DIFF) -> tuple[TrajectoryResult, np.ndarray]:
    """Read, match and evaluate two trajectory files; returns (result, matched reference poses)."""
    from ..io.poses import read_trajectory

    te, Te, _ = read_trajectory(est)
    tr, Tr, _ = read_trajectory(gt)
    ie, ir = associate(te, tr, max_diff)
    if len(ie) < 3 and align != "none":
        raise PanovoccError(f"only {len(ie)} poses match {gt} within {max_diff} (an alignment needs 3 or more)", est)
    if len(ie) <= delta:
        raise PanovoccError(f"only {len(ie)} poses match {gt} within {max_diff}; RPE needs more than "
                            f"{delta}", est)
    return evaluate_trajectory(Te[ie], Tr[ir], align=align, delta=delta), Tr[ir]


def trajectory_figure(T_ref: np.ndarray, T_est_aligned: np.ndarray, title: str):
    """A matplotlib Figure: both trajectories from above (x-y, metres), the reference dashed."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(T_ref[:, 0, 3], T_ref[:, 1, 3], "--", color="0.3", lw=1.5, label="reference")
    ax.plot(T_est_aligned[:, 0, 3], T_est_aligned[:, 1, 3], "-", color="tab:blue", lw=1.5, label="estimate (aligned)")
    ax.plot(T_ref[:1, 0, 3], T_ref[:1, 1, 3], "o", color="0.3", ms=5, label="start")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(printable(title), fontsize=9)
    fig.tight_layout()
    return fig


def run_traj_eval(cfg: TrajEvalConfig, overwrite: bool = False) -> TrajectoryResult:
    """Evaluate ``cfg.est`` against ``cfg.gt``; write ``cfg.plot`` (+ its config) and ``cfg.json_path`` if asked."""
    from ..io.atomic import check_outputs, write_text
    from ..io.runconfig import check_file_output, write_run_config

    cfg = validate_config(cfg)
    scores = [(cfg.json_path, "trajectory scores", False)]
    if cfg.plot is not None:  # the figure, its config beside, the scores: three outputs at three paths
        config_path = check_file_output(cfg.plot, "trajectory figure", overwrite, inputs=(cfg.est, cfg.gt), also=scores)
    else:
        check_outputs(scores, overwrite, inputs=(cfg.est, cfg.gt))
    res, T_ref = evaluate_files(cfg.est, cfg.gt, cfg.align, cfg.delta, cfg.max_diff)
    if cfg.json_path is not None:
        d = {"est": cfg.est, "gt": cfg.gt} | res.summary()
        write_text(cfg.json_path, json.dumps(d, indent=2) + "\n")
    if cfg.plot is not None:
        from ..io.figures import write_png

        title = (f"{Path(cfg.est).name} vs {Path(cfg.gt).name}: ATE RMSE {res.ate['rmse']:.3f} m "
                 f"({cfg.align}), RPE {res.rpe_trans['rmse']:.3f} m / {res.rpe_rot_deg['rmse']:.2f} deg")
        write_png(trajectory_figure(T_ref, res.T_est_aligned, title), cfg.plot)
        write_run_config(config_path, cfg)
    return res


def run_traj_perturb(cfg: TrajPerturbConfig, overwrite: bool = False) -> dict:
    """Write a perturbed copy of ``cfg.gt`` (drift, then jitter) to ``cfg.out`` and its config beside
    (``OUT.config.json``)."""
    from ..geometry.drift import drift_trajectory, jitter_trajectory
    from ..io.poses import read_trajectory, write_poses, write_tum
    from ..io.runconfig import check_file_output, write_run_config

    cfg = validate_config(cfg)
    config_path = check_file_output(cfg.out, "trajectory", overwrite, inputs=(cfg.gt,))
    t, T, _ = read_trajectory(cfg.gt)
    D = drift_trajectory(T, trans_m_per_sqrt_frame=cfg.drift, trans_m_per_m=cfg.drift_per_m,
                         rot_deg_per_frame=cfg.rot_drift_deg, seed=cfg.seed)
    D = jitter_trajectory(D, trans_m=cfg.jitter, rot_deg=cfg.rot_jitter_deg, seed=cfg.seed)
    if cfg.offset is not None:
        D[:, :3, 3] += np.asarray(cfg.offset, np.float64)
    if str(cfg.out).lower().endswith(".tum"):
        write_tum(cfg.out, D, timestamps=t)
    else:
        write_poses(cfg.out, D)
    write_run_config(config_path, cfg)
    end = float(np.linalg.norm(D[-1, :3, 3] - T[-1, :3, 3]))
    return {"poses": len(D), "end_error_m": end, "out": str(cfg.out)}
