"""Mapping past one machine (issue 23): --frames ranges, shards on Dask workers, merges of maps.

The map of a sequence is the exact integer sum of its frames' deltas, so a sharded run, a run killed and
resumed, and the merge of maps of disjoint frame ranges all give the sequential run's folder bit for bit:
memory.npz, prediction.npz, map.ply, poses.txt and the delta log (every record's bytes, in frame order)."""

import os

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.io.sequence import SequenceMeta, write_frame, write_meta, write_sequence_poses
from panovocc_cli.mapping.pipeline import MapConfig, run_map
from panovocc_cli.rendering.raycast import RaycastRenderer
from room_sequence import room_scene, room_trajectory

W = 128
N = 8
OUTPUTS = ("memory.npz", "prediction.npz", "map.ply", "poses.txt", "config.json", "deltas/shard-000000.pvd",
           "deltas/commits.pvj", "deltas/snapshot.npz")


def write_labelled_room(seq, n, width, poses=None):
    """The furnished box room rendered with its class labels (semantic/), so maps of it carry semantics."""
    scene = room_scene(True)
    ren = RaycastRenderer(scene, width)
    poses = room_trajectory(n) if poses is None else poses
    for i, T in enumerate(poses):
        fr = ren.render(T)
        write_frame(seq, i, fr.rgb, fr.depth, fr.labels)
    write_meta(seq, SequenceMeta(width=width, height=width // 2, frames=len(poses), class_names=scene.class_names))
    write_sequence_poses(seq, poses)
    return poses


@pytest.fixture(scope="module")
def labelled_room(tmp_path_factory):
    seq = tmp_path_factory.mktemp("shards") / "room"
    write_labelled_room(seq, N, W)
    return seq


def _cfg(seq, out, **kw):
    kw.setdefault("checkpoint_every", 3)
    kw.setdefault("semantic", _semantic())
    return MapConfig(seq=str(seq), out=str(out), **kw)


def _semantic():
    from panovocc_cli.mapping.config import SemanticParams

    return SemanticParams(vocab="wall,table,cabinet,shelf")


def folder_bytes(out, names=OUTPUTS, config=False):
    got = {}
    for n in names:
        if n == "config.json" and not config:
            continue
        got[n] = (out / n).read_bytes()
    return got


@pytest.fixture(scope="module")
def sequential(labelled_room, tmp_path_factory):
    out = tmp_path_factory.mktemp("seqmap") / "map"
    run_map(_cfg(labelled_room, out), progress=False)
    return out


def test_frames_range_keeps_sequence_ids_and_refuses_bad_ranges(labelled_room, tmp_path):
    from panovocc_cli.mapping import Mapper
    from panovocc_cli.mapping.config import frame_ids

    out = tmp_path / "part"
    s = run_map(_cfg(labelled_room, out, frames="2:5"), progress=False)
    assert s["integrated"] == 3
    m = Mapper.load(out)
    try:
        assert m.frame_ids == [2, 3, 4]
    finally:
        m.close()
    assert frame_ids("0:2,5:", 8).tolist() == [0, 1, 5, 6, 7]
    for bad in ("5:2", "0:9", "a:b", "3", "0:4,2:6", ":"):
        with pytest.raises(PanovoccError, match="--frames"):
            run_map(_cfg(labelled_room, tmp_path / f"bad{len(bad)}", frames=bad), progress=False)
        assert not (tmp_path / f"bad{len(bad)}").exists()


def _records(out):
    """Every delta record of a map folder, in log order: (kind, frame id, payload bytes)."""
    from panovocc_cli.io.mapstore import DeltaLog

    log = DeltaLog(out)
    try:
        return [(kind, fid, log.read(loc)) for kind, fid, loc in log.records]
    finally:
        log.close()


def test_sharded_runs_equal_the_sequential_map_for_1_2_3_workers_and_a_killed_worker(labelled_room, sequential,
                                                                                       tmp_path):
    from distributed import Client, LocalCluster

    from panovocc_cli.benchmark.runner import WORKER_ENV
    from panovocc_cli.benchmark.sharded import EXIT_HOOK_ENV, DaskShards

    want = folder_bytes(sequential)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0", env=WORKER_ENV,
                      silence_logs=50) as cluster, Client(cluster) as client:
        for n in (1, 2, 3):
            cluster.scale(n)
            client.wait_for_workers(n)
            out = tmp_path / f"w{n}"
            shards = DaskShards(client, shards_per_worker=2)
            s = run_map(_cfg(labelled_room, out), progress=False, shards=shards)
            assert s["integrated"] == N and shards.stats["workers"] == n and shards.stats["shards"] == min(N, 2 * n)
            assert folder_bytes(out) == want, n
        # a worker process that exits in the middle of a shard: the shard is computed again elsewhere
        mark = tmp_path / "exited"
        client.run(lambda: os.environ.__setitem__(EXIT_HOOK_ENV, str(mark)))
        pids = set(client.run(os.getpid).values())
        out = tmp_path / "killed"
        run_map(_cfg(labelled_room, out), progress=False, shards=DaskShards(client, shards_per_worker=1, warm=False))
        assert mark.exists()  # a worker did exit mid-shard ...
        client.wait_for_workers(3)
        assert set(client.run(os.getpid).values()) != pids  # ... and was replaced by the nanny
        assert folder_bytes(out) == want
    assert [r[:2] for r in _records(out)] == [(1, i) for i in range(N)]
