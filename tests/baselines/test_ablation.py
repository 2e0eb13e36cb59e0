"""The map ablations: the pose perturbation-and-correction schedule with and without RPU, and ``map --config``."""

import json

import numpy as np
import pytest

from panovocc_cli.io.grid import read_grid
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.mapping.ablation import AblationParams, CorrectionSchedule

DRIFT = ["--drift-rot-deg", "1.5", "--drift-trans-m", "0.03", "--correct-every", "3"]


def test_schedule_blocks_and_reanchoring():
    rng = np.random.default_rng(1)
    T = np.tile(np.eye(4), (7, 1, 1))
    T[:, :3, 3] = rng.normal(size=(7, 3))
    p = AblationParams(drift_rot_deg=2.0, drift_trans_m=0.05, drift_seed=4, correct_every=3)
    s = CorrectionSchedule(T, p)
    assert [s.corrections_after(i) for i in range(7)] == [[], [], [0, 1, 2], [], [], [3, 4, 5], [6]]
    assert np.allclose(s.integration_pose(0), T[0])  # the drift starts at the first pose
    assert not np.allclose(s.integration_pose(2), T[2])
    # after a correction, drift restarts from the corrected pose: frame 3 sits where the drift moved it from 2
    assert np.allclose(s.integration_pose(3), T[2] @ np.linalg.inv(s.D[2]) @ s.D[3])
    again = CorrectionSchedule(T, p)
    assert np.array_equal(again.D, s.D)  # seeded
    assert CorrectionSchedule(T, AblationParams()).corrections_after(2) == []  # no drift: nothing to correct


def test_drift_is_a_seeded_random_walk():
    """Zero drift: the true poses; a drift: rigid poses, the first exact, the same seed the same bytes, errors growing
    like a random walk."""
    from panovocc_cli.mapping.ablation import drifted_poses

    n = 200
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, 0, 3] = np.linspace(0, 4, n)
    assert np.array_equal(drifted_poses(T, AblationParams()), T)
    p = AblationParams(drift_rot_deg=0.0, drift_trans_m=0.01, drift_seed=3)
    D = drifted_poses(T, p)
    assert np.array_equal(D, drifted_poses(T, p)) and np.array_equal(D[0], T[0])
    assert np.allclose(D[:, :3, :3], np.eye(3))  # no rotation drift: translation errors only
    err = D[:, :3, 3] - T[:, :3, 3]
    steps = np.diff(err, axis=0)
    assert abs(steps.std() - 0.01) < 0.0015  # each step adds N(0, 0.01^2) per axis
    R = drifted_poses(T, AblationParams(drift_rot_deg=1.0, drift_seed=3))[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-12)


def test_rpu_undoes_the_drift_exactly_and_without_it_stale_copies_stay(room, tmp_path, cli):
    """With RPU the corrected map is byte-identical to the map made with the true poses; without RPU the stale,
    drifted contributions stay: more occupied voxels, and the drifted copies are in the map."""
    base = ["map", room, None, "--segmenter", "none", "--quiet"]

    def run(name, *extra):
        argv = list(base)
        argv[2] = tmp_path / name
        code, out, err = cli([*argv, *extra])
        assert code == 0, err
        return out

    run("plain")
    out = run("rpu", *DRIFT)
    assert "3 pose corrections applied" in out  # frames 1, 2 and 3 of the 4 (frame 0 never drifts)
    run("norpu", *DRIFT, "--no-rpu")
    plain, rpu, norpu = (read_grid(tmp_path / n / "prediction.npz") for n in ("plain", "rpu", "norpu"))
    assert (tmp_path / "rpu" / "prediction.npz").read_bytes() == (tmp_path / "plain" / "prediction.npz").read_bytes()
    occ = lambda g: int(((g.labels != 0) & (g.labels != 255)).sum())  # noqa: E731
    assert occ(norpu) > 1.15 * occ(plain)
    n = len(Sequence(room))
    assert len((tmp_path / "norpu" / "poses.txt").read_text().splitlines()) == n + 3  # 3 stale copies kept
    cfg = json.loads((tmp_path / "norpu" / "config.json").read_text())
    assert cfg["ablation"] == {"use_rpu": False, "drift_rot_deg": 1.5, "drift_trans_m": 0.03, "drift_seed": 0,
                               "correct_every": 3}
    code, _, err = cli(["map", "--resume", tmp_path / "rpu", "--quiet"])
    assert code == 2 and "cannot be resumed" in err


def test_map_config_file(room, tmp_path, cli):
    cfg = tmp_path / "ablate.json"
    cfg.write_text(json.dumps({"kernel": "point", "use_gsc": False, "use_rpu": False, "segmenter": "none",
                               "voxel_size": 0.1}))
    code, _, err = cli(["map", room, tmp_path / "m", "--config", cfg, "--voxel-size", "0.12", "--quiet"])
    assert code == 0, err
    saved = json.loads((tmp_path / "m" / "config.json").read_text())
    assert saved["geometry"]["kernel"] == "point" and saved["semantic"]["use_gsc"] is False
    assert saved["ablation"]["use_rpu"] is False and saved["semantic"]["segmenter"] == "none"
    assert saved["geometry"]["voxel_size"] == 0.12  # the command line wins over the file
    for bad, expect in [({"kernal": "point"}, "unknown map option 'kernal'"), ({"nu": 3}, "--nu"),
                        ({"use_gsc": "no"}, "true or false")]:
        cfg.write_text(json.dumps(bad))
        code, _, err = cli(["map", room, tmp_path / "bad", "--config", cfg, "--quiet"])
        assert code == 2 and expect in err and str(cfg) in err and not (tmp_path / "bad").exists()
    code, _, err = cli(["map", room, tmp_path / "bad", "--config", tmp_path / "none.json", "--quiet"])
    assert code == 2 and "not found" in err
