"""Seeded pose errors: odometry-style random-walk drift accumulated along true poses, and per-frame jitter.

The drifted trajectory re-chains the true relative motions with a small random rigid error after each
one, exactly as dead-reckoning odometry accumulates error::

    T'_0 = T_0
    T'_i = T'_{i-1} · (T_{i-1}⁻¹ T_i) · N_i          i = 1 … n−1

``N_i = [Exp(ω_i) | τ_i]`` is expressed in camera ``i``'s frame. Each axis of ``ω_i`` (radians) is
normal with standard deviation ``rot_deg_per_frame`` (converted to radians); each axis of ``τ_i``
(metres) is normal with standard deviation ``sqrt(trans_m_per_sqrt_frame² + (trans_m_per_m · d_i)²)``,
where ``d_i = ‖t(T_{i-1}⁻¹ T_i)‖`` is the distance the true camera moved in step ``i``. So on a
trajectory without rotation the position error after ``n`` steps has standard deviation
``trans_m_per_sqrt_frame · √n`` per axis (a random walk), plus a part proportional to the length of
each step (the relative-error model of odometry); rotation errors also swing later positions about
the pose where they arose (the lever arm), as real drift does.

The random numbers are drawn once, all together, from ``numpy.random.default_rng(seed)`` as an
``(n − 1, 6)`` array of standard normals and then scaled: the same seed gives the same bytes, and at
the same seed a larger drift is the same drift, scaled (what an ablation over drift levels wants).

**Jitter** (:func:`jitter_trajectory`) is the other kind of pose error: independent per frame, not
accumulated, what a good front end leaves after its loop closures and refinement (a few millimetres and
hundredths of a degree around the truth)::

    T''_i = T_i · J_i          i = 0 … n−1

``J_i = [Exp(ω_i) | τ_i]`` in camera ``i``'s frame (the rotation turns the camera about its own centre),
each axis of ``ω_i`` normal with standard deviation ``rot_deg`` and each axis of ``τ_i`` normal with
standard deviation ``trans_m``. Its normals come from their own stream, ``default_rng([seed, 1])``, drawn
at once as an ``(n, 6)`` array: jitter and drift of one seed are independent, adding jitter leaves the
drift's numbers as they were, and at one seed a larger jitter is the same jitter, scaled.
"""

from __future__ import annotations

import numpy as np

from ..errors import PanovoccError


def so3_exp(omega) -> np.ndarray:
    """Rotation matrices of axis-angle vectors (Rodrigues' formula).

    Parameters
    ----------
    omega : (..., 3) float
        Rotation vectors, radians (direction = axis, norm = angle).

    Returns
    -------
    R : (..., 3, 3) float64
        Rotations; the identity where ``omega`` is zero.
    """
    w = np.asarray(omega, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -w[..., 2], w[..., 1]
    K[..., 1, 0], K[..., 1, 2] = w[..., 2], -w[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -w[..., 1], w[..., 0]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


def _check_poses(T_world_cam, what: str) -> np.ndarray:
    """``T_world_cam`` as (n, 4, 4) float64 with n >= 1 and finite entries (PanovoccError naming ``what``)."""
    T = np.asarray(T_world_cam, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] == 0:
        raise PanovoccError(f"{what}: expected (n, 4, 4) poses with n >= 1, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise PanovoccError(f"{what}: poses contain NaN or infinite values")
    return T


def _check_sigmas(what: str, **sigmas) -> None:
    for name, v in sigmas.items():
        if not np.isfinite(v) or v < 0:
            raise PanovoccError(f"{what}: {name} must be a finite number >= 0, got {v}")


def drift_trajectory(
    T_world_cam,
    *,
    trans_m_per_sqrt_frame: float = 0.0,
    trans_m_per_m: float = 0.0,
    rot_deg_per_frame: float = 0.0,
    seed: int = 0,
) -> np.ndarray:
    """A drifting copy of a trajectory (the module docstring gives the model).

    Parameters
    ----------
    T_world_cam : (n, 4, 4) float
        True camera-to-world poses, in frame order (world +Z up, OpenCV camera axes).
    trans_m_per_sqrt_frame : float, metres per √frame, >= 0
        Standard deviation, per axis, of each step's translation error independent of motion.
    trans_m_per_m : float, metres per metre travelled, >= 0
        Standard deviation, per axis, of each step's translation error per metre the true camera
        moved in that step (0.01 = 1 % of the step length).
    rot_deg_per_frame : float, degrees, >= 0
        Standard deviation, per axis, of each step's rotation error (a random walk: after ``n``
        frames the heading error has standard deviation ``rot_deg_per_frame · √n``).
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    T_world_cam_drift : (n, 4, 4) float64
        Drifted poses; the first equals the first true pose, and all are rigid. With all three
        drifts 0 the true poses come back unchanged (as float64).

    Raises
    ------
    PanovoccError
        When ``T_world_cam`` is not an (n, 4, 4) array of finite numbers, or a drift is negative or
        not finite.
    """
    T = _check_poses(T_world_cam, "drift")
    _check_sigmas("drift", trans_m_per_sqrt_frame=trans_m_per_sqrt_frame, trans_m_per_m=trans_m_per_m,
                  rot_deg_per_frame=rot_deg_per_frame)
    n = T.shape[0]
    out = T.copy()
    if n == 1 or trans_m_per_sqrt_frame == trans_m_per_m == rot_deg_per_frame == 0:
        return out
    z = np.random.default_rng(seed).standard_normal((n - 1, 6))
    rel = np.linalg.inv(T[:-1]) @ T[1:]                       # (n-1, 4, 4) true steps
    step_m = np.linalg.norm(rel[:, :3, 3], axis=1)
    sigma_t = np.sqrt(trans_m_per_sqrt_frame**2 + (trans_m_per_m * step_m) ** 2)
    N = np.tile(np.eye(4), (n - 1, 1, 1))
    N[:, :3, :3] = so3_exp(z[:, :3] * np.deg2rad(rot_deg_per_frame))
    N[:, :3, 3] = z[:, 3:] * sigma_t[:, None]
    for i in range(1, n):
        step = rel[i - 1] @ N[i - 1]
        out[i] = out[i - 1] @ step
        # re-orthonormalise so thousands of products stay rigid to 1e-12
        U, _, Vt = np.linalg.svd(out[i, :3, :3])
        out[i, :3, :3] = U @ Vt
    return out


def jitter_trajectory(T_world_cam, *, trans_m: float = 0.0, rot_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """A copy of a trajectory with independent per-frame pose errors (the module docstring gives the model).

    Parameters
    ----------
    T_world_cam : (n, 4, 4) float
        Camera-to-world poses, in frame order.
    trans_m : float, metres, >= 0
        Standard deviation, per camera axis, of each frame's translation error.
    rot_deg : float, degrees, >= 0
        Standard deviation, per camera axis, of each frame's rotation error (about the camera centre).
    seed : int
        Seed of the jitter's stream, ``numpy.random.default_rng([seed, 1])``.

    Returns
    -------
    T_world_cam_jitter : (n, 4, 4) float64
        ``T_i · J_i``, rigid; every frame is jittered, the first included. With both sigmas 0 the poses
        come back unchanged (as float64).

    Raises
    ------
    PanovoccError
        When ``T_world_cam`` is not an (n, 4, 4) array of finite numbers, or a sigma is negative or not
        finite.
    """
    T = _check_poses(T_world_cam, "jitter")
    _check_sigmas("jitter", trans_m=trans_m, rot_deg=rot_deg)
    out = T.copy()
    if trans_m == rot_deg == 0:
        return out
    z = np.random.default_rng([int(seed), 1]).standard_normal((T.shape[0], 6))
    J = np.tile(np.eye(4), (T.shape[0], 1, 1))
    J[:, :3, :3] = so3_exp(z[:, :3] * np.deg2rad(rot_deg))
    J[:, :3, 3] = z[:, 3:] * trans_m
    out = T @ J
    U, _, Vt = np.linalg.svd(out[:, :3, :3])
    out[:, :3, :3] = U @ Vt
    return out
