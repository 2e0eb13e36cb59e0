"""geometry/drift.py: the seeded drifting trajectory — determinism, the model's statistics, edge cases."""

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.drift import drift_trajectory, so3_exp
from panovocc_cli.geometry.poses import check_rigid


def _line(n, step_m=0.1):
    """n poses moving along world x by step_m a frame, camera yawing 1 degree a frame."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.arange(n) * step_m
    T[:, :3, :3] = so3_exp(np.outer(np.deg2rad(np.arange(n)), [0.0, 0.0, 1.0]))
    return T


def _steps(T):
    return np.linalg.inv(T[:-1]) @ T[1:]


def test_so3_exp_matches_closed_form():
    a = 0.7
    R = so3_exp([0.0, 0.0, a])
    assert np.allclose(R, [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]], atol=1e-15)
    assert np.array_equal(so3_exp(np.zeros(3)), np.eye(3))
    w = np.array([1e-9, -2e-9, 3e-9])
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    assert np.allclose(so3_exp(w), np.eye(3) + K, atol=1e-16)
    Rs = so3_exp(np.random.default_rng(1).normal(size=(50, 3)))
    assert np.allclose(Rs @ Rs.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(Rs), 1.0)


def test_deterministic_and_seeded():
    T = _line(40)
    kw = dict(trans_m_per_sqrt_frame=0.01, trans_m_per_m=0.02, rot_deg_per_frame=0.3)
    a = drift_trajectory(T, seed=3, **kw)
    b = drift_trajectory(T, seed=3, **kw)
    c = drift_trajectory(T, seed=4, **kw)
    assert a.tobytes() == b.tobytes()
    assert not np.allclose(a, c)
    assert np.array_equal(a[0], T[0])
    for P in a:
        check_rigid(P, tol=1e-10)
    # drift accumulates: the end is further from the truth than the second frame
    assert np.linalg.norm(a[-1, :3, 3] - T[-1, :3, 3]) > np.linalg.norm(a[1, :3, 3] - T[1, :3, 3])


def test_zero_drift_returns_the_truth_and_one_pose_is_fine():
    T = _line(10)
    assert np.array_equal(drift_trajectory(T, seed=1), T)
    one = drift_trajectory(T[:1], rot_deg_per_frame=1.0)
    assert np.array_equal(one, T[:1])


def test_step_errors_have_the_stated_standard_deviations():
    n = 4001
    T = _line(n, step_m=0.2)
    D = drift_trajectory(T, trans_m_per_sqrt_frame=0.003, trans_m_per_m=0.02, rot_deg_per_frame=0.5, seed=0)
    err = np.linalg.inv(_steps(T)) @ _steps(D)               # N_i, in camera i's frame
    tau = err[:, :3, 3]
    expect_t = np.hypot(0.003, 0.02 * 0.2)
    assert np.std(tau, axis=0) == pytest.approx([expect_t] * 3, rel=0.06)
    # rotation angle about each axis (small): skew part of R
    R = err[:, :3, :3]
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1) / 2
    assert np.rad2deg(np.std(w, axis=0)) == pytest.approx([0.5] * 3, rel=0.06)


def test_random_walk_grows_with_root_n():
    """No motion, translation drift only: the end error over many seeds has std sigma * sqrt(n - 1)."""
    n, sigma = 26, 0.01
    T = np.tile(np.eye(4), (n, 1, 1))
    ends = np.array([drift_trajectory(T, trans_m_per_sqrt_frame=sigma, seed=s)[-1, :3, 3] for s in range(1500)])
    assert np.std(ends) == pytest.approx(sigma * np.sqrt(n - 1), rel=0.06)


def test_same_seed_scales_linearly_in_translation():
    T = np.tile(np.eye(4), (20, 1, 1))
    a = drift_trajectory(T, trans_m_per_sqrt_frame=0.01, seed=7)
    b = drift_trajectory(T, trans_m_per_sqrt_frame=0.02, seed=7)
    assert np.allclose(b[:, :3, 3], 2 * a[:, :3, 3], atol=1e-15)


@pytest.mark.parametrize("bad", [
    dict(T_world_cam=np.eye(4)),
    dict(T_world_cam=np.zeros((0, 4, 4))),
    dict(T_world_cam=np.full((2, 4, 4), np.nan)),
    dict(T_world_cam=np.tile(np.eye(4), (2, 1, 1)), rot_deg_per_frame=-1.0),
    dict(T_world_cam=np.tile(np.eye(4), (2, 1, 1)), trans_m_per_m=float("nan")),
])
def test_bad_input_is_a_panovocc_error(bad):
    with pytest.raises(PanovoccError, match="drift"):
        drift_trajectory(**bad)


# --- per-frame jitter -------------------------------------------------------------------------------


def _rotvec_small(R):
    """Rotation vectors (n, 3) radians of nearly-identity rotations (their skew part)."""
    return np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1) / 2


def test_jitter_errors_are_independent_per_frame_with_the_stated_sigmas():
    from panovocc_cli.geometry.drift import jitter_trajectory

    n = 6000
    T = _line(n, step_m=0.2)
    J = jitter_trajectory(T, trans_m=0.01, rot_deg=0.1, seed=0)
    err = np.linalg.inv(T) @ J                          # J_i, in camera i's frame
    tau = err[:, :3, 3]
    assert np.std(tau, axis=0) == pytest.approx([0.01] * 3, rel=0.05)
    assert np.abs(np.mean(tau, axis=0)).max() < 0.01 * 4 / np.sqrt(n)
    w = _rotvec_small(err[:, :3, :3])
    assert np.rad2deg(np.std(w, axis=0)) == pytest.approx([0.1] * 3, rel=0.05)
    # not accumulated: the error of the last frame is no larger than any other's, and consecutive
    # frames' errors are uncorrelated (drift's would be nearly equal)
    assert abs(np.corrcoef(tau[:-1, 0], tau[1:, 0])[0, 1]) < 0.05
    assert np.linalg.norm(tau[-1]) < 0.06
    # every frame is jittered, the first included; all stay rigid
    assert not np.allclose(J[0], T[0])
    for P in J[::97]:
        check_rigid(P, tol=1e-10)


def test_jitter_is_seeded_scales_and_leaves_the_drift_alone():
    from panovocc_cli.geometry.drift import jitter_trajectory

    T = _line(30)
    a = jitter_trajectory(T, trans_m=0.005, rot_deg=0.05, seed=3)
    assert a.tobytes() == jitter_trajectory(T, trans_m=0.005, rot_deg=0.05, seed=3).tobytes()
    assert not np.allclose(a, jitter_trajectory(T, trans_m=0.005, rot_deg=0.05, seed=4))
    # at one seed a larger translation jitter is the same jitter scaled
    t1 = (np.linalg.inv(T) @ jitter_trajectory(T, trans_m=0.01, seed=3))[:, :3, 3]
    t2 = (np.linalg.inv(T) @ jitter_trajectory(T, trans_m=0.02, seed=3))[:, :3, 3]
    assert np.allclose(t2, 2 * t1, atol=1e-12)
    # its own stream: not the drift's numbers (whose first step would be scaled by the same normals)
    D = drift_trajectory(T, trans_m_per_sqrt_frame=0.01, seed=3)
    d_err = (np.linalg.inv(_steps(T)) @ _steps(D))[:, :3, 3]
    assert not np.allclose(t1[1:], d_err, atol=1e-6)
    assert np.array_equal(jitter_trajectory(T, seed=3), T)  # zero jitter: unchanged


@pytest.mark.parametrize("bad", [
    dict(T_world_cam=np.eye(4)),
    dict(T_world_cam=np.full((2, 4, 4), np.inf)),
    dict(T_world_cam=np.tile(np.eye(4), (2, 1, 1)), trans_m=-0.1),
    dict(T_world_cam=np.tile(np.eye(4), (2, 1, 1)), rot_deg=float("nan")),
])
def test_jitter_bad_input_is_a_panovocc_error(bad):
    from panovocc_cli.geometry.drift import jitter_trajectory

    with pytest.raises(PanovoccError, match="jitter"):
        jitter_trajectory(**bad)
