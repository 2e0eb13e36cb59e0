"""Trajectory accuracy: Umeyama alignment, absolute trajectory error (ATE) and relative pose error (RPE).

The numbers are those evo 1.38.1 computes (``evo_ape`` / ``evo_rpe`` with the translation part, and the
rotation angle in degrees), so results can be compared with published tables; the tests check them
against evo's own Python API.

* Alignment (:func:`umeyama`, :func:`align_trajectory`): the estimated positions are mapped onto the
  reference ones by the least-squares rigid (``se3``) or similarity (``sim3``) transform of Umeyama
  (1991); ``none`` leaves them. As in evo, a Sim(3) alignment scales the estimate's translations and
  then applies the rigid part: ``T_aligned_i = [R | t] · [R_i | s t_i]``.
* Placement (:func:`fit_poses`, ``se3-pose``; not evo's): the rigid motion fitted to whole poses, the
  orientations as well as the positions, each weighted by its scatter about the fit. What places a map by a
  reference trajectory with independent per-frame noise (``map --poses-align se3-pose``): a rotation
  fitted to positions alone is only as good as σ_t / (the trajectory's extent · √n), which on a room-sized
  path is several times what the orientations give (σ_r / √n).
* ATE (:func:`ate_errors`): ``‖t_est_i − t_ref_i‖`` after alignment, metres.
* RPE (:func:`rpe_errors`): for pairs ``(i, i + delta)`` of consecutive frames, the error pose
  ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` (Q reference, P estimate); its translation norm in metres and its
  rotation angle in degrees.
* Statistics (:func:`error_stats`): rmse, mean, median, std (population), min, max, sse.

All poses are ``T_world_cam`` (n, 4, 4) float64. Maths only: no files, no printing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import PanovoccError

ALIGNMENTS = ("se3", "sim3", "none")
"""Alignment of an estimated trajectory to its reference before ATE."""
POSE_FIT = "se3-pose"
"""The rigid fit of whole poses (:func:`fit_poses`): a placement, not one of evo's alignments."""
PLACEMENTS = ("none", "se3", POSE_FIT, "sim3")
"""How ``map --poses-align`` moves a pose file (or the front end's poses) onto a reference trajectory."""
#: Floors of the fitted scatter (metres, radians): two trajectories that agree exactly still weigh both parts.
_FIT_FLOOR_T, _FIT_FLOOR_R = 1e-6, 1e-6


def umeyama(src, dst, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares similarity ``dst ≈ s R src + t`` (Umeyama 1991; evo's ``umeyama_alignment``).

    Parameters
    ----------
    src, dst : (n, 3) float, metres
        Corresponding points (estimated and reference positions).
    with_scale : bool
        Estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Returns
    -------
    R : (3, 3) float64, rotation; t : (3,) float64, metres; s : float

    Raises
    ------
    PanovoccError
        When the points are too few or degenerate (all on a line or a point): no unique rotation.
    """
    x = np.asarray(src, np.float64)
    y = np.asarray(dst, np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise PanovoccError(f"alignment: expected two (n, 3) point sets, got {x.shape} and {y.shape}")
    n = x.shape[0]
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    var_x = float(np.sum(xc * xc)) / n
    cov = yc.T @ xc / n
    U, d, Vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < 2:
        raise PanovoccError(f"alignment: the {n} positions are degenerate (on one line or one point); "
                            "use --align none or a trajectory that turns")
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    s = float(np.trace(np.diag(d) @ S) / var_x) if with_scale else 1.0
    t = my - s * R @ mx
    return R, t, s


def _nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation R maximising ``trace(R^T M)`` (Kabsch), (3, 3) float64."""
    U, _, Vt = np.linalg.svd(M)
    S = np.eye(3)
    S[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ S @ Vt


def fit_poses(T_est, T_ref, iterations: int = 5) -> tuple[np.ndarray, np.ndarray, dict]:
    """The rigid motion ``[R | t]`` with ``T_ref_i ≈ [R | t] · T_est_i``, fitted to whole poses.

    Maximum likelihood under independent per-frame noise, isotropic in position (σ_t an axis) and in
    rotation (σ_r an axis): ``R`` maximises ``trace(R^T M)``,
    ``M = Σ q'_i p'_i^T / σ_t² + Σ R_ref_i R_est_i^T / (2 σ_r²)`` (p', q' the positions about their means; the
    second sum is ``‖R R_est_i − R_ref_i‖_F² ≈ 2 θ_i²`` expanded), and ``t = q̄ − R p̄``. σ_t and σ_r are not
    known: the fit starts from the positions alone (Umeyama's rotation; from the orientations alone where the
    positions do not fix one and Umeyama refuses them, a camera that stands still or moves along a line) and
    refits with both weighted by its residuals' scatter, ``iterations`` passes in all (σ_t² = Σ‖e_i‖² / 3n,
    σ_r² = Σ θ_i² / 3n, floored at 1 µm and 1 µrad). So orientations that disagree with the positions by more
    than their noise (a reference that holds positions only, its orientations all equal) weigh next to nothing,
    and the fit is Umeyama's; where the positions fix no rotation, the reference's orientations must be the same
    camera's as the estimate's.

    Returns
    -------
    R : (3, 3) float64; t : (3,) float64, metres; info : {"sigma_t_m", "sigma_r_deg"}, the last residual scatter
    """
    T_est, T_ref = _pair(T_est, T_ref)
    n = len(T_est)
    p, q = T_est[:, :3, 3], T_ref[:, :3, 3]
    c_pos = (q - q.mean(0)).T @ (p - p.mean(0))
    c_rot = np.einsum("nij,nkj->ik", T_ref[:, :3, :3], T_est[:, :3, :3])

    def scatter(R):  # the translation that goes with R, and the residuals' variance an axis
        t = q.mean(0) - R @ p.mean(0)
        e = p @ R.T + t - q
        theta = rotation_angle(R @ T_est[:, :3, :3] @ np.swapaxes(T_ref[:, :3, :3], 1, 2))
        return (t, max(float(np.sum(e * e)) / (3 * n), _FIT_FLOOR_T ** 2),
                max(float(np.sum(theta * theta)) / (3 * n), _FIT_FLOOR_R ** 2))

    try:
        R = umeyama(p, q)[0]
    except PanovoccError:  # the positions fix no rotation (Umeyama refuses them): start from the orientations
        R = _nearest_rotation(c_rot)
    for _ in range(max(int(iterations), 1) - 1):
        _, var_t, var_r = scatter(R)
        R = _nearest_rotation(c_pos / var_t + c_rot / (2.0 * var_r))
    t, var_t, var_r = scatter(R)
    return R, t, {"sigma_t_m": float(np.sqrt(var_t)), "sigma_r_deg": float(np.degrees(np.sqrt(var_r)))}


def apply_sim3(T_world_cam, R, t, s: float = 1.0) -> np.ndarray:
    """Poses (n, 4, 4) moved by the similarity ``(R, t, s)``: ``[R | t] · [R_i | s t_i]`` (float64)."""
    T = np.array(T_world_cam, np.float64, copy=True)
    T[:, :3, 3] *= s
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = R, t
    return A @ T


def align_trajectory(T_est, T_ref, mode: str = "se3") -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Align an estimated trajectory to a reference of the same length.

    Parameters
    ----------
    T_est, T_ref : (n, 4, 4) float, T_world_cam
    mode : ``se3`` | ``sim3`` | ``none`` | ``se3-pose`` (:func:`fit_poses`: whole poses, not positions alone)

    Returns
    -------
    T_aligned : (n, 4, 4) float64; R : (3, 3); t : (3,) metres; s : float (1 unless sim3)
    """
    T_est, T_ref = _pair(T_est, T_ref)
    if mode not in PLACEMENTS:
        raise PanovoccError(f"alignment must be one of {', '.join(PLACEMENTS)}, got {mode!r}")
    if mode == "none":
        return T_est.copy(), np.eye(3), np.zeros(3), 1.0
    if mode == POSE_FIT:
        R, t, _ = fit_poses(T_est, T_ref)
        return apply_sim3(T_est, R, t), R, t, 1.0
    R, t, s = umeyama(T_est[:, :3, 3], T_ref[:, :3, 3], with_scale=mode == "sim3")
    return apply_sim3(T_est, R, t, s), R, t, s


def _pair(T_est, T_ref) -> tuple[np.ndarray, np.ndarray]:
    T_est = np.asarray(T_est, np.float64)
    T_ref = np.asarray(T_ref, np.float64)
    for T, what in ((T_est, "estimate"), (T_ref, "reference")):
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise PanovoccError(f"trajectory {what}: expected (n, 4, 4) poses, got shape {T.shape}")
    if len(T_est) != len(T_ref):
        raise PanovoccError(f"trajectories have {len(T_est)} and {len(T_ref)} poses; match them first")
    if len(T_est) == 0:
        raise PanovoccError("trajectories are empty (no matched poses)")
    return T_est, T_ref


def ate_errors(T_est, T_ref) -> np.ndarray:
    """(n,) float64 metres: position error of each (already aligned) pose."""
    T_est, T_ref = _pair(T_est, T_ref)
    return np.linalg.norm(T_est[:, :3, 3] - T_ref[:, :3, 3], axis=1)


def rotation_angle(R) -> np.ndarray:
    """(...,) float64 radians in [0, π]: the angle of rotations (..., 3, 3)."""
    R = np.asarray(R, np.float64)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.arctan2(np.linalg.norm(w, axis=-1) / 2.0, c)


def rpe_errors(T_est, T_ref, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors over pairs ``(i, i + delta)``, ``i = 0, delta, 2 delta, ...`` (evo's consecutive pairs).

    Returns
    -------
    trans_m : (m,) float64, metres; rot_deg : (m,) float64, degrees
    """
    T_est, T_ref = _pair(T_est, T_ref)
    if int(delta) < 1:
        raise PanovoccError(f"RPE delta must be >= 1 frame, got {delta}")
    i = np.arange(0, len(T_est) - delta, delta)
    j = i + delta
    Q = np.linalg.inv(T_ref[i]) @ T_ref[j]
    P = np.linalg.inv(T_est[i]) @ T_est[j]
    E = np.linalg.inv(Q) @ P
    return np.linalg.norm(E[:, :3, 3], axis=1), np.rad2deg(rotation_angle(E[:, :3, :3]))


def error_stats(err) -> dict:
    """evo's statistics of an error array: rmse, mean, median, std, min, max, sse (NaN when empty)."""
    e = np.asarray(err, np.float64)
    if e.size == 0:
        return {k: float("nan") for k in ("rmse", "mean", "median", "std", "min", "max")} | {"sse": 0.0}
    return {"rmse": float(np.sqrt(np.mean(e * e))), "mean": float(np.mean(e)), "median": float(np.median(e)),
            "std": float(np.std(e)), "min": float(np.min(e)), "max": float(np.max(e)), "sse": float(np.sum(e * e))}


@dataclass
class TrajectoryResult:
    """The accuracy of one estimated trajectory (evo's ``Result`` in spirit: data, not text).

    Attributes
    ----------
    align : str, the alignment used; rotation (3, 3), translation (3,) metres, scale : the alignment
    pairs : int, matched poses compared
    ate : dict of error_stats, metres; rpe_trans : dict, metres; rpe_rot_deg : dict, degrees
    rpe_delta : int, frames between the poses of an RPE pair
    ate_errors : (pairs,) float64 metres; T_est_aligned : (pairs, 4, 4) float64
    """

    align: str
    rotation: np.ndarray
    translation: np.ndarray
    scale: float
    pairs: int
    ate: dict
    rpe_trans: dict
    rpe_rot_deg: dict
    rpe_delta: int
    ate_errors: np.ndarray = field(repr=False)
    T_est_aligned: np.ndarray = field(repr=False)

    def summary(self) -> dict:
        """JSON-ready numbers (no arrays)."""
        return {"align": self.align, "pairs": self.pairs, "scale": self.scale,
                "rotation": self.rotation.tolist(), "translation_m": self.translation.tolist(),
                "ate_m": self.ate, "rpe_m": self.rpe_trans, "rpe_deg": self.rpe_rot_deg, "rpe_delta": self.rpe_delta}


def evaluate_trajectory(T_est, T_ref, align: str = "se3", delta: int = 1) -> TrajectoryResult:
    """ATE after alignment and RPE of an estimate against a reference with matched poses.

    Parameters
    ----------
    T_est, T_ref : (n, 4, 4) float, T_world_cam, pose ``i`` of each at the same time
    align : ``se3`` | ``sim3`` | ``none``
    delta : frames between the poses of an RPE pair

    RPE is computed on the aligned estimate (a Sim(3) alignment rescales relative motions too).
    """
    T_al, R, t, s = align_trajectory(T_est, T_ref, align)
    e = ate_errors(T_al, T_ref)
    rt, rr = rpe_errors(T_al, T_ref, delta)
    return TrajectoryResult(align=align, rotation=R, translation=t, scale=s, pairs=len(e), ate=error_stats(e),
                            rpe_trans=error_stats(rt), rpe_rot_deg=error_stats(rr), rpe_delta=int(delta),
                            ate_errors=e, T_est_aligned=T_al)
