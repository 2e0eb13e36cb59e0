"""map / revise / resume end to end on a tiny rendered room; exactness of the reversible update."""

import json

import numpy as np
import pytest
from map_helpers import load_memory

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.grid import read_grid
from panovocc_cli.io.poses import write_poses
from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.pipeline import MapConfig, run_map, run_revise
from room_sequence import ROOM, write_room_sequence

W = 128
N = 5


@pytest.fixture(scope="module")
def room_seq(tmp_path_factory):
    seq = tmp_path_factory.mktemp("seq") / "room"
    write_room_sequence(seq, N, W, furniture=True)
    return seq


def _cfg(seq, out, **kw):
    kw.setdefault("geometry", GeometryParams())
    kw.setdefault("checkpoint_every", 2)
    return MapConfig(seq=str(seq), out=str(out), **kw)


def _bytes(out):
    return {n: (out / n).read_bytes() for n in ("memory.npz", "prediction.npz", "map.ply")}


def test_map_outputs_three_states(room_seq, tmp_path):
    out = tmp_path / "m"
    s = run_map(_cfg(room_seq, out), progress=False)
    g = read_grid(out / "prediction.npz")
    vals = set(np.unique(g.labels).tolist())
    assert vals == {0, 254, 255}
    # the room's interior (away from walls and furniture) is free, the walls are occupied
    lo, hi = np.array(ROOM[0]), np.array(ROOM[1])
    c = g.centers(np.argwhere(np.ones(g.labels.shape, bool))).reshape(g.labels.shape + (3,))
    margin = np.minimum(c - lo, hi - c).min(axis=-1)
    centre_air = (np.abs(c[..., 0]) < 0.6) & (np.abs(c[..., 1]) < 0.5) & (np.abs(c[..., 2] - 1.9) < 0.3)
    assert (g.labels[centre_air] == 0).mean() > 0.95
    occ = g.labels == 254
    assert occ.sum() == s["occupied"] > 500
    assert np.median(np.abs(margin[occ])) < 0.1  # occupied voxels sit on the walls (furniture aside)
    # grazing kernel tails thicken surfaces at this tiny width (sigma_t = r * 2.8 deg): bounded, not absent
    assert np.mean(margin[occ] < -0.2) < 0.1 and np.mean(margin[occ] < -0.4) < 0.01
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["geometry"]["stride"] == 1 and cfg["geometry"]["kernel"] == "psvf"
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(out / "map.ply"))
    assert len(pc.points) == s["occupied"] and pc.has_colors()
    # the memory reloads to the same grid
    mem, done, poses = load_memory(out)
    assert done == N and poses.shape == (N, 4, 4)


def test_point_kernel_ablation_runs(room_seq, tmp_path):
    cfg = _cfg(room_seq, tmp_path / "p")
    cfg.geometry = GeometryParams(kernel="point")
    s = run_map(cfg, progress=False)
    assert s["occupied"] > 300


@pytest.mark.slow
def test_revise_wrong_poses_to_right_equals_direct(room_seq, tmp_path):
    direct = tmp_path / "direct"
    run_map(_cfg(room_seq, direct), progress=False)
    true = np.loadtxt(room_seq / "poses.txt").reshape(-1, 4, 4)
    wrong = true.copy()
    rng = np.random.default_rng(3)
    for i in (1, 3):
        a = rng.normal(0, 0.05)
        c, s = np.cos(a), np.sin(a)
        wrong[i, :3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ wrong[i, :3, :3]
        wrong[i, :3, 3] += rng.normal(0, 0.1, 3)
    write_poses(tmp_path / "wrong.txt", wrong)
    rev = tmp_path / "rev"
    run_map(_cfg(room_seq, rev, poses=str(tmp_path / "wrong.txt")), progress=False)
    assert (rev / "prediction.npz").read_bytes() != (direct / "prediction.npz").read_bytes()
    s = run_revise(rev, room_seq / "poses.txt", progress=False)
    assert s["revised"] == 2
    np.testing.assert_array_equal(read_grid(rev / "prediction.npz").labels, read_grid(direct / "prediction.npz").labels)
    assert (rev / "memory.npz").read_bytes() == (direct / "memory.npz").read_bytes()
    assert run_revise(rev, room_seq / "poses.txt", progress=False)["revised"] == 0
    # bad pose files: wrong count, non-rigid
    write_poses(tmp_path / "short.txt", true[:3])
    with pytest.raises(PanovoccError, match="3 poses"):
        run_revise(rev, tmp_path / "short.txt", progress=False)
    lines = (room_seq / "poses.txt").read_text().splitlines()
    lines[0] = " ".join(["2"] * 16)
    (tmp_path / "bad.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(PanovoccError):
        run_revise(rev, tmp_path / "bad.txt", progress=False)
    assert (rev / "memory.npz").read_bytes() == (direct / "memory.npz").read_bytes()


@pytest.mark.slow
def test_resume_after_kill_gives_same_bytes(room_seq, tmp_path):
    full = tmp_path / "full"
    run_map(_cfg(room_seq, full), progress=False)
    part = tmp_path / "part"
    s = run_map(_cfg(room_seq, part), progress=False, stop_after=3)  # killed after frame 3, checkpoint at 2
    assert s["stopped_at"] == 3 and not (part / "prediction.npz").exists()
    assert load_memory(part)[1] == 2
    run_map(resume_out=part, progress=False)
    assert _bytes(part) == _bytes(full)


@pytest.mark.slow
def test_cli_map_revise_and_bad_input(room_seq, tmp_path, capsys):
    from panovocc_cli.cli import main

    def run(*args):
        with pytest.raises(SystemExit) as e:
            main(list(args))
        return e.value.code, capsys.readouterr()

    # the room has no semantic labels: the CLI asks for an explicit segmenter (geometry only here)
    code, io = run("map", str(room_seq), str(tmp_path / "o"), "--quiet", "--checkpoint-every", "0")
    assert code == 2 and "--segmenter none" in io.err and not (tmp_path / "o").exists()
    geo = ("--segmenter", "none")
    code, io = run("map", str(room_seq), str(tmp_path / "o"), "--quiet", "--checkpoint-every", "0", *geo)
    assert code == 0 and "occupied" in io.out
    code, io = run("map", str(room_seq), str(tmp_path / "o"), "--quiet", *geo)
    assert code == 2 and "--resume" in io.err and len(io.err.strip().splitlines()) == 1
    code, io = run("map", str(tmp_path / "nope"), str(tmp_path / "o2"), "--quiet")
    assert code == 2 and not (tmp_path / "o2").exists()
    write_poses(tmp_path / "few.txt", np.loadtxt(room_seq / "poses.txt").reshape(-1, 4, 4)[:2])
    code, io = run("map", str(room_seq), str(tmp_path / "o3"), "--poses", str(tmp_path / "few.txt"), "--quiet", *geo)
    assert code == 2 and "2 poses" in io.err and not (tmp_path / "o3").exists()
    code, io = run("map", str(room_seq), str(tmp_path / "o4"), "--kernel", "cube", "--quiet", *geo)
    assert code == 2 and not (tmp_path / "o4").exists()
    code, io = run("map", str(room_seq), str(tmp_path / "o5"), "--rule", "majority", "--quiet", *geo)
    assert code == 2 and "--rule" in io.err and len(io.err.strip().splitlines()) == 1
    assert not (tmp_path / "o5").exists()
    code, io = run("map", str(room_seq), str(tmp_path / "o6"), "--rule", "score", "--quiet", "--checkpoint-every", "0",
                   *geo)
    assert code == 0 and '"rule": "score"' in (tmp_path / "o6" / "config.json").read_text()
    code, io = run("revise", str(tmp_path / "o"), str(room_seq / "poses.txt"), "--quiet")
    assert code == 0 and "revised 0 of 5" in io.out
    code, io = run("map", "--resume", str(tmp_path / "o"), "--quiet")
    assert code == 0


def test_revise_prints_the_cost_of_its_revisions_alone(room_seq, tmp_path, capsys):
    """``revise`` prints the wall and CPU time of the revisions themselves (frames read, deltas swapped, records
    written; not the load or the export), the figure ``make bench-scale`` reads for a loop closure inside a run."""
    import re

    from panovocc_cli.benchmark.scale import moved_tail, revisions_cost
    from panovocc_cli.cli import main
    from panovocc_cli.io.poses import read_poses

    out = tmp_path / "o"
    run_map(_cfg(room_seq, out, checkpoint_every=0), progress=False)
    write_poses(tmp_path / "moved.txt", moved_tail(read_poses(room_seq / "poses.txt"), 3))
    with pytest.raises(SystemExit) as e:
        main(["revise", str(out), str(tmp_path / "moved.txt"), "--quiet"])
    text = capsys.readouterr().out
    assert e.value.code == 0 and "revised 3 of 5 frames" in text
    wall, cpu = revisions_cost(text)
    assert 0 < wall <= float(re.search(r"frames in ([0-9.]+) s", text).group(1)) and cpu > 0
    with pytest.raises(SystemExit, match="no figures"):
        revisions_cost("revised 3 of 5 frames in 1.00 s: 10 occupied, 20 free voxels")


@pytest.mark.parametrize("existed", [False, True])
def test_map_failing_before_config_leaves_no_folder_it_created(room_seq, tmp_path, monkeypatch, existed):
    from panovocc_cli.io import mapstore

    def disk_full(*a, **k):
        raise OSError(28, "No space left on device")

    out = tmp_path / "m"
    if existed:
        out.mkdir()
    monkeypatch.setattr(mapstore, "write_map_config", disk_full)
    with pytest.raises(OSError):
        run_map(_cfg(room_seq, out), progress=False)
    assert out.is_dir() == existed  # a folder the user made stays (empty but for nothing of ours)
    if existed:
        assert [p.name for p in out.iterdir() if not p.name.startswith(".")] == []


def test_prefetched_frames_come_in_order_and_errors_where_they_belong(monkeypatch):
    """The map loop's one-ahead reader: every frame once, in order, the first read on the calling thread
    and the next ones on a second thread once the kernels allow it; a frame that fails raises when the
    loop reaches it, after the frames before it were handed out; and with a threading layer that cannot
    run kernels from two threads the loop stays on one thread."""
    import threading

    from panovocc_cli.mapping import pipeline

    def run(safe, fail_at=None):
        monkeypatch.setattr(pipeline, "concurrent_kernels_safe", lambda: safe)
        threads = {}

        def frames(i):
            threads[i] = threading.get_ident()
            if i == fail_at:
                raise PanovoccError(f"frame {i} is broken")
            return f"frame{i}"

        got = []
        try:
            for i, f in pipeline.prefetched(frames, range(3, 8)):
                got.append((i, f))
        except PanovoccError as e:
            got.append(str(e))
        return got, threads

    got, threads = run(True)
    assert got == [(i, f"frame{i}") for i in range(3, 8)]
    main = threading.get_ident()
    assert threads[3] == main and all(threads[i] != main for i in range(5, 8))
    got, threads = run(False)
    assert got == [(i, f"frame{i}") for i in range(3, 8)] and set(threads.values()) == {main}
    got, _ = run(True, fail_at=6)
    assert got == [(3, "frame3"), (4, "frame4"), (5, "frame5"), "frame 6 is broken"]
    assert list(pipeline.prefetched(lambda i: i, [])) == []


def _shifted_copy(seq, dst, shift):
    """The same capture with every camera moved by ``shift`` (3,) metres: its world moves with it."""
    import shutil

    from panovocc_cli.io.sequence import Sequence

    shutil.copytree(seq, dst)
    poses = Sequence(seq).poses.copy()
    poses[:, :3, 3] += np.asarray(shift, np.float64)
    write_poses(dst / "poses.txt", poses)
    return dst


def test_a_capture_90_km_away_gives_the_same_grid_in_its_place(room_seq, tmp_path):
    """Voxel keys are relative to the map's origin (the first frame's voxel): the capture moved 90 km (a
    whole number of 8 cm voxels) maps to the same grid, placed 90 km away; before local origins it was
    wrapped into the key range and put about 168 km from where it belongs, with exit status 0."""
    shift = np.array([90000.0, -45000.0, 120.0])  # 1125000, -562500, 1500 voxels
    far = _shifted_copy(room_seq, tmp_path / "far", shift)
    run_map(_cfg(room_seq, tmp_path / "near"), progress=False)
    run_map(_cfg(far, tmp_path / "mfar"), progress=False)
    g0, g1 = read_grid(tmp_path / "near" / "prediction.npz"), read_grid(tmp_path / "mfar" / "prediction.npz")
    np.testing.assert_array_equal(g0.labels, g1.labels)
    np.testing.assert_allclose(g1.origin - g0.origin, shift, atol=1e-6)
    np.testing.assert_array_equal(g1.index0 - g0.index0, np.round(shift / 0.08).astype(np.int64))
    cfg = json.loads((tmp_path / "mfar" / "config.json").read_text())
    assert np.all(np.abs(np.asarray(cfg["origin"]) - shift) < 5.0)  # the first camera's voxel, 90 km out
    ply = (tmp_path / "mfar" / "map.ply").read_bytes()
    assert b"element vertex" in ply


def test_a_frame_beyond_the_keys_reach_is_refused_before_any_work(room_seq, tmp_path):
    """A capture wider than the keys' reach around its origin (here: --origin 0,0,0 with cameras 90 km
    out) is refused with one line naming the frame and the limit, and leaves no output folder."""
    far = _shifted_copy(room_seq, tmp_path / "far", [90000.0, 0.0, 0.0])
    out = tmp_path / "m"
    with pytest.raises(PanovoccError, match=r"frame 0: camera at .* from the map's origin \[0\.0, 0\.0, 0\.0\].* reach"):
        run_map(_cfg(far, out, origin=[0.0, 0.0, 0.0]), progress=False)
    assert not out.exists()
    # the same capture with its own origin maps
    run_map(_cfg(far, out, origin=[90000.0, 0.0, 0.0]), progress=False)
    assert json.loads((out / "config.json").read_text())["origin"] == [90000.0, 0.0, 0.0]


def test_mapper_refuses_a_frame_beyond_the_reach_of_its_origin():
    from panovocc_cli.frame import Frame
    from panovocc_cli.geometry.cameras import ErpCamera
    from panovocc_cli.mapping import Mapper, MapperConfig

    m = Mapper(MapperConfig())
    depth = np.full((16, 32), 2.0, np.float32)
    rgb = np.zeros((16, 32, 3), np.uint8)
    m.integrate(Frame(rgb, depth, np.eye(4), ErpCamera(32, 16)))
    far = np.eye(4)
    far[0, 3] = 85000.0
    with pytest.raises(PanovoccError, match="frame 1: camera at .* reach"):
        m.integrate(Frame(rgb, depth, far, ErpCamera(32, 16), index=1))
    assert m.frame_ids == [0]


def test_sharded_log_reads_back_exactly_and_checkpoints_do_not_rewrite_the_memory(room_seq, tmp_path, monkeypatch):
    """With small shards a map's deltas span several files and read back bit for bit; a checkpoint writes
    only a journal entry (no memory.npz, no poses.txt rewrite), and the folder's bytes do not depend on
    the checkpoint schedule."""
    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping import Mapper

    full = tmp_path / "full"
    run_map(_cfg(room_seq, full), progress=False)
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 1)  # every record starts a shard of its own
    writes = []
    real = mapstore.write_memory
    monkeypatch.setattr(mapstore, "write_memory", lambda *a, **k: (writes.append(a[0]), real(*a, **k))[1])
    small = tmp_path / "small"
    run_map(dataclasses_replace(_cfg(room_seq, small), checkpoint_every=1), progress=False)
    assert len(writes) == 1  # the final save only: the N checkpoints were journal entries
    assert len(mapstore.shard_ids(small)) == N and len(mapstore.shard_ids(full)) == 1
    assert _bytes(small) == _bytes(full)
    a, b = Mapper.load(small), Mapper.load(full)
    for i in range(N):
        for pa, pb in zip(a._rpu.store.get(i).parts, b._rpu.store.get(i).parts, strict=True):
            np.testing.assert_array_equal(pa.keys, pb.keys)
            for k in pa.channels:
                np.testing.assert_array_equal(pa.channels[k], pb.channels[k])
    a.close()
    b.close()
    assert (small / "deltas" / "commits.pvj").read_bytes().__len__() == 24  # one entry after the save


def dataclasses_replace(cfg, **kw):
    import dataclasses

    return dataclasses.replace(cfg, **kw)


def test_a_failed_delta_write_stops_with_one_line_and_resumes_exactly(room_seq, tmp_path, monkeypatch):
    """Disk full while frame 3's delta is written: the memory drops that frame again (memory and store
    agree), the run stops with one line, and --resume gives the bytes of an uninterrupted run."""
    import errno

    from panovocc_cli.io import mapstore

    full = tmp_path / "full"
    run_map(_cfg(room_seq, full), progress=False)
    real = mapstore.DeltaLog.append

    def append(self, kind, fid, payload):
        if fid == 3:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, kind, fid, payload)

    monkeypatch.setattr(mapstore.DeltaLog, "append", append)
    out = tmp_path / "m"
    with pytest.raises(PanovoccError, match=r"cannot write the delta of frame 3 \(No space left on device\)") as e:
        run_map(_cfg(room_seq, out), progress=False)
    assert "\n" not in str(e.value) and "resumable" in str(e.value)
    monkeypatch.setattr(mapstore.DeltaLog, "append", real)
    run_map(resume_out=out, progress=False)
    assert _bytes(out) == _bytes(full)


def test_memory_and_store_agree_after_a_failed_write(room_seq, tmp_path, monkeypatch):
    import errno

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping import Mapper, MapperConfig
    from panovocc_cli.mapping.pipeline import SequenceFrames
    from panovocc_cli.io.sequence import Sequence

    frames = SequenceFrames(Sequence(room_seq))
    cfg = MapperConfig(geometry=GeometryParams(stride=1))
    m = Mapper(cfg, folder=tmp_path / "m", frame_source=frames)
    ref = Mapper(cfg)
    for i in range(2):
        m.integrate(frames(i))
        ref.integrate(frames(i))
    m.close()  # frame 1's record written before appends start failing (else the writer thread may still be on it)
    real = mapstore.DeltaLog.append
    monkeypatch.setattr(mapstore.DeltaLog, "append",
                        lambda self, *a: (_ for _ in ()).throw(OSError(errno.EROFS, "Read-only file system")))
    m.integrate(frames(2))  # its write fails on the writer thread
    with pytest.raises(PanovoccError, match="frame 2.*Read-only"):
        m.checkpoint()
    monkeypatch.setattr(mapstore.DeltaLog, "append", real)
    assert m.frame_ids == [0, 1]
    a, b = m.memory.to_arrays(), ref.memory.to_arrays()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    m.integrate(frames(2))
    ref.integrate(frames(2))
    m.save()
    m.close()
    back = Mapper.load(tmp_path / "m")
    a, b = back.memory.to_arrays(), ref.memory.to_arrays()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_frame_times_csv_and_the_scale_benchmarks_figures(room_seq, tmp_path):
    """`map --frame-times` writes one row a frame (time since the first frame, update ms, checkpoint flag,
    resident MB) and refuses to replace a file without --overwrite; the scale benchmark's early/late medians,
    checkpoint cost and moved tail come from it."""
    import csv

    from panovocc_cli.benchmark.scale import frame_costs, moved_tail

    times = tmp_path / "t.csv"
    s = run_map(_cfg(room_seq, tmp_path / "m", frame_times=str(times)), progress=False)
    rows = list(csv.DictReader(open(times)))
    assert [int(r["frame"]) for r in rows] == list(range(s["frames"]))
    t = [float(r["t_s"]) for r in rows]
    assert all(b >= a for a, b in zip(t, t[1:])) and all(float(r["rss_mb"]) > 10 for r in rows)
    assert [int(r["checkpoint"]) for r in rows] == [int((i + 1) % 2 == 0 and i + 1 < len(rows)) for i in range(len(rows))]
    fc = frame_costs(times)
    assert fc["frames"] == len(rows) and fc["ms_early"] > 0 and fc["ms_late"] > 0 and fc["checkpoints"] >= 1
    rss = [float(r["rss_mb"]) * 2 ** 20 for r in rows]
    assert fc["startup_rss_bytes"] == rss[0] and fc["pipeline_rss_bytes"] == max(rss[:3])  # after the third frame
    with pytest.raises(PanovoccError, match="already exists"):
        run_map(_cfg(room_seq, tmp_path / "m2", frame_times=str(times)), progress=False)
    assert not (tmp_path / "m2").exists()
    P = np.tile(np.eye(4), (10, 1, 1))
    P[:, 0, 3] = np.arange(10)
    Q = moved_tail(P, 4)
    np.testing.assert_array_equal(Q[:6], P[:6])
    assert not np.allclose(Q[6:], P[6:])
    for T in Q:
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(Q[6, :3, 3] - P[6, :3, 3]), 0.01, atol=1e-9)  # the pivot: 1 cm


def test_early_and_late_windows_of_a_run():
    """The windows the per-frame goals compare (map's frame costs, the SLAM scripts): frames 10-20 % and the
    last 10 %, never empty, the building's 7,661 frames as the scripts' n // 10 and n // 5 cut them."""
    from panovocc_cli.benchmark.scale import early_late

    e, l = early_late(7661)
    assert (e.start, e.stop, l.start, l.stop) == (766, 1532, 7661 - 766, 7661)
    for n in (1, 2, 5, 9, 10, 11, 100):
        e, l = early_late(n)
        x = np.arange(n)
        assert len(x[e]) >= 1 and len(x[l]) >= 1, n
        assert x[l][-1] == n - 1 and x[e][0] == int(0.1 * n)
    assert len(np.arange(100)[early_late(100)[0]]) == 10 and len(np.arange(100)[early_late(100)[1]]) == 10


def test_o_counts_every_frame_that_saw_surface_and_older_maps_keep_their_rule(room_seq, tmp_path):
    """Issue 26, 'one stray hit is occupied forever': the frequency rule N / max(O, 1) let a voxel with a
    measurement and no valid comparison of its centre (O = 0) count as always seen surface. A frame that
    puts a measurement in a voxel has observed it, so it counts in O too: N <= O everywhere, N / O is the
    share of observations that saw surface, and O = 0 only where N = 0 (never occupied). A map made before
    (its config.json without the key) resumes and revises with the old count, so it stays exact."""
    import dataclasses

    from panovocc_cli.mapping import Mapper

    out = tmp_path / "m"
    run_map(_cfg(room_seq, out), progress=False)
    keys, ch = Mapper.load(out).memory.nonzero()
    N, O = ch["N"][:, 0], ch["O"][:, 0]
    assert (N <= O).all() and (N > 0).any()
    old = tmp_path / "old"
    cfg = _cfg(room_seq, old, geometry=dataclasses.replace(GeometryParams(), observe_hits=False))
    run_map(cfg, progress=False)
    d = json.loads((old / "config.json").read_text())
    del d["geometry"]["observe_hits"]  # as a map made before the rule writes it
    (old / "config.json").write_text(json.dumps(d))
    m = Mapper.load(old)
    assert m.config.geometry.observe_hits is False
    _, ch0 = m.memory.nonzero()
    assert (ch0["N"][:, 0] > ch0["O"][:, 0]).any()  # the old count: measurements without a valid comparison


def test_revise_matches_tum_poses_by_timestamp_as_map_does(room_seq, tmp_path):
    """revise reads a pose file as map --poses does (io/poses.py frame_poses): a TUM file's lines are matched
    to frames by timestamp, so two swapped lines change nothing, and the same file maps and revises alike."""
    from panovocc_cli.io.poses import write_tum

    true = np.loadtxt(room_seq / "poses.txt").reshape(-1, 4, 4)
    write_tum(tmp_path / "t.tum", true)
    out = tmp_path / "m"
    run_map(_cfg(room_seq, out, poses=str(tmp_path / "t.tum")), progress=False)
    before = _bytes(out)
    order = np.arange(len(true))
    order[[1, 2]] = order[[2, 1]]
    lines = (tmp_path / "t.tum").read_text().splitlines(keepends=True)
    (tmp_path / "swapped.tum").write_text("".join(lines[i] for i in order))
    assert run_revise(out, tmp_path / "swapped.tum", progress=False)["revised"] == 0
    assert _bytes(out) == before
    with pytest.raises(PanovoccError, match="1 of 5 frames \\(4\\)"):  # a TUM file missing a pose: the frame is named
        write_tum(tmp_path / "few.tum", true[:-1])
        run_revise(out, tmp_path / "few.tum", progress=False)


def test_a_slam_run_failing_mid_run_does_not_call_itself_resumable(room_seq, tmp_path):
    """--poses slam runs refuse --resume: a failure found mid-run says to start over, never 'resumable'."""
    from panovocc_cli.mapping.config import POSES_SLAM

    def pose_source(seq):
        def source(i, frame):
            if i == 2:
                raise PanovoccError("frame 2: the tracker's input is broken")
            return seq.poses[i], []
        return source

    out = tmp_path / "m"
    with pytest.raises(PanovoccError, match="frame 2: the tracker's input is broken") as e:
        run_map(_cfg(room_seq, out, poses=POSES_SLAM), progress=False, pose_source=pose_source)
    msg = str(e.value)
    assert "\n" not in msg and "resum" not in msg.replace("cannot be resumed", "") and "--overwrite" in msg
    with pytest.raises(PanovoccError, match="cannot be resumed"):
        run_map(resume_out=out, progress=False)


def _commits(out) -> list[tuple[int, int]]:
    """The (shard, end) of each entry of OUT/deltas/commits.pvj."""
    import struct

    data = (out / "deltas" / "commits.pvj").read_bytes()
    return [struct.unpack("<4sqqI", data[i:i + 24])[1:3] for i in range(0, len(data), 24)]


@pytest.mark.parametrize("damaged", [0, 3])
def test_resume_refuses_a_damaged_record_wherever_the_replay_meets_it(room_seq, tmp_path, damaged):
    """A resumed run rebuilds its memory from the log, decoding the records ahead of the adds on a second thread
    (``rpu.REPLAY_AHEAD``): a record whose payload cannot be decoded (its checksum made to match, so the log's
    own check, which rolls a torn tail back, passes it) is refused with one line naming its shard, whether it
    is the first record or one decoded ahead while earlier ones were added; the folder is left as it was.
    Mended, the same replay gives the clean run's bytes."""
    import zlib

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping import rpu

    assert rpu.REPLAY_AHEAD < 3  # frame 3's record is decoded ahead of an add
    full = tmp_path / "full"
    run_map(_cfg(room_seq, full), progress=False)
    part = tmp_path / "part"
    run_map(_cfg(room_seq, part, checkpoint_every=1), progress=False, stop_after=4)  # killed: no memory.npz
    puts = [loc for kind, _, loc in mapstore.DeltaLog(part).records if kind == mapstore.PUT]
    assert len(puts) == 4 and not (part / "memory.npz").exists()
    shard, offset, length = puts[damaged]
    path = mapstore.shard_path(part, shard)
    original = path.read_bytes()
    data = bytearray(original)
    data[offset:offset + length] = b"\x28\xb5\x2f\xfd" + bytes(length - 4)  # a Zstandard magic, then nothing
    head = list(mapstore._HEADER.unpack_from(data, offset - mapstore._HEADER.size))
    head[4] = zlib.crc32(bytes(data[offset:offset + length]))
    mapstore._HEADER.pack_into(data, offset - mapstore._HEADER.size, *head)
    path.write_bytes(bytes(data))
    before = {p.name: p.read_bytes() for p in sorted((part / "deltas").iterdir())}
    with pytest.raises(PanovoccError, match="cannot read delta") as e:
        run_map(resume_out=part, progress=False)
    assert path.name in str(e.value) and len(str(e.value).splitlines()) == 1
    assert {p.name: p.read_bytes() for p in sorted((part / "deltas").iterdir())} == before
    path.write_bytes(original)
    run_map(resume_out=part, progress=False)
    assert _bytes(part) == _bytes(full)


def test_resume_over_a_truncated_delta_log_rolls_back_and_is_exact(room_seq, tmp_path):
    """A delta log cut short below its last commit(s) (a truncated shard) is rolled back by --resume to the
    last commit the log still reaches, as a killed run's tail is, and the frames after it are mapped again:
    the result is a clean run's bytes. revise still refuses such a folder (it would drop frames)."""
    full = tmp_path / "full"
    run_map(_cfg(room_seq, full), progress=False)
    part = tmp_path / "part"
    run_map(_cfg(room_seq, part, checkpoint_every=1), progress=False, stop_after=4)  # commits at 1 to 4 frames
    commits = _commits(part)
    assert len(commits) == 4 and len({s for s, _ in commits}) == 1
    with open(part / "deltas" / "shard-000000.pvd", "r+b") as f:
        f.truncate(commits[3][1] - 10)  # frame 3's record torn: the log reaches the commit after frame 2 only
    run_map(resume_out=part, progress=False)
    assert _bytes(part) == _bytes(full)
    done = tmp_path / "done"  # a finished map, its only delta file cut in half
    run_map(_cfg(room_seq, done), progress=False)
    shard = done / "deltas" / "shard-000000.pvd"
    with open(shard, "r+b") as f:
        f.truncate(shard.stat().st_size // 2)
    with pytest.raises(PanovoccError, match="delta log ends before"):
        run_revise(done, room_seq / "poses.txt", progress=False)
    run_map(resume_out=done, progress=False)
    assert _bytes(done) == _bytes(full)
