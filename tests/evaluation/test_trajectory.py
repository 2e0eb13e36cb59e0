"""evaluation/trajectory.py and io/poses.py's timestamp matching against evo 1.38.1's own numbers."""

import copy

import numpy as np
import pytest
from cli_helpers import run_cli

from panovocc_cli.errors import PanovoccError
from panovocc_cli.evaluation.trajectory import (align_trajectory, error_stats, evaluate_trajectory, rotation_angle,
                                                umeyama)
from panovocc_cli.geometry.drift import drift_trajectory, so3_exp
from panovocc_cli.io.poses import frame_poses, match_timestamps, read_trajectory, write_poses, write_tum

evo = pytest.importorskip("evo")
from evo.core import metrics, sync  # noqa: E402
from evo.core.trajectory import PoseTrajectory3D  # noqa: E402


def _helix(n=60):
    t = np.linspace(0, 3, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.stack([np.cos(t) * 2, np.sin(t) * 1.5, 0.3 * t], 1)
    T[:, :3, :3] = so3_exp(np.stack([0.1 * np.sin(t), 0.05 * t, t], 1))
    return T


def _evo(T_est, T_ref, align):
    ref = PoseTrajectory3D(poses_se3=list(T_ref), timestamps=np.arange(len(T_ref), dtype=float))
    est = PoseTrajectory3D(poses_se3=list(T_est), timestamps=np.arange(len(T_est), dtype=float))
    est = copy.deepcopy(est)
    if align != "none":
        est.align(ref, correct_scale=align == "sim3")
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames, all_pairs=False)
    rpe.process_data((ref, est))
    rot = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, 1, metrics.Unit.frames, all_pairs=False)
    rot.process_data((ref, est))
    return ape.get_all_statistics(), rpe.get_all_statistics(), rot.get_all_statistics(), np.stack(est.poses_se3)


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_ate_and_rpe_equal_evo(align):
    T_ref = _helix()
    T_est = drift_trajectory(T_ref, trans_m_per_sqrt_frame=0.01, rot_deg_per_frame=0.4, seed=2)
    if align == "sim3":  # a scaled, moved estimate: Sim(3) must undo the scale
        T_est[:, :3, 3] *= 0.8
    T_est = np.einsum("ij,njk->nik", np.block([[so3_exp([0, 0, 0.5]), np.array([[1.0], [2.0], [0.5]])],
                                               [np.zeros((1, 3)), np.ones((1, 1))]]), T_est)
    res = evaluate_trajectory(T_est, T_ref, align=align)
    ape, rpe, rot, est_aligned = _evo(T_est, T_ref, align)
    for k in ("rmse", "mean", "median", "std", "min", "max", "sse"):
        assert res.ate[k] == pytest.approx(ape[k], rel=1e-9, abs=1e-12), k
        assert res.rpe_trans[k] == pytest.approx(rpe[k], rel=1e-9, abs=1e-12), k
        assert res.rpe_rot_deg[k] == pytest.approx(rot[k], rel=1e-6, abs=1e-7), k
    assert np.allclose(res.T_est_aligned, est_aligned, atol=1e-10)
    if align == "sim3":
        assert res.scale == pytest.approx(1 / 0.8, rel=0.05)


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 3))
    R = so3_exp([0.3, -0.2, 1.1])
    y = 2.5 * x @ R.T + [1, -2, 3]
    R2, t2, s2 = umeyama(x, y, with_scale=True)
    assert np.allclose(R2, R) and np.allclose(t2, [1, -2, 3]) and s2 == pytest.approx(2.5)
    with pytest.raises(PanovoccError, match="degenerate"):
        umeyama(np.outer(np.arange(5.0), [1, 0, 0]), np.outer(np.arange(5.0), [0, 1, 0]))


def test_exact_estimate_has_zero_error_and_alignment_modes_checked():
    T = _helix(20)
    res = evaluate_trajectory(T, T, "se3")
    assert res.ate["rmse"] < 1e-12 and res.rpe_trans["max"] < 1e-12 and res.rpe_rot_deg["max"] < 1e-5
    with pytest.raises(PanovoccError, match="alignment"):
        align_trajectory(T, T, "bogus")
    with pytest.raises(PanovoccError, match="poses"):
        evaluate_trajectory(T[:5], T)
    assert rotation_angle(so3_exp([0, 0, np.pi - 1e-3])) == pytest.approx(np.pi - 1e-3)
    assert np.isnan(error_stats([])["rmse"])


def test_match_timestamps_equals_evo():
    rng = np.random.default_rng(5)
    a = np.sort(rng.uniform(0, 10, 80))
    b = np.sort(np.concatenate([a[::2] + rng.normal(0, 0.004, 40), rng.uniform(-1, 12, 30)]))
    for d in (0.001, 0.01, 0.3):
        ia, ib = match_timestamps(a, b, d)
        ea, eb = sync.matching_time_indices(a, b, d)
        assert ia.tolist() == ea and ib.tolist() == eb


def test_tum_and_nice_slam_read_with_timestamps(tmp_path):
    T = _helix(12)
    write_tum(tmp_path / "a.tum", T[::2], timestamps=np.arange(0, 12, 2) + 0.003)
    write_tum(tmp_path / "all.tum", T[[3, 0, 1, 2, 5, 4, 7, 6, 8, 9, 10, 11]],
              timestamps=[3, 0, 1, 2, 5, 4, 7, 6, 8, 9, 10, 11])
    write_poses(tmp_path / "nice.txt", T)
    t, P, form = read_trajectory(tmp_path / "a.tum")
    assert form == "tum" and np.allclose(t, np.arange(0, 12, 2) + 0.003)
    assert np.allclose(frame_poses(tmp_path / "all.tum", 12), T, atol=1e-9)  # order does not matter
    assert np.array_equal(frame_poses(tmp_path / "nice.txt", 12), T)
    with pytest.raises(PanovoccError, match="6 of 12 frames"):
        frame_poses(tmp_path / "a.tum", 12)
    assert np.allclose(frame_poses(tmp_path / "a.tum", 6, stamps=np.arange(0, 12, 2)), T[::2], atol=1e-9)
    write_tum(tmp_path / "clock.tum", T[::-1], timestamps=1305031102.0 + 0.033 * np.arange(12)[::-1])
    with pytest.raises(PanovoccError, match="match none of the frame indices"):  # clock stamps: never guessed
        frame_poses(tmp_path / "clock.tum", 12)
    with pytest.raises(PanovoccError, match="11 poses for 12"):
        write_poses(tmp_path / "short.txt", T[:11])
        frame_poses(tmp_path / "short.txt", 12)


def test_traj_perturb_then_eval_command_line(tmp_path, capsys):
    T = _helix(50)
    write_poses(tmp_path / "gt.txt", T)
    code, out, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "est.tum", "--drift", "0.01",
                          "--rot-drift-deg", "0.2", "--seed", "4"])
    assert code == 0, err
    first = (tmp_path / "est.tum").read_bytes()
    code, _, _ = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "est.tum", "--drift", "0.01",
                      "--rot-drift-deg", "0.2", "--seed", "4", "--overwrite"])
    assert code == 0 and (tmp_path / "est.tum").read_bytes() == first  # seeded: same bytes
    assert (tmp_path / "est.config.json").is_file()
    _, D, form = read_trajectory(tmp_path / "est.tum")
    assert form == "tum" and np.allclose(D, drift_trajectory(T, trans_m_per_sqrt_frame=0.01, rot_deg_per_frame=0.2,
                                                              seed=4), atol=1e-9)
    code, out, err = run_cli(capsys, ["traj", "eval", tmp_path / "est.tum", tmp_path / "gt.txt", "--plot",
                          tmp_path / "top.png", "--json", tmp_path / "r.json"])
    assert code == 0, err
    import json

    r = json.loads((tmp_path / "r.json").read_text())
    ape, rpe, rot, _ = _evo(D, T, "se3")
    assert r["ate_m"]["rmse"] == pytest.approx(ape["rmse"], rel=1e-9)
    assert f"rmse {ape['rmse']:.4f}" in out
    assert (tmp_path / "top.png").stat().st_size > 1000 and (tmp_path / "top.config.json").is_file()


def test_traj_perturb_offset_moves_every_position_and_nothing_else(tmp_path, capsys):
    """--offset X,Y,Z: every camera position moved by the same vector, the rotations untouched, after any
    jitter; a malformed offset is refused with exit 2 and nothing written."""
    from panovocc_cli.geometry.drift import jitter_trajectory

    T = _helix(30)
    write_poses(tmp_path / "gt.txt", T)
    code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "o.txt", "--offset",
                                    "0.001,0,-0.002"])
    assert code == 0, err
    _, D, _ = read_trajectory(tmp_path / "o.txt")
    assert np.allclose(D[:, :3, :3], T[:, :3, :3], atol=1e-12)
    assert np.allclose(D[:, :3, 3] - T[:, :3, 3], [0.001, 0.0, -0.002], atol=1e-9)
    code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "oj.txt", "--jitter", "0.01",
                                    "--seed", "3", "--offset", "0.5,0.5,0.5"])
    assert code == 0, err
    J = jitter_trajectory(T, trans_m=0.01, rot_deg=0.0, seed=3)
    assert np.allclose(read_trajectory(tmp_path / "oj.txt")[1][:, :3, 3] - J[:, :3, 3], 0.5, atol=1e-9)
    for bad in ("1,2", "1,2,x", "1,2,nan"):
        code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "bad.txt", "--offset", bad])
        assert code == 2 and "--offset" in err and not (tmp_path / "bad.txt").exists()


def test_traj_perturb_jitter_command_line(tmp_path, capsys):
    """--jitter / --rot-jitter-deg: per-frame noise on top of the drift, seeded; ATE near the jitter's sigma."""
    import json

    from panovocc_cli.geometry.drift import jitter_trajectory

    T = _helix(400)
    write_poses(tmp_path / "gt.txt", T)
    args = ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "j.txt", "--jitter", "0.01", "--rot-jitter-deg",
            "0.1", "--seed", "2"]
    code, out, err = run_cli(capsys, args)
    assert code == 0, err
    first = (tmp_path / "j.txt").read_bytes()
    assert run_cli(capsys, args + ["--overwrite"])[0] == 0 and (tmp_path / "j.txt").read_bytes() == first
    cfg = json.loads((tmp_path / "j.config.json").read_text())
    assert cfg["jitter"] == 0.01 and cfg["rot_jitter_deg"] == 0.1
    _, J, form = read_trajectory(tmp_path / "j.txt")
    assert form == "nice-slam" and np.allclose(J, jitter_trajectory(T, trans_m=0.01, rot_deg=0.1, seed=2), atol=1e-12)
    # unaligned ATE of per-axis sigma 1 cm: sqrt(3) cm RMS in position (the rotation jitter turns the
    # camera about its own centre and moves no position)
    code, out, err = run_cli(capsys, ["traj", "eval", tmp_path / "j.txt", tmp_path / "gt.txt", "--align", "none",
                                      "--json", tmp_path / "r.json"])
    assert code == 0, err
    assert json.loads((tmp_path / "r.json").read_text())["ate_m"]["rmse"] == pytest.approx(0.01 * np.sqrt(3), rel=0.1)
    # drift and jitter together: the drift of the same seed, then the jitter on top
    code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "dj.txt", "--drift", "0.002",
                                    "--jitter", "0.01", "--seed", "2"])
    assert code == 0, err
    _, DJ, _ = read_trajectory(tmp_path / "dj.txt")
    expect = jitter_trajectory(drift_trajectory(T, trans_m_per_sqrt_frame=0.002, seed=2), trans_m=0.01, seed=2)
    assert np.allclose(DJ, expect, atol=1e-12)
    code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "bad.txt", "--jitter", "-1"])
    assert code == 2 and "--jitter" in err and not (tmp_path / "bad.txt").exists()


@pytest.mark.parametrize("opt", ["--drift", "--drift-per-m", "--rot-drift-deg"])
def test_traj_perturb_refuses_a_drift_that_overflows(tmp_path, capsys, opt):
    """--drift 1e300 squared overflows (it was an OverflowError traceback): the drifts have a range."""
    write_poses(tmp_path / "gt.txt", _helix(5))
    code, _, err = run_cli(capsys, ["traj", "perturb", tmp_path / "gt.txt", tmp_path / "o.txt", opt, "1e300"])
    assert code == 2 and opt in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gt.txt"]


def _tum_text(T, stamps) -> str:
    from panovocc_cli.geometry.poses import rot_to_quat

    return "".join(" ".join(repr(float(x)) for x in [t, *P[:3, 3], *rot_to_quat(P[:3, :3])]) + "\n"
                   for t, P in zip(stamps, T))


def test_duplicate_timestamps_and_huge_coordinates_are_refused(tmp_path, capsys):
    """A TUM file with a timestamp twice (which pose is frame t?) and a coordinate of 1e308 m (squares overflow:
    ATE inf) are refused by the one trajectory reader, so traj eval, map --poses and revise all refuse them."""
    T = _helix(12)
    write_tum(tmp_path / "gt.tum", T)
    (tmp_path / "dup.tum").write_text(_tum_text(T, [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 10]))
    with pytest.raises(PanovoccError, match="line 12: timestamp 10.0 repeats line 11"):
        read_trajectory(tmp_path / "dup.tum")
    far = T.copy()
    far[5, 0, 3] = 1e308
    (tmp_path / "far.tum").write_text(_tum_text(far, range(12)))
    write_poses(tmp_path / "far.txt", far)
    for name, line in (("far.tum", 6), ("far.txt", 6)):
        with pytest.raises(PanovoccError, match=f"line {line}: camera position .* beyond"):
            read_trajectory(tmp_path / name)
    for est in ("dup.tum", "far.tum"):
        code, out, err = run_cli(capsys, ["traj", "eval", tmp_path / est, tmp_path / "gt.tum"])
        assert code == 2 and est in err and len(err.strip().splitlines()) == 1 and "ATE" not in out, err


def _room_walk(n=60):
    """A path about a room's size that turns (the jitter bench's scale: 60 frames over a few metres)."""
    t = np.linspace(0, 2 * np.pi, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.stack([1.2 * np.cos(t), 0.8 * np.sin(t), 1.5 + 0.02 * np.sin(3 * t)], 1)
    T[:, :3, :3] = so3_exp(np.stack([np.full(n, -np.pi / 2), 0.05 * np.sin(t), t], 1))
    return T


def test_fit_poses_recovers_a_rigid_motion_exactly_even_standing_still():
    from panovocc_cli.evaluation.trajectory import fit_poses

    T = _room_walk()
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = so3_exp([0.2, -0.4, 2.0]), [90e3, -4e3, 12.0]  # far from the origin, turned
    R, t, info = fit_poses(T, A @ T)
    assert np.allclose(R, A[:3, :3], atol=1e-12) and np.allclose(t, A[:3, 3], atol=1e-7)
    assert info["sigma_t_m"] <= 1e-6 and info["sigma_r_deg"] <= 1e-4
    still = np.tile(T[:1], (10, 1, 1))  # one position: Umeyama has no rotation to give, the orientations do
    with pytest.raises(PanovoccError, match="degenerate"):
        align_trajectory(still, A @ still, "se3")
    assert np.allclose(align_trajectory(still, A @ still, "se3-pose")[0], A @ still, atol=1e-7)


def test_fit_poses_places_by_a_jittered_reference_better_than_umeyama():
    """The reference carries 10 mm / 0.1 deg of independent noise a frame (traj perturb --jitter): the fit of
    whole poses turns the trajectory by about 0.1 deg / sqrt(n), Umeyama on positions by sigma_t over the path's
    extent, several times more; both find the translation alike, and the fit reports the noise it saw."""
    from panovocc_cli.evaluation.trajectory import fit_poses
    from panovocc_cli.geometry.drift import jitter_trajectory

    T = _room_walk()
    err_pose, err_umeyama = [], []
    for seed in range(20):
        J = jitter_trajectory(T, trans_m=0.01, rot_deg=0.1, seed=seed)
        R, t, info = fit_poses(T, J)
        assert info["sigma_t_m"] == pytest.approx(0.01, rel=0.3) and info["sigma_r_deg"] == pytest.approx(0.1, rel=0.3)
        err_pose.append(np.degrees(rotation_angle(R)))
        err_umeyama.append(np.degrees(rotation_angle(align_trajectory(T, J, "se3")[1])))
    assert np.median(err_pose) < 0.03 and np.median(err_umeyama) > 2 * np.median(err_pose)


def test_map_poses_align_se3_pose(tmp_path):
    """map --poses-align se3-pose moves a pose file onto the reference by the whole-pose fit."""
    from panovocc_cli.mapping.pipeline import run_poses
    from panovocc_cli.mapping.config import MapConfig

    seq = tmp_path / "seq"
    seq.mkdir()
    (seq / "meta.json").write_text('{"frames": 60, "width": 64, "height": 32, "camera": "erp", '
                                   '"depth_scale": 1000.0, "class_names": []}')
    T = _room_walk()
    write_poses(seq / "poses.txt", T)
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = so3_exp([0.0, 0.0, 0.3]), [1.0, 2.0, 0.0]
    write_poses(tmp_path / "est.txt", np.linalg.inv(A) @ T)
    got = run_poses(MapConfig(seq=str(seq), out=str(tmp_path / "m"), poses=str(tmp_path / "est.txt"),
                              poses_align="se3-pose"))
    assert np.allclose(got, T, atol=1e-9)


def test_fit_poses_weighs_down_orientations_that_disagree_with_the_positions():
    """A reference that holds positions only (every orientation the identity, as a GNSS track written as TUM):
    its orientations disagree with the turning estimate by tens of degrees, so they weigh nothing and the fit is
    Umeyama's, not a turn towards the identity."""
    from panovocc_cli.evaluation.trajectory import fit_poses
    from panovocc_cli.geometry.drift import jitter_trajectory

    T = _room_walk()
    ref = jitter_trajectory(T, trans_m=0.01, seed=3)
    ref[:, :3, :3] = np.eye(3)
    R, t, info = fit_poses(T, ref)
    R_u, t_u, _ = umeyama(T[:, :3, 3], ref[:, :3, 3])
    assert np.degrees(rotation_angle(R.T @ R_u)) < 0.01 and np.abs(t - t_u).max() < 1e-3
    assert info["sigma_r_deg"] > 10
