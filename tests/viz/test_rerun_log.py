"""The Rerun building blocks (viz/rerun_log.py) on small grids with answers known by hand, and the live log's
revisions and loop closures read back with Rerun's own reader."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
pytest.importorskip("rerun")

from rerun_helpers import boxes, read_rrd  # noqa: E402

from panovocc_cli.geometry.poses import look_at  # noqa: E402
from panovocc_cli.grid import Grid  # noqa: E402
from panovocc_cli.viz import rerun_log as rl  # noqa: E402

H = 0.1


def grid(labels, names, i0=(0, 0, 0)):
    return Grid(np.asarray(labels, np.uint8), (np.asarray(i0) + 0.5) * H, H, names)


def test_difference_counts_by_hand():
    # ground truth: a row of 6 voxels; the prediction is shifted by one voxel and has other class names
    g = grid([[[0, 1, 2, 2, 255, 1]]], ["empty", "wall", "chair"])
    p = grid([[[1, 2, 3, 254, 1]]], ["empty", "chair", "Wall", "floor"], i0=(0, 0, 1))
    # voxel k (gt), pred covers k = 1..5: pred labels at k: 1 chair, 2 wall, 3 floor, 4 254, 5 chair
    # k=0: gt 0, pred none -> nothing; k=1: gt wall, pred chair -> wrong class; k=2: gt chair, pred wall -> wrong;
    # k=3: gt chair, pred floor -> wrong; k=4: gt 255 -> not scored; k=5: gt wall, pred chair -> wrong
    d = rl.grid_difference(p, g)
    assert len(d["false_positive"]) == 0 and len(d["false_negative"]) == 0 and len(d["wrong_class"]) == 4
    p2 = grid([[[0, 2, 0, 0, 0, 2]]], ["empty", "chair", "wall"])  # same box: names match by canonical name
    d = rl.grid_difference(p2, g)
    assert len(d["false_positive"]) == 0 and len(d["wrong_class"]) == 0
    assert np.allclose(d["false_negative"], [[0.05, 0.05, 0.25], [0.05, 0.05, 0.35]])  # the two chairs missed
    p3 = grid([[[1, 0, 0, 0, 1, 0]]], ["empty", "wall"])
    d = rl.grid_difference(p3, g)
    assert np.allclose(d["false_positive"], [[0.05, 0.05, 0.05]])  # k=0; k=4 is not scored


def test_frusta_point_along_the_camera_axis():
    T = look_at([1.0, 2.0, 1.5], [0.0, 1.0, 0.0])
    strips = rl.frustum_strips(T[None], size=0.2)
    assert len(strips) == 5 and strips[0].shape == (5, 3)
    base_centre = strips[0][:4].mean(axis=0)
    assert np.allclose(base_centre, T[:3, 3] + 0.2 * T[:3, 2], atol=1e-6)  # ahead along the camera's +z
    assert all(np.allclose(s[0], T[:3, 3], atol=1e-6) for s in strips[1:])  # edges from the apex


def test_class_table_and_legend():
    g = grid([[[0, 1, 1, 254, 2]]], ["empty", "wall", "chair"])
    table = rl.class_table(g.class_names)
    assert [k for k, _, _ in table] == [1, 2, 254]
    assert table[0][2] == (0x9B, 0xD6, 0xE2)  # the paper's wall colour
    md = rl.legend_markdown(g)
    assert "| wall | 2 |" in md and "| chair | 1 |" in md and "occupied (no class) | 1 |" in md


def test_live_log_records_frames_revisions_and_loops(tmp_path):
    from panovocc_cli.frame import Frame
    from panovocc_cli.geometry.cameras import ErpCamera
    from panovocc_cli.mapping.mapper import Mapper, MapperConfig
    from panovocc_cli.viz.live import LiveLog
    from box_room import box_depth

    m = Mapper(MapperConfig())
    log = LiveLog(rrd=tmp_path / "live.rrd", every=2, pano_width=32)
    poses = [look_at([0.2 * k, 0.0, 0.0], [1.0, 0.3 * k, 0.0]) for k in range(3)]
    for k, T in enumerate(poses):
        f = Frame(rgb=np.full((32, 64, 3), 40 * k, np.uint8), depth=box_depth(64, T), T_world_cam=T,
                  camera=ErpCamera(64, 32), index=k)
        m.integrate(f)
        rev = [(0, poses[0] @ np.diag([1.0, 1, 1, 1]))] if k == 2 else []
        if k == 2:
            log.loops(2, [(0, 2)])
        log.frame(k, f, m, rev)
    assert not (tmp_path / "live.rrd").exists()  # written under a temporary name until the run succeeds
    log.finish(m, {"frames": 3})
    log.close(ok=True)
    rec = read_rrd(tmp_path / "live.rrd")
    assert [r["frame"] for r in rec["panorama"]] == [0, 1, 2] and len(rec["depth"]) == 3
    assert [r["frame"] for r in rec["world/camera"]] == [0, 1, 2]
    # the map: at frame 1 (every 2), at frame 2 (a revision), and at the end
    maps = rec["world/map/occupied"]
    assert len(maps) == 3
    final, ids = boxes(maps[-1])
    assert len(final) == m.export().summary()["occupied"] and set(ids.tolist()) == {254}
    texts = [r["TextLog:text"][0] for r in rec["log"]]
    assert any("loop closure 0-2" in t for t in texts) and any("revised: 0" in t for t in texts)
    assert any(t.startswith("run finished") for t in texts)
    strip = np.asarray(rec["world/slam/loop_closures"][-1]["LineStrips3D:strips"][0], np.float32)
    assert np.allclose(strip, [poses[0][:3, 3], poses[2][:3, 3]], atol=1e-6)
    assert len(rec["world/slam/revised"]) == 1
    # a failed run leaves nothing
    log2 = LiveLog(rrd=tmp_path / "failed.rrd")
    log2.frame(0, f, m, [])
    log2.close(ok=False)
    assert not list(tmp_path.glob("*failed*")) and not list(tmp_path.glob(".failed*"))
