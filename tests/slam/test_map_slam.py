"""``panovocc map SEQ OUT --poses slam``: the estimated poses flow into the streaming map, revisions included,
and the final memory equals, bit for bit, one built directly from the final poses."""

import json
import shutil

import numpy as np
from cli_helpers import run_cli
from map_helpers import load_memory

from panovocc_cli.evaluation.trajectory import evaluate_trajectory
from panovocc_cli.io.poses import read_poses, read_trajectory, write_tum
from panovocc_cli.io.sequence import Sequence


def test_map_with_slam_poses_equals_a_map_from_the_final_poses(loop_seq, tmp_path, capsys, monkeypatch):
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.pipeline import load_config, sequence_frames
    from panovocc_cli.slam import SlamParams
    from panovocc_cli.slam.run import run_map_slam

    truth = read_poses(loop_seq / "poses.txt")
    seq_dir = tmp_path / "seq"
    shutil.copytree(loop_seq, seq_dir)
    (seq_dir / "poses.txt").unlink()  # --poses slam never reads them
    code, stdout, err = run_cli(capsys, ["map", seq_dir, tmp_path / "default", "--poses", "slam", "--quiet"])
    assert code == 0, err
    assert "slam: 48 of 48 frames placed" in stdout
    # the front end alone (no map) gives the same poses.txt
    from panovocc_cli.slam.run import run_slam_poses

    info = run_slam_poses(seq_dir, tmp_path / "poses_only", frame_times=tmp_path / "track.csv")
    assert info["placed"] == 48 and info["unplaced_frames"] == []
    assert (tmp_path / "poses_only" / "poses.txt").read_bytes() == (tmp_path / "default" / "poses.txt").read_bytes()
    # its frame times: a row a frame, time rising, the keyframe store as slam.json states it at the end
    lines = (tmp_path / "track.csv").read_text().splitlines()
    assert lines[0] == "frame,t_s,track_ms,keyframes,points_bytes,held_bytes,rss_mb" and len(lines) == 49
    rows = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    assert rows[:, 0].tolist() == list(range(48)) and np.all(np.diff(rows[:, 1]) > 0) and np.all(rows[:, 2] > 0)
    store = info["keyframe_store"]
    assert rows[-1, 3] == store["keyframes"] == info["keyframes"] and rows[-1, 4] == store["points"] > 0
    assert rows[-1, 5] == store["held_bytes"] > 0
    assert np.all(np.diff(rows[:, 3]) >= 0) and rows[0, 3] == 1
    # the exactness check wants many revisions: optimise after every loop edge, revise every frame moved 1 mm
    out = tmp_path / "map"
    params = SlamParams(loop_optimise_m=0.0, loop_optimise_deg=0.0, revise_trans_m=0.001, revise_rot_deg=0.05)
    run_map_slam(MapConfig(seq=str(seq_dir), out=str(out)), progress=False, params=params)
    info = json.loads((out / "slam.json").read_text())
    assert info["optimisations"] >= 1 and info["revisions"] > 0 and info["unplaced_frames"] == []
    final = read_poses(out / "poses.txt")
    t, tum, form = read_trajectory(out / "trajectory.tum")
    assert form == "tum" and t.tolist() == list(range(48)) and np.allclose(tum, final, atol=1e-9)
    # the estimate is the truth up to the choice of world frame (level first camera at the origin)
    assert evaluate_trajectory(final, truth, "se3").ate["rmse"] < 0.01

    # a map built from scratch with the final poses: the same memory, bit for bit
    cfg = load_config(out)
    seq = Sequence(seq_dir, poses=final)
    frames = sequence_frames(cfg, seq)
    ref = Mapper(cfg.mapper_config())
    for i in range(len(seq)):
        ref.integrate(frames(i))
    mem, done, poses = load_memory(out)
    assert done == 48 and np.array_equal(poses, final)
    k1, c1 = mem.nonzero()
    k2, c2 = ref.memory.nonzero()
    assert np.array_equal(k1, k2)
    assert set(c1) == set(c2) and all(np.array_equal(c1[n], c2[n]) for n in c1)

    # the same run with small shards, a checkpoint every 4 frames and every 8 revisions: they compact the log
    # (docs/mapping.md "Compaction of the delta log"), the memory and each frame's record are the same
    import dataclasses

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping import pipeline

    small = tmp_path / "small"
    logged = sum(mapstore.shard_path(out, s).stat().st_size for s in mapstore.shard_ids(out))  # ~2x its live records
    monkeypatch.setattr(mapstore, "SHARD_BYTES", logged // 16)
    monkeypatch.setattr(pipeline, "REVISIONS_PER_CHECKPOINT", 8)  # the final refinement's pass, committed in parts
    s = run_map_slam(dataclasses.replace(MapConfig(seq=str(seq_dir), out=str(small)), checkpoint_every=4),
                     progress=False, params=params)
    c = s["compactions"]
    assert c["count"] >= 1 and c["freed_bytes"] > c["copied_bytes"] > 0
    assert (small / "memory.npz").read_bytes() == (out / "memory.npz").read_bytes()
    a, b = Mapper.load(small), Mapper.load(out)
    assert a.frame_ids == b.frame_ids and all(a._rpu.store.payload(i) == b._rpu.store.payload(i) for i in a.frame_ids)
    a.close()
    b.close()
    assert c["log_bytes"] < logged


def test_poses_file_matched_and_aligned_to_a_reference(loop_seq, tmp_path):
    from panovocc_cli.mapping.config import MapConfig
    from panovocc_cli.mapping.pipeline import run_poses
    from panovocc_cli.geometry.drift import so3_exp

    truth = read_poses(loop_seq / "poses.txt")
    A = np.eye(4)
    A[:3, :3], A[:3, 3] = so3_exp([0.1, -0.3, 1.2]), [3.0, -1.0, 0.5]
    moved = A @ truth
    order = np.random.default_rng(0).permutation(48)  # TUM lines in any order: matched by timestamp
    write_tum(tmp_path / "est.tum", moved[order], timestamps=order.astype(float))
    cfg = MapConfig(seq=str(loop_seq), out=str(tmp_path / "m"), poses=str(tmp_path / "est.tum"))
    assert np.allclose(run_poses(cfg), moved, atol=1e-9)
    aligned = run_poses(MapConfig(seq=str(loop_seq), out=str(tmp_path / "m"), poses=str(tmp_path / "est.tum"),
                                  poses_align="se3"))
    assert np.allclose(aligned, truth, atol=1e-6)
    assert run_poses(MapConfig(seq=str(loop_seq), out=str(tmp_path / "m"))) is None  # SEQ/poses.txt as before
