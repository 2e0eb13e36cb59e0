"""``panovocc view`` and ``panovocc map --rerun``, end to end on the shared four-frame fixture; the recordings
are read back with Rerun's own reader (rerun.chunk.RrdReader) and compared with the map's files."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
pytest.importorskip("rerun")

from cli_helpers import run_cli, snapshot  # noqa: E402
from rerun_helpers import boxes, read_rrd  # noqa: E402

from panovocc_cli.io.grid import read_grid  # noqa: E402
from panovocc_cli.io.poses import read_poses  # noqa: E402


def occupied(g):
    ijk = np.argwhere((g.labels != 0) & (g.labels != 255))
    return g.centers(ijk), g.labels[tuple(ijk.T)]


def test_view_logs_the_map(base, tmp_path, capsys):
    before = snapshot(base)
    out = tmp_path / "v.rrd"
    code, o, err = run_cli(capsys, ["view", base / "map", "--out", out, "--free", "--quiet"])
    assert code == 0, err
    assert snapshot(base) == before
    rec = read_rrd(out)
    pred = read_grid(base / "map" / "prediction.npz")
    centres, labels = occupied(pred)
    got, ids = boxes(rec["world/map/occupied"][0])
    assert len(got) == len(centres) and np.allclose(got, centres, atol=1e-5) and np.array_equal(ids, labels)
    ctx = rec["world/map"][0]["AnnotationContext:context"][0]
    named = {d["class_id"]: d["class_description"]["info"]["label"] for d in ctx}
    assert all(named[k] == pred.class_names[k] for k in np.unique(labels) if k < 254)
    assert len(rec["world/map/free"][0]["Points3D:positions"]) == int((pred.labels == 0).sum())
    poses = read_poses(base / "map" / "poses.txt")
    assert [r["frame"] for r in rec["world/camera"]] == list(range(len(poses)))
    assert np.allclose(rec["world/camera"][2]["Transform3D:translation"][0], poses[2][:3, 3], atol=1e-5)
    traj = np.asarray(rec["world/trajectory"][0]["LineStrips3D:strips"][0])
    assert np.allclose(traj, poses[:, :3, 3], atol=1e-5)
    assert len(rec["world/frusta"][0]["LineStrips3D:strips"]) == 5 * len(poses)
    assert len(rec["panorama"]) == len(poses) and rec["panorama"][0]["EncodedImage:media_type"] == ["image/jpeg"]
    assert len(rec["depth"]) == len(poses)
    assert "| colour | class | voxels |" in rec["legend"][0]["TextDocument:text"][0]
    assert json.loads((tmp_path / "v.config.json").read_text())["free"] is True


def test_view_difference_to_ground_truth(base, tmp_path, capsys):
    out = tmp_path / "d.rrd"
    code, o, err = run_cli(capsys, ["view", base / "map", "--out", out, "--gt", base / "gt.npz", "--no-images",
                                    "--quiet"])
    assert code == 0, err
    rec = read_rrd(out)
    assert "panorama" not in rec
    # the difference counted a second way: voxel by voxel through dictionaries of world indices
    pred, gt = read_grid(base / "map" / "prediction.npz"), read_grid(base / "gt.npz")

    def table(g):
        ijk = np.argwhere(g.labels != 255)
        return {tuple(int(v) for v in k + g.index0): g.class_names[g.labels[tuple(k)]] if 0 < g.labels[tuple(k)] < 254
                else int(g.labels[tuple(k)]) for k in ijk}

    P, G = table(pred), table(gt)
    fp = sum(1 for k, v in G.items() if v == 0 and P.get(k, 0) != 0)
    fn = sum(1 for k, v in G.items() if v != 0 and P.get(k, 0) == 0)
    wrong = sum(1 for k, v in G.items() if isinstance(v, str) and isinstance(P.get(k), str) and P[k] != v)
    counts = {kind: len(boxes(rec[f"world/diff/{kind}"][0])[0]) for kind in ("false_positive", "false_negative",
                                                                             "wrong_class")}
    assert counts == {"false_positive": fp, "false_negative": fn, "wrong_class": wrong}
    assert f"{fp} false positive, {fn} false negative, {wrong} wrong-class" in o


def test_view_without_display_writes_beside_the_map(base, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    m = tmp_path / "m"
    shutil.copytree(base / "map", m)
    code, o, err = run_cli(capsys, ["view", m, "--no-images", "--quiet"])
    assert code == 0, err
    assert (tmp_path / "m.rrd").is_file() and "rerun " in o
    code, o, err = run_cli(capsys, ["view", m, "--no-images", "--quiet"])  # it exists now
    assert code == 2 and "--overwrite" in err
    assert run_cli(capsys, ["view", m, "--no-images", "--quiet", "--overwrite"])[0] == 0


@pytest.mark.parametrize("case", ["not_a_map", "missing", "unfinished", "not_rrd", "bad_gt"])
def test_view_bad_input_one_line_exit_2(case, base, tmp_path, capsys):
    target, extra = base / "map", []
    if case == "not_a_map":
        target = base / "seq"
    elif case == "missing":
        target = tmp_path / "nothing"
    elif case == "unfinished":
        target = tmp_path / "m"
        shutil.copytree(base / "map", target)
        (target / "prediction.npz").unlink()
    elif case == "bad_gt":
        bad = tmp_path / "gt.npz"
        bad.write_bytes(b"PK\x03\x04 not a zip")
        extra = ["--gt", bad]
    before = snapshot(base, tmp_path)
    out = tmp_path / ("v.txt" if case == "not_rrd" else "v.rrd")
    code, o, err = run_cli(capsys, ["view", target, "--out", out, "--quiet", *extra])
    assert code == 2, (o, err)
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in err
    assert snapshot(base, tmp_path) == before


def test_map_rerun_logs_the_run_and_changes_no_map_byte(base, tmp_path, capsys):
    out, rrd = tmp_path / "map", tmp_path / "live.rrd"
    code, o, err = run_cli(capsys, ["map", base / "seq", out, "--rerun", rrd, "--rerun-every", "2", "--quiet"])
    assert code == 0, err
    for name in ("prediction.npz", "map.ply", "poses.txt"):  # the same bytes as the fixture's map without the log
        assert (out / name).read_bytes() == (base / "map" / name).read_bytes(), name
    rec = read_rrd(rrd)
    n = len(read_poses(base / "map" / "poses.txt"))
    assert [r["frame"] for r in rec["panorama"]] == list(range(n))
    assert [r["frame"] for r in rec["world/camera"]] == list(range(n))
    maps = rec["world/map/occupied"]
    assert [r["frame"] for r in maps] == [1, 3, 3]  # every 2 frames, then the final map at the end
    centres, labels = occupied(read_grid(out / "prediction.npz"))
    got, ids = boxes(maps[-1])
    assert len(got) == len(centres)
    order_a, order_b = np.lexsort(got.T), np.lexsort(centres.T)
    assert np.allclose(got[order_a], centres[order_b], atol=1e-5) and np.array_equal(ids[order_a], labels[order_b])
    assert any(t["TextLog:text"][0].startswith("run finished") for t in rec["log"])


@pytest.mark.parametrize("case", ["bad_seq", "not_rrd", "url_alone", "both", "exists"])
def test_map_rerun_bad_input_leaves_no_recording(case, base, tmp_path, capsys):
    seq, rrd, extra = base / "seq", tmp_path / "live.rrd", []
    if case == "bad_seq":
        seq = tmp_path / "no-seq"
    elif case == "not_rrd":
        rrd = tmp_path / "live.txt"
    elif case == "url_alone":
        extra = ["--rerun-url", "rerun+http://127.0.0.1:1/proxy"]
    elif case == "both":
        extra = ["--rerun-connect"]
    elif case == "exists":
        rrd.write_bytes(b"mine")
    before = snapshot(base, tmp_path)
    code, o, err = run_cli(capsys, ["map", seq, tmp_path / "map", "--rerun", rrd, "--quiet", *extra])
    assert code == 2, (o, err)
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ")
    assert snapshot(base, tmp_path) == before


def test_map_slam_rerun_hears_of_loop_closures(base, tmp_path, capsys, monkeypatch):
    """--poses slam: the pose source passes the tracker's loop edges to the live log (a loop edge is added to the
    tracker's own answer at frame 2, so the wiring is seen whatever the four frames give)."""
    import dataclasses

    from panovocc_cli.slam import run as slam_run

    track = slam_run.Tracker.track

    def with_loop(self, i, depth):
        step = track(self, i, depth)
        return dataclasses.replace(step, loops=list(step.loops) + ([(0, 1)] if i == 2 else []))

    monkeypatch.setattr(slam_run.Tracker, "track", with_loop)
    rrd = tmp_path / "slam.rrd"
    code, o, err = run_cli(capsys, ["map", base / "seq", tmp_path / "map", "--poses", "slam", "--rerun", rrd,
                                    "--quiet"])
    assert code == 0, err
    rec = read_rrd(rrd)
    assert [r["frame"] for r in rec["world/camera"]] == [0, 1, 2, 3]
    texts = [(r["frame"], r["TextLog:text"][0]) for r in rec["log"]]
    assert (2, "frame 2: loop closure 0-1") in texts
    assert "world/slam/loop_closures" in rec
