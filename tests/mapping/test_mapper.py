"""The streaming Mapper: exactly `panovocc map` frame by frame; revise during a run, remove and save/load
are exact (bit-identical memory); an empty depth frame is an empty observation."""

import dataclasses

import numpy as np
import pytest
from semantics_helpers import circle_poses, write_labelled_room

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.cameras import ErpCamera
from panovocc_cli.io import mapstore
from panovocc_cli.io.grid import read_grid
from panovocc_cli.io.poses import write_poses
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.mapping import Frame, Mapper, MapperConfig
from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.pipeline import MapConfig, load_config, run_map, run_revise, sequence_frames
from panovocc_cli.mapping.rpu import FROZEN

W = 64
N = 5



def _moved(T, seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(0, 0.1)
    c, s = np.cos(a), np.sin(a)
    out = T.copy()
    out[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ out[:3, :3]
    out[:3, 3] += rng.normal(0, 0.15, 3)
    return out


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    """The furnished, labelled room of semantics_helpers, 64x32, 5 frames."""
    seq = tmp_path_factory.mktemp("mapperseq") / "room"
    return write_labelled_room(seq, W, N)


@pytest.fixture(scope="module")
def mapped(seq_dir, tmp_path_factory):
    """`panovocc map` (simulated segmenter, 12 classes) of the room with the surface-offset channel P (its
    revise, remove, save and load below are exact like the other channels'): (output folder, its frame
    source)."""
    out = tmp_path_factory.mktemp("mapped") / "m"
    run_map(MapConfig(seq=str(seq_dir), out=str(out), checkpoint_every=0, geometry=GeometryParams(offsets=True)),
            progress=False)
    cfg = load_config(out)
    return out, cfg, sequence_frames(cfg, Sequence(seq_dir))


def _arrays(mapper):
    return mapper.memory.to_arrays()


def _assert_same_memory(a, b):
    x, y = _arrays(a), _arrays(b)
    assert sorted(x) == sorted(y)
    for k in x:
        np.testing.assert_array_equal(x[k], y[k], err_msg=k)


def test_frame_by_frame_equals_map_command(mapped, tmp_path):
    out, cfg, frames = mapped
    mapper = Mapper(cfg.mapper_config())
    assert mapper.config.vocab and len(mapper.config.vocab) == 12
    for i in range(N):
        f = frames(i)
        assert f.logits.shape == (W // 2, W, 12) and f.camera == ErpCamera(W, W // 2)
        assert mapper.integrate(f) == i
    g = mapper.prediction()
    ref = read_grid(out / "prediction.npz")
    np.testing.assert_array_equal(g.labels, ref.labels)
    assert g.class_names == ref.class_names and np.array_equal(g.origin, ref.origin)
    assert len(set(np.unique(g.labels).tolist()) - {0, 254, 255}) > 1  # classes, not only geometry
    saved = mapper.save(tmp_path / "api")
    assert "ch_P" in _arrays(mapper) and _arrays(mapper)["ch_P"].any()  # the surface offsets, summed like the rest
    for name in ("memory.npz", "poses.txt"):
        assert (saved / name).read_bytes() == (out / name).read_bytes(), name
    a, b = Mapper.load(saved), Mapper.load(out)  # the same records: each frame's delta, bit for bit
    for i in range(N):
        for pa, pb in zip(a._rpu.store.get(i).parts, b._rpu.store.get(i).parts, strict=True):
            np.testing.assert_array_equal(pa.keys, pb.keys)
            assert pa.channels.keys() == pb.channels.keys()
            for k in pa.channels:
                np.testing.assert_array_equal(pa.channels[k], pb.channels[k])
    a.close()
    b.close()
    # in a folder from the start (deltas written as they are made): the same bytes
    with Mapper(cfg.mapper_config(), folder=tmp_path / "f", frame_source=frames) as m2:
        for i in range(N):
            m2.integrate(frames(i))
        m2.save()
    assert (tmp_path / "f" / "memory.npz").read_bytes() == (out / "memory.npz").read_bytes()


def test_revise_during_run_equals_final_pose_from_start(mapped, tmp_path):
    _, cfg, frames = mapped
    true = np.stack([frames(i).T_world_cam for i in range(N)])

    def frame(i, T):
        f = frames(i)
        f.T_world_cam = T
        return f

    direct = Mapper(cfg.mapper_config())
    for i in range(N):
        direct.integrate(frame(i, true[i]))
    # kept frames (no source), in RAM: frame 1 starts wrong, is revised twice mid-run, frame 3 once at the end
    m = Mapper(cfg.mapper_config())
    for i in range(N):
        m.integrate(frame(i, _moved(true[i], i) if i in (1, 3) else true[i]))
        if i == 2:
            assert m.revise(1, _moved(true[1], 7))
            assert m.revise(1, true[1])
            assert not m.revise(1, true[1])  # unchanged pose: nothing to do
    with pytest.raises(AssertionError):
        _assert_same_memory(m, direct)
    m.revise(3, true[3])
    _assert_same_memory(m, direct)
    np.testing.assert_array_equal(m.prediction().labels, direct.prediction().labels)
    # deltas in a folder, data from a frame source, a checkpoint between integration and revision
    f = Mapper(cfg.mapper_config(), folder=tmp_path / "f", frame_source=frames)
    for i in range(N):
        f.integrate(frame(i, _moved(true[i], i) if i == 1 else true[i]))
        if i == 2:
            f.save()
    f.revise(1, true[1])  # frame 1 is committed: its new record counts from the next commit on
    f.close()  # waits for the background write (the mapper stays usable)
    f.save()
    f.close()
    _assert_same_memory(f, direct)
    d = tmp_path / "d"
    direct.save(d)
    assert (tmp_path / "f" / "memory.npz").read_bytes() == (d / "memory.npz").read_bytes()


def test_remove_equals_never_added_and_save_load(mapped, tmp_path):
    _, cfg, frames = mapped
    m = Mapper(cfg.mapper_config())
    for i in range(N):
        m.integrate(frames(i))
    without = Mapper(cfg.mapper_config())
    for i in range(N):
        if i != 2:
            without.integrate(frames(i))
    m.remove(2)
    assert m.frame_ids == [0, 1, 3, 4] == without.frame_ids
    _assert_same_memory(m, without)
    np.testing.assert_array_equal(m.prediction().labels, without.prediction().labels)
    with pytest.raises(PanovoccError, match="not in the map"):
        m.remove(2)
    with pytest.raises(PanovoccError, match="already in the map"):
        m.integrate(frames(3))
    # save / load round trip, ids 0 1 3 4 kept in memory.npz
    folder = m.save(tmp_path / "m")
    with np.load(folder / "memory.npz") as z:
        assert z["frame_ids"].tolist() == [0, 1, 3, 4] and int(z["frames_done"]) == 4
    back = Mapper.load(folder)
    assert back.frame_ids == [0, 1, 3, 4] and back.config == m.config
    _assert_same_memory(back, m)
    np.testing.assert_array_equal(back.prediction().labels, m.prediction().labels)
    # a loaded map keeps working: revising needs the frames' data, removing does not
    with pytest.raises(PanovoccError, match="frame_source"):
        back.revise(0, _moved(frames(0).T_world_cam, 1))
    back.frame_source = frames
    back.integrate(frames(2))  # put frame 2 back: equal to the full map
    full = Mapper(cfg.mapper_config())
    for i in range(N):
        full.integrate(frames(i))
    _assert_same_memory(back, full)
    back.remove(4)
    back.save()
    again = Mapper.load(folder)
    assert again.frame_ids == [0, 1, 2, 3]
    full.remove(4)
    _assert_same_memory(again, full)
    # a new mapper may not take over a folder that holds a map
    with pytest.raises(PanovoccError, match="already holds a map"):
        Mapper(cfg.mapper_config(), folder=folder)


def test_only_committed_records_count_and_a_torn_tail_is_cut(mapped, tmp_path):
    """The log's COMMIT records are the commit points: an uncommitted revision (a killed run) is cut off
    when the folder is opened; a committed one counts even without a new memory snapshot (replayed); a torn
    record at the end is cut back to the last commit. Each time the memory equals the direct sum."""
    _, cfg, frames = mapped

    def direct(poses):
        ref = Mapper(cfg.mapper_config())
        for i, T in poses.items():
            ref.integrate(dataclasses.replace(frames(i), T_world_cam=T))
        return ref

    folder = tmp_path / "m"
    m = Mapper(cfg.mapper_config(), folder=folder, frame_source=frames)
    for i in range(3):
        m.integrate(frames(i))
    m.save()
    true = {i: frames(i).T_world_cam for i in range(3)}
    T = _moved(true[1], 3)
    m.revise(1, T)
    m.close()  # killed here: the revision's record is on disk, not committed
    back = Mapper.load(folder)
    assert np.array_equal(back.pose(1), true[1])
    _assert_same_memory(back, direct(true))
    back.frame_source = frames
    back.revise(1, T)
    back.checkpoint()  # committed, memory.npz not rewritten
    back.integrate(frames(3))  # and one more frame after the commit, not committed
    back.close()
    again = Mapper.load(folder)
    assert again.frame_ids == [0, 1, 2] and np.array_equal(again.pose(1), T)
    _assert_same_memory(again, direct({**true, 1: T}))
    again.frame_source = frames
    again.integrate(frames(3))
    again.checkpoint()
    again.close()
    shard = mapstore.shard_path(folder, mapstore.shard_ids(folder)[-1])
    size = shard.stat().st_size
    with open(shard, "ab") as fh:  # a torn record after the last commit (a kill mid-write)
        fh.write(b"PVD1\x01" + b"\x00" * 40)
    torn = Mapper.load(folder)
    assert torn.frame_ids == [0, 1, 2, 3] and shard.stat().st_size == size
    _assert_same_memory(torn, direct({**true, 1: T, 3: frames(3).T_world_cam}))
    torn.close()


def test_frame_checks_and_empty_depth_frame(mapped):
    _, cfg, frames = mapped
    m = Mapper(cfg.mapper_config())
    f = frames(0)
    empty = Frame(f.rgb, np.zeros_like(f.depth), f.T_world_cam, f.camera, logits=f.logits)
    assert m.integrate(empty) == 0 and m.empty_frames == [0] and len(m.memory) == 0
    assert m.integrate(frames(1)) == 1
    g = m.prediction()
    assert (g.labels != 255).any()
    with pytest.raises(PanovoccError, match="logits have 3 classes"):
        m.integrate(Frame(f.rgb, f.depth, f.T_world_cam, f.camera, logits=f.logits[..., :3]))
    with pytest.raises(PanovoccError, match="depth is float64"):
        m.integrate(Frame(f.rgb, f.depth.astype(np.float64), f.T_world_cam, f.camera))
    with pytest.raises(PanovoccError, match="finite"):
        m.integrate(Frame(f.rgb, f.depth, np.full((4, 4), np.nan), f.camera))
    with pytest.raises(PanovoccError, match="2:1"):
        ErpCamera(64, 20)
    # a geometry-only mapper ignores logits
    geo = Mapper(MapperConfig(geometry=cfg.geometry, occupancy=cfg.occupancy))
    geo.integrate(frames(1))
    assert [c.name for c in geo.memory.specs] == ["A", "N", "F", "O", "P"]  # the fixture's map keeps P
    assert set(np.unique(geo.prediction().labels).tolist()) <= {0, 254, 255}


def test_map_with_an_empty_depth_frame_and_revise_without_the_old_pose_file(seq_dir, tmp_path, capsys):
    import shutil

    from panovocc_cli.cli import main

    seq = tmp_path / "seq"
    shutil.copytree(seq_dir, seq)
    from panovocc_cli.io.images import write_png

    write_png(seq / "depth" / "000002.png", np.zeros((W // 2, W), np.uint16))  # the sensor dropped frame 2
    wrong = circle_poses(N)
    wrong[3] = _moved(wrong[3], 1)
    write_poses(tmp_path / "wrong.txt", wrong)
    with pytest.raises(SystemExit) as e:
        main(["map", str(seq), str(tmp_path / "o"), "--poses", str(tmp_path / "wrong.txt"), "--quiet",
              "--checkpoint-every", "2"])
    io = capsys.readouterr()
    assert e.value.code == 0 and "1 frame(s) had no valid depth" in io.out and ": 2" in io.out
    (tmp_path / "wrong.txt").unlink()  # revise must not need the pose file the map was made with
    s = run_revise(tmp_path / "o", seq / "poses.txt", progress=False)
    assert s["revised"] == 1
    s2 = run_map(MapConfig(seq=str(seq), out=str(tmp_path / "direct"), checkpoint_every=0), progress=False)
    assert s2["empty_frames"] == [2]
    for name in ("memory.npz", "prediction.npz", "map.ply"):
        assert (tmp_path / "o" / name).read_bytes() == (tmp_path / "direct" / name).read_bytes(), name


def test_checkpoint_of_the_earlier_form_still_loads(mapped, tmp_path):
    """Checkpoints written before the streaming mapper listed the poses of all N frames beside frames_done."""
    _, cfg, frames = mapped
    m = Mapper(cfg.mapper_config())
    for i in range(2):
        m.integrate(frames(i))
    folder = m.save(tmp_path / "c")
    arrays, done, poses, ids = mapstore.read_memory(folder)
    assert done == 2 and poses.shape == (2, 4, 4) and ids is None
    mapstore.write_memory(folder, arrays, 2, np.stack([frames(i).T_world_cam for i in range(N)]))
    back = Mapper.load(folder, frame_source=frames)
    assert back.frame_ids == [0, 1]
    _assert_same_memory(back, m)
    for i in range(2, N):
        back.integrate(frames(i))
        m.integrate(frames(i))
    _assert_same_memory(back, m)


def test_observation_made_where_the_frame_is_read(mapped, seq_dir, tmp_path):
    """The map loop's reader (pipeline.observed): the frame's observation is made on the reading thread and
    its logits dropped (a prefetched frame then holds 4 bytes a pixel of semantics, not C floats); integrating
    the frame with that observation gives the same delta records and memory as integrating it with its
    logits, and wrong logits are refused in the same words."""
    from panovocc_cli.mapping.pipeline import observed

    out, cfg, frames = mapped
    a, b = Mapper(cfg.mapper_config()), Mapper(cfg.mapper_config())
    read = observed(frames, b)
    for i in range(N):
        f, obs = read(i)
        assert f.logits is None and f.features is None and obs is not None
        assert obs.classes.nbytes + obs.q.nbytes < frames(i).logits.nbytes / 10
        a.integrate(frames(i))
        b.integrate(f, obs)
        assert a.record(i) == b.record(i)
    _assert_same_memory(a, b)
    f = frames(0)
    bad = dataclasses.replace(f, logits=f.logits[..., :3])
    for call in (b.observe, Mapper(cfg.mapper_config()).integrate):
        with pytest.raises(PanovoccError, match="logits have 3 classes, the vocabulary 12"):
            call(bad)
    geo = Mapper(MapperConfig(geometry=cfg.mapper_config().geometry))
    g, obs = observed(frames, geo)(0)
    assert obs is None and g.logits is not None  # nothing to observe: the frame as read


def test_semantic_stride_run_api_and_revise_exact(seq_dir, tmp_path):
    """`map --semantic-stride 2`: the segmenter sees every 2nd pixel, the config records the stride, the
    API fed the same frames gives the same memory, full-size logits give the same delta as logits at the
    stride, and a revision is still exact."""
    out = tmp_path / "s2"
    run_map(MapConfig(seq=str(seq_dir), out=str(out), checkpoint_every=0, semantic_stride=2), progress=False)
    cfg = load_config(out)
    assert cfg.semantic_stride == 2 and cfg.semantic.weights.stride == 2
    frames = sequence_frames(cfg, Sequence(seq_dir))
    assert frames(0).logits.shape == (W // 4, W // 2, 12)
    loaded = Mapper.load(out)
    assert loaded.config.weights.stride == 2
    api = Mapper(cfg.mapper_config())
    for i in range(N):
        api.integrate(frames(i))
    _assert_same_memory(api, loaded)
    f = frames(1)
    full = np.repeat(np.repeat(f.logits, 2, axis=0), 2, axis=1)  # full size; its pixels (2i, 2j) = f.logits
    a, b = Mapper(cfg.mapper_config()), Mapper(cfg.mapper_config())
    a.integrate(f)
    b.integrate(dataclasses.replace(f, logits=full))
    _assert_same_memory(a, b)
    T = _moved(frames(3).T_world_cam, 11)
    api.revise(3, T)
    ref = Mapper(cfg.mapper_config())
    for i in range(N):
        ref.integrate(dataclasses.replace(frames(i), T_world_cam=T) if i == 3 else frames(i))
    _assert_same_memory(api, ref)


def test_one_parser_reads_a_map_config_for_the_run_and_the_mapper(mapped):
    """A map folder's config.json is read by one parser: the run's config (MapConfig) and the mapper's
    (MapperConfig, also what Mapper.load reads) accept and refuse the same sections, with the same line."""
    import copy
    import json

    from panovocc_cli.mapping.config import MapConfig as RunConfig

    out, cfg, _ = mapped
    d = json.loads((out / mapstore.CONFIG_NAME).read_text())
    assert MapperConfig.from_json(d) == cfg.mapper_config()
    assert MapperConfig.from_json(cfg.mapper_config().to_json()) == cfg.mapper_config()  # Mapper.save's form

    def edit(path, value):
        e = copy.deepcopy(d)
        *head, last = path
        node = e
        for k in head:
            node = node[k]
        if value is KeyError:
            del node[last]
        else:
            node[last] = value
        return e

    bad = [edit(("geometry", "voxel_size"), True),  # a bool where metres are expected (was read as 1 m)
           edit(("geometry", "stride"), 4.0),  # a float where a pixel count is expected
           edit(("geometry", "no_such_key"), 1),
           edit(("occupancy",), KeyError),
           edit(("format_version",), "3"),  # a string where the version number is expected
           edit(("format_version",), 99),
           edit(("semantic", "no_such_key"), 1),
           [1, 2]]
    for e in bad:
        with pytest.raises(PanovoccError) as run_err:
            RunConfig.from_json(e, "here/config.json")
        with pytest.raises(PanovoccError) as mapper_err:
            MapperConfig.from_json(e, "here/config.json")
        assert str(run_err.value) == str(mapper_err.value), e


def test_revision_never_calls_the_segmenter(seq_dir, tmp_path):
    """A revision takes the frame's semantics from the observation kept with its delta: the frame source
    gives depth and colours only (its logits, if any, are ignored), the segmenter is never called, and the
    map equals one built with the final pose from the start — in RAM, in a folder, and after a reload."""
    out = tmp_path / "m"
    run_map(MapConfig(seq=str(seq_dir), out=str(out), checkpoint_every=0), progress=False)
    cfg = load_config(out)
    frames = sequence_frames(cfg, Sequence(seq_dir))
    calls = []
    real = frames.segmenter.logits

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    frames.segmenter.logits = counting
    T = _moved(frames(2).T_world_cam, 5)
    ref = Mapper(cfg.mapper_config())
    for i in range(N):
        ref.integrate(dataclasses.replace(frames(i), T_world_cam=T) if i == 2 else frames(i))
    calls.clear()

    def wrong_logits(i):  # a source whose logits are garbage: they must not be used
        f = frames.read(i)
        return dataclasses.replace(f, logits=np.zeros((W // 2, W, 12), np.float32))

    m = Mapper.load(out, frame_source=wrong_logits)
    m.revise(2, T)
    _assert_same_memory(m, ref)
    m.save()
    m.close()
    _assert_same_memory(Mapper.load(out), ref)
    assert calls == []
    # in RAM with kept frames: the logits are dropped once the observation is made
    r = Mapper(cfg.mapper_config())
    for i in range(N):
        r.integrate(frames(i))
    assert all(f.logits is None for f in r._frames.values())
    calls.clear()
    r.revise(2, T)
    assert calls == []
    _assert_same_memory(r, ref)
    # the command: revise reads the sequence without building a segmenter
    write_poses(tmp_path / "p.txt", np.stack([T if i == 2 else frames.read(i).T_world_cam for i in range(N)]))
    run_revise(str(out), str(tmp_path / "p.txt"), progress=False)
    _assert_same_memory(Mapper.load(out), ref)


def test_a_semantic_map_of_an_older_format_is_refused_in_one_line(mapped, tmp_path):
    import json
    import shutil

    out, _, _ = mapped
    old = tmp_path / "old"
    shutil.copytree(out, old)
    d = json.loads((old / "config.json").read_text())
    d["format_version"] = 3
    (old / "config.json").write_text(json.dumps(d))
    with pytest.raises(PanovoccError, match="format 3.*map the sequence again"):
        Mapper.load(old)


def test_save_never_overwrites_a_config_it_cannot_prove_equal(mapped, tmp_path):
    """Mapper.save over a folder whose config.json is another map's, or unreadable, refuses in one line and
    writes nothing; a map made before local origins (no origin in config.json) saves over itself keeping its
    config.json, so map --resume and revise can still read it."""
    import json
    import shutil

    from cli_helpers import snapshot

    out, cfg, frames = mapped
    other = dataclasses.replace(cfg.mapper_config(), vocab=[])  # a geometry-only mapper
    m = Mapper(other)
    m.integrate(dataclasses.replace(frames(0), logits=None))
    for name, text in (("theirs", (out / "config.json").read_text()), ("broken", "{not json")):
        d = tmp_path / name
        d.mkdir()
        (d / "config.json").write_text(text)
        before = snapshot(d)
        with pytest.raises(PanovoccError, match="config.json") as e:
            m.save(d)
        assert "\n" not in str(e.value)
        assert snapshot(d) == before
    legacy = tmp_path / "legacy"
    shutil.copytree(out, legacy)
    d = json.loads((legacy / "config.json").read_text())
    d.pop("origin")
    (legacy / "config.json").write_text(json.dumps(d, indent=2) + "\n")
    text = (legacy / "config.json").read_text()
    back = Mapper.load(legacy)
    assert back.config.origin == [0.0, 0.0, 0.0]
    back.save(legacy)
    back.close()
    assert (legacy / "config.json").read_text() == text
    assert load_config(legacy).seq == cfg.seq


def test_revise_from_a_second_thread_while_integrate_runs_is_serialised_and_exact(mapped):
    """A SLAM thread revises frames while the main thread integrates: the mapper's lock lets one mutation
    run at a time (never interleaved), and the memory equals the sequential computation bit for bit."""
    import threading
    import time

    _, cfg, frames = mapped
    moved = {0: _moved(frames(0).T_world_cam, 5), 1: _moved(frames(1).T_world_cam, 6)}
    m = Mapper(cfg.mapper_config())
    m.integrate(frames(0))
    m.integrate(frames(1))
    events, errors, inside = [], [], threading.Event()
    real_keep, real_revise = m._rpu.keep, m._rpu.revise

    def keep(*a, **k):
        events.append("keep+")
        inside.set()
        time.sleep(0.05)  # a long update: the other thread has every chance to run meanwhile
        real_keep(*a, **k)
        events.append("keep-")

    def revise(*a, **k):
        events.append("revise+")
        real_revise(*a, **k)
        events.append("revise-")

    m._rpu.keep, m._rpu.revise = keep, revise

    def slam():
        try:
            inside.wait(10)
            for j, T in moved.items():
                m.revise(j, T)
        except BaseException as e:  # noqa: BLE001 - reported by the assertion below
            errors.append(e)

    t = threading.Thread(target=slam)
    t.start()
    for i in range(2, N):
        m.integrate(frames(i))
    t.join(30)
    assert not t.is_alive() and errors == []
    pairs = [events[k:k + 2] for k in range(0, len(events), 2)]
    assert all(a[:-1] == b[:-1] and a[-1] == "+" and b[-1] == "-" for a, b in pairs), events
    assert sorted(events) == sorted(["keep+", "keep-"] * (N - 2) + ["revise+", "revise-"] * 2)
    seq = Mapper(cfg.mapper_config())
    for i in range(N):
        f = frames(i)
        seq.integrate(dataclasses.replace(f, T_world_cam=moved.get(i, f.T_world_cam)))
    _assert_same_memory(m, seq)
    np.testing.assert_array_equal(m.prediction().labels, seq.prediction().labels)


def test_revise_many_equals_a_loop_of_revise(mapped, tmp_path):
    """``Mapper.revise_many`` (``panovocc revise``: frame i + 1's delta computed while frame i's is swapped in
    on a second thread) gives the memory and the delta records of a loop of ``revise``, bit for bit and
    equal to a map made with the final poses: a frame listed twice, an unchanged pose, frames out of order.
    A swap that fails is raised in order: the frames before it are revised, the frames after it are not."""
    import threading

    _, cfg, frames = mapped
    true = {i: frames(i).T_world_cam for i in range(N)}
    direct = Mapper(cfg.mapper_config())
    for i in range(N):
        direct.integrate(frames(i))

    def start(name):
        m = Mapper(cfg.mapper_config(), folder=tmp_path / name, frame_source=frames)
        for i in range(N):
            m.integrate(dataclasses.replace(frames(i), T_world_cam=_moved(true[i], i) if i != 3 else true[i]))
        m.save()
        return m

    plan = [(4, _moved(true[4], 9)), (0, true[0]), (3, true[3]), (4, true[4]), (2, true[2]), (1, true[1])]
    loop, many = start("loop"), start("many")
    assert sum(loop.revise(i, T) for i, T in plan) == 5
    threads, done, reads = set(), [], []
    real = many._rpu.revise
    many._rpu.revise = lambda *a, **k: (threads.add(threading.current_thread().name), real(*a, **k))[1]
    real_get = many._rpu.store.get
    many._rpu.store.get = lambda fid: (reads.append((int(fid), threading.current_thread().name)), real_get(fid))[1]
    assert many.revise_many([(i, T, None) for i, T in plan], done=done.append) == 5
    assert done == [4, 0, 4, 2, 1] and all(t.startswith("revise") for t in threads)
    # kept deltas read ahead on their own thread, except the first frame's and a frame listed again (read by
    # the calling thread once the swap in progress has ended); an unchanged pose reads nothing
    assert sorted(reads) == sorted([(4, "MainThread"), (0, "revise-read_0"), (4, "MainThread"),
                                    (2, "revise-read_0"), (1, "revise-read_0")])
    _assert_same_memory(many, loop)
    _assert_same_memory(many, direct)
    for i in range(N):
        assert many.record(i) == loop.record(i), i
    loop.close()

    failing = start("failing")
    real_replace = failing.memory.replace
    calls = []

    def replace(old, new):
        calls.append(1)
        if len(calls) == 3:
            raise PanovoccError("a memory channel would pass the int64 range")
        real_replace(old, new)

    failing.memory.replace = replace
    with pytest.raises(PanovoccError, match="int64"):
        failing.revise_many([(i, true[i], None) for i in (0, 1, 2, 4)])
    assert [np.array_equal(failing.pose(i), true[i]) for i in range(N)] == [True, True, False, True, False]
    failing.close()
    many.close()

    # a frame listed again with another changed frame between: its kept delta (which its first swap may still
    # be writing) is read only once the swap in progress has ended, never beside it
    again = start("again")
    events = []
    real_swap, real_revision = again._swap, again._revision
    again._swap = lambda fid, *a: (events.append(("swap", fid)), real_swap(fid, *a), events.append(("end", fid)))[1]
    again._revision = lambda fid, *a: (events.append(("revision", fid)), real_revision(fid, *a))[1]
    assert again.revise_many([(4, true[4], None), (0, true[0], None), (4, _moved(true[4], 9), None)]) == 3
    assert events.index(("end", 0)) < len(events) - 1 - events[::-1].index(("revision", 4))
    loop = start("loop2")
    for i, T in ((4, true[4]), (0, true[0]), (4, _moved(true[4], 9))):
        loop.revise(i, T)
    _assert_same_memory(again, loop)
    for i in range(N):
        assert again.record(i) == loop.record(i), i
    again.close()
    loop.close()


def test_poses_that_are_not_rigid_are_refused_naming_the_frame(mapped):
    """A scaled pose, a reflection or a matrix whose last row is not [0 0 0 1] (e.g. a transposed one) is
    refused by integrate and revise in one line naming the frame; the map is unchanged."""
    _, cfg, frames = mapped
    m = Mapper(cfg.mapper_config())
    m.integrate(frames(0))
    before = _arrays(m)
    f = frames(1)
    scaled, flipped, transposed = f.T_world_cam.copy(), f.T_world_cam.copy(), f.T_world_cam.T.copy()
    scaled[:3, :3] *= 1.01
    flipped[:, 0] *= -1
    for T in (scaled, flipped, transposed):
        with pytest.raises(PanovoccError, match=r"^frame 1: T_world_cam: (not rigid|last row)") as e:
            m.integrate(dataclasses.replace(f, T_world_cam=T))
        assert "\n" not in str(e.value)
        with pytest.raises(PanovoccError, match=r"^frame 0: T_world_cam: (not rigid|last row)"):
            m.revise(0, T)
    assert m.frame_ids == [0]
    after = _arrays(m)
    assert all(np.array_equal(before[k], after[k]) for k in before)
    assert m.integrate(dataclasses.replace(f, T_world_cam=f.T_world_cam + 1e-9)) == 1  # within the tolerance


@pytest.mark.parametrize("background", [True, FROZEN])
def test_a_background_save_writes_poses_only_after_its_commit(mapped, tmp_path, monkeypatch, background):
    """``save(background=True)`` (what ``map`` overlaps with its grid and PLY) and ``save(background=FROZEN)``
    (what ``revise`` overlaps with its export) write poses.txt after the memory's commit: a memory write that
    fails leaves poses.txt, memory.npz and the committed map as they were, and the error comes out of
    ``close``."""
    _, cfg, frames = mapped
    folder = tmp_path / "m"
    m = Mapper(cfg.mapper_config(), folder=folder, frame_source=frames)
    for i in range(3):
        m.integrate(frames(i))
    m.save()
    before = {n: (folder / n).read_bytes() for n in ("poses.txt", "memory.npz")}
    old_T = m.pose(1)
    m.revise(1, _moved(old_T, 4))

    def disk_full(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mapstore, "write_memory", disk_full)
    m.save(background=background)
    with pytest.raises(OSError, match="No space"):
        m.close()
    m._rpu.rollback()
    assert {n: (folder / n).read_bytes() for n in before} == before
    back = Mapper.load(folder)
    assert np.array_equal(back.pose(1), old_T)
    back.close()


def test_a_frozen_save_streams_the_memory_on_the_writer_thread_while_it_is_exported(mapped, tmp_path, monkeypatch):
    """``save(background=FROZEN)`` (``revise``, issue 21): memory.npz is streamed from the memory itself on the
    writer thread (no whole copy: ``to_arrays`` is never called) while the caller exports the same memory;
    memory.npz, poses.txt and the snapshot index are the bytes of a foreground save, and the export made
    meanwhile (with cubes of 4 voxels) labels as a later one with the default cube."""
    import threading

    from panovocc_cli.mapping.memory import MemoryChunks, VoxelMemory

    _, cfg, frames = mapped
    names = ("memory.npz", "poses.txt", "deltas/snapshot.npz")
    out = {}
    for arm in ("fg", "frozen"):
        folder = tmp_path / arm
        m = Mapper(cfg.mapper_config(), folder=folder, frame_source=frames)
        for i in range(4):
            m.integrate(frames(i))
        m.revise(2, _moved(m.pose(2), 5))
        if arm == "fg":
            m.save()
            ex = m.export(block=4)
        else:
            readers, real = [], MemoryChunks.chunks
            monkeypatch.setattr(MemoryChunks, "chunks", lambda self, *a, **k: (
                readers.append(threading.current_thread() is not threading.main_thread()), real(self, *a, **k))[1])
            monkeypatch.setattr(VoxelMemory, "to_arrays", lambda *a, **k: pytest.fail("a frozen save copies the memory"))
            m.save(background=FROZEN)
            ex = m.export(block=4)  # cubes of 4 voxels: many cubes, the same labels
            m.close()
            monkeypatch.undo()
            assert readers and all(readers)  # streamed on the writer thread only
        m.close()
        out[arm] = ({n: (folder / n).read_bytes() for n in names}, ex)
    assert out["fg"][0] == out["frozen"][0]
    a, b = out["fg"][1], out["frozen"][1]
    assert np.array_equal(a.grid.labels, b.grid.labels) and np.array_equal(a.labels, b.labels)
    back = Mapper.load(tmp_path / "frozen")
    ref = back.export()  # the default cube: the same labels as cubes of 4
    back.close()
    assert np.array_equal(ref.labels, b.labels) and np.array_equal(ref.grid.labels, b.grid.labels)


def test_a_kept_delta_is_freed_once_its_record_is_encoded_and_a_failed_write_is_undone_from_it(tmp_path,
                                                                                            monkeypatch):
    """The delta writer drops a new frame's delta once its record is made (it is not alive beside the next
    frame's working set); an append that fails after that is undone from the record: the memory again
    equals the sum of the frames the store keeps, bit for bit."""
    import errno
    import gc
    import threading
    import weakref

    from panovocc_cli.mapping.memory import Delta, FrameDelta, VoxelMemory
    from panovocc_cli.mapping.mapper import memory_channels
    from panovocc_cli.mapping.rpu import DeltaStore, ReversibleMemory

    cfg = MapperConfig()
    rng = np.random.default_rng(3)

    def delta(seed):
        keys = np.unique(np.random.default_rng(seed).integers(0, 10 ** 6, 5000))
        n = len(keys)
        return FrameDelta((Delta(keys, {"A": rng.integers(1, 2 ** 20, (n, 1)), "N": rng.integers(0, 2, (n, 1)),
                                        "F": rng.integers(0, 2, (n, 1)), "O": rng.integers(0, 2, (n, 1))}),))

    rm = ReversibleMemory(VoxelMemory(cfg.geometry.voxel_size, memory_channels(cfg)), DeltaStore(tmp_path / "m"))
    rm.keep(0, delta(0), np.eye(4))
    rm.store.flush()
    before = rm.memory.to_arrays()
    appended, go = threading.Event(), threading.Event()
    real = mapstore.DeltaLog.append

    def append(self, kind, fid, payload):  # the record is made; the write waits, then fails
        appended.set()
        go.wait(30)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(mapstore.DeltaLog, "append", append)
    d = delta(1)
    gone = weakref.ref(d)
    rm.keep(1, d, np.eye(4))
    del d
    assert appended.wait(30)
    gc.collect()
    assert gone() is None  # freed while its record is still being written
    go.set()
    with pytest.raises(PanovoccError, match=r"cannot write the delta of frame 1 \(No space left on device\)"):
        rm.checkpoint()
    monkeypatch.setattr(mapstore.DeltaLog, "append", real)
    assert rm.store.ids() == [0]
    after = rm.memory.to_arrays()
    assert sorted(after) == sorted(before)
    for k in before:
        np.testing.assert_array_equal(after[k], before[k])
    rm.close()
