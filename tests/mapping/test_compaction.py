"""Compaction of the delta log: the records a revision or a removal leaves dead are dropped, at checkpoints
once they pass half the live bytes and on demand (``panovocc compact``), and the map is unchanged."""

import errno

import numpy as np
import pytest
from semantics_helpers import write_labelled_room

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io import mapstore
from panovocc_cli.io.poses import write_poses
from panovocc_cli.io.sequence import Sequence
from panovocc_cli.mapping import Mapper
from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.pipeline import MapConfig, load_config, run_map, run_revise, sequence_frames
from panovocc_cli.mapping.rpu import COMPACT_DEAD_SHARE

W = 64
N = 5
PLAN = [1 + r % (N - 1) for r in range(28)]  # the frames revised, in turn


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """The labelled room (64x32, 5 frames) mapped with the simulated segmenter: (seq, map folder, frame source)."""
    seq = write_labelled_room(tmp_path_factory.mktemp("cseq") / "room", W, N)
    out = tmp_path_factory.mktemp("cmap") / "m"
    run_map(MapConfig(seq=str(seq), out=str(out), checkpoint_every=0, geometry=GeometryParams()), progress=False)
    cfg = load_config(out)
    return seq, out, cfg, sequence_frames(cfg, Sequence(seq))


def _jittered(T, rng):
    out = T.copy()
    a = rng.normal(0, 0.02)
    c, s = np.cos(a), np.sin(a)
    out[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ out[:3, :3]
    out[:3, 3] += rng.normal(0, 0.05, 3)
    return out


def _memory(m):
    return m.memory.to_arrays()


def _same(a, b):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def _log_bytes(folder):
    return sum(mapstore.shard_path(folder, s).stat().st_size for s in mapstore.shard_ids(folder))


def _saved_map(cfg, frames, folder):
    """A mapper keeping its deltas in ``folder``: the five frames integrated and saved."""
    m = Mapper(cfg.mapper_config(), folder=folder, frame_source=frames)
    for i in range(N):
        m.integrate(frames(i))
    m.save()
    return m


def _records(m):
    """Each kept frame's record payload, by frame id."""
    return {i: m._rpu.store.payload(i) for i in m.frame_ids}


def test_checkpoints_compact_the_log_and_the_map_equals_the_direct_one(room, tmp_path, monkeypatch):
    """Frames revised 28 times with checkpoints between: the log stays below (1 + COMPACT_DEAD_SHARE) times
    its live records plus a shard (here a few records), the memory equals the one built from the final poses
    bit for bit, and the folder reopens to it (its snapshot deleted by a compacting checkpoint: rebuilt
    from the log) with every frame's record as it was."""
    _, _, cfg, frames = room
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 350_000)
    rng = np.random.default_rng(4)
    true = [frames(i).T_world_cam for i in range(N)]
    m = _saved_map(cfg, frames, tmp_path / "f")
    worst = 0.0
    for r, i in enumerate(PLAN):  # frame 0 is never revised: its record shares a shard with dead ones
        m.revise(i, true[i] if r >= len(PLAN) - N + 1 else _jittered(true[i], rng))
        m.checkpoint()
        m.flush()
        live = m._rpu.store.nbytes()
        worst = max(worst, (_log_bytes(tmp_path / "f") - 2 * mapstore.SHARD_BYTES) / live)
    m.close()
    store = m._rpu.store
    assert len(store.compactions) >= 3 and any(copied for _, _, copied in store.compactions)
    assert worst <= 1 + COMPACT_DEAD_SHARE
    assert not (tmp_path / "f" / "deltas" / "snapshot.npz").exists()  # deleted with the shards it pointed into
    direct = Mapper(cfg.mapper_config())
    for i in range(N):
        direct.integrate(frames(i))
    _same(_memory(m), _memory(direct))
    again = Mapper.load(tmp_path / "f")
    _same(_memory(again), _memory(direct))
    assert _records(again) == _records(m)
    again.close()
    # without compaction the same run's log keeps every record: about (1 + 28 / N) times the live ones
    g = Mapper(cfg.mapper_config(), folder=tmp_path / "g", frame_source=frames)
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 10 ** 12)
    for i in range(N):
        g.integrate(frames(i))
    rng = np.random.default_rng(4)
    for r, i in enumerate(PLAN):
        g.revise(i, true[i] if r >= len(PLAN) - N + 1 else _jittered(true[i], rng))
        g.checkpoint()
    g.close()
    assert _log_bytes(tmp_path / "g") > 5 * _log_bytes(tmp_path / "f") / (1 + COMPACT_DEAD_SHARE)
    assert _records(g) == _records(m)


def test_a_compaction_that_cannot_write_leaves_the_map_as_it_was(room, tmp_path, monkeypatch):
    """Disk full while the live records are copied: one line, the copies cut off, no shard deleted, and
    the folder reopens to the memory of its last commit."""
    _, _, cfg, frames = room
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 700_000)  # the first shard: the five frames' first records
    m = _saved_map(cfg, frames, tmp_path / "f")
    rng = np.random.default_rng(1)
    true = [frames(i).T_world_cam for i in range(N)]
    for r in range(15):  # frames 0 and 1 stay: two live records to copy out of the first shard
        m.revise(2 + r % 3, _jittered(true[2 + r % 3], rng))
    m.flush()
    before = {s: mapstore.shard_path(tmp_path / "f", s).read_bytes() for s in mapstore.shard_ids(tmp_path / "f")}
    assert m._rpu.store.compaction_victims()
    held = _memory(m)
    real = mapstore.DeltaLog.append
    calls = []

    def append(self, kind, fid, payload):
        calls.append(fid)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, kind, fid, payload)

    monkeypatch.setattr(mapstore.DeltaLog, "append", append)
    with pytest.raises(PanovoccError, match="cannot compact the delta log .*No space left.*the map is as it was"):
        m.checkpoint()
    monkeypatch.setattr(mapstore.DeltaLog, "append", real)
    after = {s: mapstore.shard_path(tmp_path / "f", s).read_bytes() for s in mapstore.shard_ids(tmp_path / "f")}
    assert after == before  # the copy made was cut off again
    _same(_memory(m), held)
    m.checkpoint()  # the disk has room again: the same compaction goes through
    m.close()
    assert m._rpu.store.compactions and _log_bytes(tmp_path / "f") < sum(map(len, before.values()))
    again = Mapper.load(tmp_path / "f")
    _same(_memory(again), held)
    again.close()


def test_compact_command_drops_dead_records_and_changes_nothing_else(room, tmp_path, capsys):
    """`panovocc compact` after three `revise` runs and a removal: the log shrinks to the kept records,
    memory.npz, the exports and every kept record keep their bytes, a second run has nothing to do, and a
    folder that is not a map gets one line, exit 2."""
    import shutil

    from cli_helpers import run_cli

    seq, src, _, _ = room
    out = tmp_path / "m"
    shutil.copytree(src, out)
    poses = Sequence(seq).poses
    rng = np.random.default_rng(2)
    for r in range(3):
        moved = np.stack([_jittered(T, rng) for T in poses]) if r < 2 else poses
        write_poses(tmp_path / f"p{r}.txt", moved)
        run_revise(str(out), str(tmp_path / f"p{r}.txt"), progress=False)
    m = Mapper.load(out)
    m.remove(4)
    m.save()
    kept, held = _records(m), _memory(m)
    m.close()
    files = {n: (out / n).read_bytes() for n in ("memory.npz", "prediction.npz", "map.ply", "poses.txt")}
    before = _log_bytes(out)
    code, stdout, stderr = run_cli(capsys, ["compact", str(out)])
    assert code == 0, stderr
    after = _log_bytes(out)
    assert f"{before / 1e6:.1f} MB -> {after / 1e6:.1f} MB" in stdout
    assert after == sum(len(p) + mapstore.RECORD_HEADER_BYTES for p in kept.values())
    assert {n: (out / n).read_bytes() for n in files} == files
    again = Mapper.load(out)
    assert _records(again) == kept and again.frame_ids == [0, 1, 2, 3]
    _same(_memory(again), held)
    again.close()
    code, stdout, _ = run_cli(capsys, ["compact", str(out)])
    assert code == 0 and stdout.startswith("nothing to compact: 4 frames")
    assert _log_bytes(out) == after
    code, stdout, stderr = run_cli(capsys, ["compact", str(tmp_path)])
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


def test_a_removal_stays_removed_when_its_drop_record_is_compacted(room, tmp_path, monkeypatch):
    """Frame 1 removed while its first record sits in a shard that stays (mostly live): the shard holding
    its DROP is compacted, the DROP is written again, and the reopened map does not bring frame 1 back."""
    _, _, cfg, frames = room
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 700_000)  # the first shard: the five frames' first records
    m = _saved_map(cfg, frames, tmp_path / "f")
    rng = np.random.default_rng(3)
    T4 = frames(4).T_world_cam
    m.revise(4, _jittered(T4, rng))
    m.remove(1)
    for _ in range(8):
        m.revise(4, _jittered(T4, rng))
    m.revise(4, T4)
    m.checkpoint()
    m.close()
    store = m._rpu.store
    assert store.compactions and 0 in mapstore.shard_ids(tmp_path / "f")  # the first shard stayed
    drops = [fid for s in mapstore.shard_ids(tmp_path / "f") for kind, fid, _ in store._log.headers(s)
             if kind == mapstore.DROP]
    assert drops == [1]
    direct = Mapper(cfg.mapper_config())
    for i in (0, 2, 3, 4):
        direct.integrate(frames(i))
    again = Mapper.load(tmp_path / "f")
    assert again.frame_ids == [0, 2, 3, 4]
    _same(_memory(again), _memory(direct))
    again.close()


def test_every_shard_is_on_disk_before_the_commit_that_covers_it(room, tmp_path, monkeypatch):
    """A commit fsyncs the shard it ends in; a shard closed since the last commit is fsynced when it is
    closed, so a power cut after the commit cannot lose records the journal says are there."""
    import os

    _, _, cfg, frames = room
    monkeypatch.setattr(mapstore, "SHARD_BYTES", 1)  # every record starts a shard of its own
    synced, real = [], os.fsync
    monkeypatch.setattr(mapstore.os, "fsync", lambda fd: (synced.append(os.readlink(f"/proc/self/fd/{fd}")), real(fd))[1])
    m = _saved_map(cfg, frames, tmp_path / "f")
    m.close()
    shards = [str(mapstore.shard_path(tmp_path / "f", s)) for s in mapstore.shard_ids(tmp_path / "f")]
    assert len(shards) == N and set(shards) <= set(synced)
