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


def write_labelled_room(seq, n, width, poses=None, world=None):
    """The furnished box room rendered with its class labels (semantic/), so maps of it carry semantics;
    ``world`` (4, 4): the poses written are ``world @ pose`` (the same capture, recorded in another world)."""
    scene = room_scene(True)
    ren = RaycastRenderer(scene, width)
    poses = room_trajectory(n) if poses is None else poses
    for i, T in enumerate(poses):
        fr = ren.render(T)
        write_frame(seq, i, fr.rgb, fr.depth, fr.labels)
    write_meta(seq, SequenceMeta(width=width, height=width // 2, frames=len(poses), class_names=scene.class_names))
    write_sequence_poses(seq, poses if world is None else np.einsum("ij,njk->nik", world, poses))
    return poses


@pytest.fixture(scope="module")
def labelled_room(tmp_path_factory):
    seq = tmp_path_factory.mktemp("shards") / "room"
    write_labelled_room(seq, N, W)
    return seq


def _cfg(seq, out, **kw):
    """The run's config: semantic, with the surface-offset channel P (every shard, merge and resume below sums
    it exactly like the other channels)."""
    from panovocc_cli.mapping.params import GeometryParams

    kw.setdefault("checkpoint_every", 3)
    kw.setdefault("semantic", _semantic())
    kw.setdefault("geometry", GeometryParams(offsets=True))
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
    # a --frames run killed after 1 frame resumes to the uninterrupted run's bytes
    cut = tmp_path / "cut"
    run_map(_cfg(labelled_room, cut, frames="2:5"), progress=False, stop_after=1)
    run_map(resume_out=cut, progress=False)
    assert folder_bytes(cut) == folder_bytes(out)
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


class _Steps:
    """A progress bar's stand-in that records each step it is moved by, and moves the bar."""

    def __init__(self, bar, steps):
        self.bar, self.steps = bar, steps

    def update(self, k):
        self.steps.append(k)
        self.bar.update(k)


def test_sharded_runs_equal_the_sequential_map_for_1_2_3_workers_and_a_killed_worker(labelled_room, sequential,
                                                                                       tmp_path):
    from distributed import Client, LocalCluster

    from panovocc_cli.benchmark.runner import WORKER_ENV
    from panovocc_cli.benchmark.sharded import EXIT_HOOK_ENV, DaskShards

    class CountingShards(DaskShards):
        """DaskShards whose progress bar (handed over by run_map) records each step it is moved by."""

        @property
        def progress(self):
            return self._bar

        @progress.setter
        def progress(self, bar):
            self.steps = []
            self._bar = None if bar is None else _Steps(bar, self.steps)

    want = folder_bytes(sequential)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0", env=WORKER_ENV,
                      silence_logs=50) as cluster, Client(cluster) as client:
        for n in (1, 2, 3):
            cluster.scale(n)
            client.wait_for_workers(n)
            out = tmp_path / f"w{n}"
            shards = CountingShards(client, shards_per_worker=2)
            s = run_map(_cfg(labelled_room, out), progress=False, shards=shards)
            assert s["integrated"] == N and shards.stats["workers"] == n and shards.stats["shards"] == min(N, 2 * n)
            assert folder_bytes(out) == want, n
            # the bar moved as the workers integrated frames (their events), not in shard-sized steps
            # only, and ended at the frame count
            assert sum(shards.steps) == N and len(shards.steps) > min(N, 2 * n), shards.steps
        # a run killed after 3 frames, resumed on the workers
        out = tmp_path / "resumed"
        run_map(_cfg(labelled_room, out), progress=False, stop_after=3)
        run_map(resume_out=out, progress=False, shards=DaskShards(client))
        assert folder_bytes(out) == want
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
        # workers of another checkout (their code fingerprint differs): one line, before anything is written
        client.run(lambda: setattr(__import__("panovocc_cli.benchmark.tasks", fromlist=["x"]), "code_fingerprint",
                                   lambda: "f" * 64))
        with pytest.raises(PanovoccError, match="a worker: this worker runs other code"):
            DaskShards(client).check_workers()
    assert [r[:2] for r in _records(out)] == [(1, i) for i in range(N)]


def test_merging_two_halves_equals_the_whole_map_and_revises_like_it(labelled_room, sequential, tmp_path, capsys):
    from cli_helpers import run_cli

    from panovocc_cli.io.poses import write_poses
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping.pipeline import run_revise

    a, b, out = tmp_path / "a", tmp_path / "b", tmp_path / "ab"
    run_map(_cfg(labelled_room, a, frames="0:3"), progress=False)
    run_map(_cfg(labelled_room, b, frames="3:"), progress=False)
    code, so, err = run_cli(capsys, ["merge", b, a, out, "--quiet"])  # in any order
    assert code == 0, err
    assert f"merged 2 maps ({N} frames)" in so
    assert folder_bytes(out) == folder_bytes(sequential)
    assert _records(out) == _records(sequential)  # every record, byte for byte, in frame order
    with np.load(out / "memory.npz") as z:  # the surface-offset channel P is part of what is summed exactly
        assert "ch_P" in z and np.asarray(z["ch_P"]).any()
    # the merged map revises exactly as the whole map does
    poses = Sequence(labelled_room).poses.copy()
    poses[5][:3, 3] += [0.03, -0.02, 0.0]
    write_poses(tmp_path / "moved.txt", poses)
    import shutil

    whole = tmp_path / "whole"
    shutil.copytree(sequential, whole)
    assert run_revise(out, tmp_path / "moved.txt", progress=False)["revised"] == 1
    run_revise(whole, tmp_path / "moved.txt", progress=False)
    assert folder_bytes(out) == folder_bytes(whole)
    # refused with one line, nothing written: colliding ids, other parameters, an existing OUT
    code, _, err = run_cli(capsys, ["merge", a, a, tmp_path / "x"])
    assert code == 2 and "frame 0 is in both" in err and "--renumber" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()
    c = tmp_path / "c"
    run_map(_cfg(labelled_room, c, frames="3:", semantic=__import__("panovocc_cli.mapping.config", fromlist=["x"])
                 .SemanticParams(vocab="wall,table")), progress=False)
    code, _, err = run_cli(capsys, ["merge", a, c, tmp_path / "x"])
    assert code == 2 and "vocab" in err and str(c) in err and not (tmp_path / "x").exists()
    code, _, err = run_cli(capsys, ["merge", a, b, out])
    assert code == 2 and "--overwrite" in err


def test_merging_separate_captures_renumbers_and_equals_one_map_of_both(labelled_room, tmp_path, capsys):
    """Two captures of the room (other trajectories) in one world frame: the merge equals mapping the
    frames of both as one sequence, and a transform re-integrates the second capture in the first's frame."""
    from cli_helpers import run_cli

    from panovocc_cli.io.sequence import Sequence

    p1 = Sequence(labelled_room).poses.copy()
    p2 = p1[::-1].copy()
    p2[:, :3, 3] += [0.11, 0.07, 0.0]
    both = tmp_path / "both"
    write_labelled_room(both, 0, W, poses=np.concatenate([p1[:4], p2[:4]]))
    second = tmp_path / "second"
    write_labelled_room(second, 0, W, poses=p2[:4])
    origin = [0.0, 0.0, 1.2]
    from panovocc_cli.mapping.config import SemanticParams

    geo = SemanticParams(segmenter="none")  # the simulated segmenter's noise is seeded by the frame id
    m1, m2, m12, ref = (tmp_path / n for n in ("m1", "m2", "m12", "ref"))
    run_map(_cfg(labelled_room, m1, frames="0:4", origin=origin, semantic=geo), progress=False)
    run_map(_cfg(second, m2, origin=origin, semantic=geo), progress=False)
    run_map(_cfg(both, ref, origin=origin, semantic=geo), progress=False)
    code, _, err = run_cli(capsys, ["merge", m1, m2, m12 / "x"])
    assert code == 2 and "--renumber" in err
    code, _, err = run_cli(capsys, ["merge", m1, m2, m12, "--renumber", "--quiet"])
    assert code == 0, err
    skip = ("poses.txt", "config.json")  # the same poses; config.json names the sources
    assert folder_bytes(m12, [n for n in OUTPUTS if n not in skip]) == folder_bytes(ref, [n for n in OUTPUTS
                                                                                         if n not in skip])
    code, _, err = run_cli(capsys, ["revise", m12, tmp_path / "none.txt"])
    assert code == 2 and "several sequences" in err
    # the second capture made in a world moved by T: --transform T^-1 brings it back, exactly
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.5, -0.25, 0.0]
    moved = tmp_path / "moved"
    write_labelled_room(moved, 0, W, poses=p2[:4], world=T)
    mm = tmp_path / "mm"
    run_map(_cfg(moved, mm, semantic=geo), progress=False)
    Tinv = np.linalg.inv(T)
    (tmp_path / "T.txt").write_text("\n".join(" ".join(repr(float(v)) for v in row) for row in Tinv) + "\n")
    code, so, err = run_cli(capsys, ["merge", m1, mm, tmp_path / "mT", "--renumber", "--transform",
                                     tmp_path / "T.txt", "--quiet"])
    assert code == 0, err
    from map_helpers import load_memory

    got, ref_mem = load_memory(tmp_path / "mT")[0], load_memory(m12)[0]
    k1, c1 = got.nonzero()
    k2, c2 = ref_mem.nonzero()
    # the moved capture brought back by the inverse (here exactly representable: the poses come back bit for
    # bit) gives the direct merge's voxels and grid
    from panovocc_cli.io.grid import read_grid

    assert np.array_equal(k1, k2)
    assert np.array_equal(read_grid(tmp_path / "mT" / "prediction.npz").labels, read_grid(m12 / "prediction.npz").labels)


def test_cli_map_on_workers_and_its_refusals(labelled_room, sequential, tmp_path, capsys):
    from cli_helpers import run_cli

    from panovocc_cli.benchmark.runner import dask_client
    from panovocc_cli.benchmark.sharded import code_task, shard_task

    out = tmp_path / "cli"
    code, so, err = run_cli(capsys, ["map", labelled_room, out, "--workers", "2", "--checkpoint-every", "3",
                                     "--vocab", "wall,table,cabinet,shelf", "--offsets", "--quiet",
                                     "--shards-per-worker", "4"])
    assert code == 0, err
    # 8 shards: a tree of sums on the workers down to two, which the client adds
    assert f"mapped {N} of {N} frames" in so and "shards: 8 on 2 worker(s)" in so
    assert "ms of CPU a frame" in so and "update 0.0 ms" not in so  # the workers' figure, not the client's
    assert folder_bytes(out) == folder_bytes(sequential)
    code, _, err = run_cli(capsys, ["map", labelled_room, tmp_path / "f", "--shards-per-worker", "2"])
    assert code == 2 and "--shards-per-worker needs --workers" in err and not (tmp_path / "f").exists()
    # one line, exit 2, nothing written
    code, _, err = run_cli(capsys, ["map", labelled_room, tmp_path / "f", "--frames", "6:3"])
    assert code == 2 and "--frames 6:3" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "f").exists()
    code, _, err = run_cli(capsys, ["map", labelled_room, tmp_path / "f", "--workers", "2", "--scheduler", "x"])
    assert code == 2 and "not both" in err
    code, _, err = run_cli(capsys, ["map", labelled_room, tmp_path / "f", "--workers", "1", "--frame-times",
                                    tmp_path / "t.csv"])
    assert code == 2 and "--frame-times" in err and not (tmp_path / "f").exists()
    with pytest.raises(PanovoccError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        with dask_client("tcp://127.0.0.1:9", timeout="2s"):
            pass
    with pytest.raises(PanovoccError, match="this worker runs other code"):  # what a worker of another checkout says
        shard_task("{}", "0" * 64, [0, 1])
    with pytest.raises(PanovoccError, match="a worker: this worker runs other code"):
        code_task("0" * 64)


def test_align_finds_the_transform_between_two_captures(labelled_room, tmp_path, capsys):
    """--align: the room captured again in a world shifted by a few centimetres and turned by 2 degrees;
    GICP of the occupied voxels recovers the transform to within a fraction of a voxel."""
    from cli_helpers import run_cli

    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping.config import SemanticParams
    from panovocc_cli.mapping.merge import occupied_points
    from panovocc_cli.slam.registration import register_points

    geo = SemanticParams(segmenter="none")
    p = Sequence(labelled_room).poses.copy()
    a = np.deg2rad(2.0)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = [0.06, -0.04, 0.02]
    moved = tmp_path / "moved"
    write_labelled_room(moved, 0, W, poses=p[4:8], world=T)
    m1, m2 = tmp_path / "m1", tmp_path / "m2"
    run_map(_cfg(labelled_room, m1, frames="0:4", semantic=geo), progress=False)
    run_map(_cfg(moved, m2, semantic=geo), progress=False)
    found, fitness = register_points(occupied_points(m1), occupied_points(m2))
    err = np.linalg.inv(T) @ np.linalg.inv(found)  # identity when found = T^-1
    assert fitness > 0.5
    assert np.abs(err[:3, 3]).max() < 0.02 and np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 0.5
    code, so, e = run_cli(capsys, ["merge", m1, m2, tmp_path / "m12", "--renumber", "--align", "--quiet"])
    assert code == 0, e
    assert "--align: MAP_B registered onto MAP_A" in so


def test_a_renumbered_merge_of_one_sequence_is_not_revised_from_the_wrong_frames(labelled_room, tmp_path, capsys):
    from cli_helpers import run_cli

    from panovocc_cli.mapping.config import SemanticParams

    geo = SemanticParams(segmenter="none")
    a, b, out = tmp_path / "a", tmp_path / "b", tmp_path / "ab"
    run_map(_cfg(labelled_room, a, frames="0:2", semantic=geo), progress=False)
    run_map(_cfg(labelled_room, b, frames="2:4", semantic=geo), progress=False)
    code, _, err = run_cli(capsys, ["merge", a, b, out, "--renumber", "--quiet"])  # b's ids become 4, 5
    assert code == 0, err
    code, _, err = run_cli(capsys, ["revise", out, labelled_room / "poses.txt"])
    assert code == 2 and "cannot be revised" in err
