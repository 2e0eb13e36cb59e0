"""Semantic mapping: labelled occupied voxels, exact revise/resume with semantics, vocabularies, CLI."""

import json

import numpy as np
import pytest
from map_helpers import load_memory
from semantics_helpers import CLASS_NAMES, circle_poses, write_labelled_room

from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import read_grid
from panovocc_cli.io.poses import write_poses
from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.memory import FIXED_SCALE
from panovocc_cli.mapping.pipeline import MapConfig, run_map, run_revise
from panovocc_cli.evaluation.reference import relabel_from_ground_truth
from panovocc_cli.mapping.config import SemanticParams

W = 128
N = 6



@pytest.fixture(scope="module")
def sem_seq(tmp_path_factory):
    """The furnished room of semantics_helpers (walls at x = +-2.5, y = +-3), labelled, 128x64, 6 frames."""
    seq = tmp_path_factory.mktemp("semseq") / "room"
    return write_labelled_room(seq, W, N)


@pytest.fixture(scope="module")
def default_map(sem_seq, tmp_path_factory):
    out = tmp_path_factory.mktemp("defmap") / "m"
    s = run_map(_cfg(sem_seq, out), progress=False)
    return out, s


def _cfg(seq, out, **sem):
    return MapConfig(seq=str(seq), out=str(out), checkpoint_every=2, geometry=GeometryParams(),
                     semantic=SemanticParams(**sem))


def _bytes(out):
    return {n: (out / n).read_bytes() for n in ("memory.npz", "prediction.npz", "map.ply")}


def _centres(g: Grid):
    return g.centers(np.argwhere(np.ones(g.labels.shape, bool))).reshape(g.labels.shape + (3,))


def _clean_wall(g: Grid):
    """Occupied voxels on the bare part of the wall x = -2.5 (y in [-1, 0.5], z in [0.8, 2.2])."""
    c = _centres(g)
    band = (np.abs(c[..., 0] + 2.5) < 0.09) & (c[..., 1] > -1.0) & (c[..., 1] < 0.5) & (c[..., 2] > 0.8) \
        & (c[..., 2] < 2.2)
    return band & (g.labels != 0) & (g.labels != 255)


def test_noisy_wall_ends_up_wall(default_map):
    out, s = default_map
    g = read_grid(out / "prediction.npz")
    assert list(g.class_names[1:]) == ["ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table",
                                       "curtain", "door", "tv", "lighting"]
    wall = _clean_wall(g)
    assert wall.sum() > 40
    assert np.mean(g.labels[wall] == g.class_names.index("wall")) > 0.9
    occ = (g.labels != 0) & (g.labels != 255)
    assert occ.sum() == s["occupied"] and 0.8 * s["occupied"] < s["classed"] <= s["occupied"]
    assert np.count_nonzero(occ & (g.labels != 254)) == s["classed"]
    # the ceiling plane (z = 2.6) is ceiling
    c = _centres(g)
    ceil = occ & (np.abs(c[..., 2] - 2.6) < 0.09) & (np.abs(c[..., 0]) < 2) & (np.abs(c[..., 1]) < 2.5) \
        & ~((np.abs(c[..., 0]) < 0.4) & (np.abs(c[..., 1]) < 0.4))  # the lamp hangs there
    assert np.mean(g.labels[ceil] == g.class_names.index("ceiling")) > 0.9
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(out / "map.ply"))
    cols = np.rint(np.asarray(pc.colors) * 255).astype(int)
    assert len(cols) == s["occupied"]
    from panovocc_cli.classes import class_color

    assert np.mean(np.all(cols == class_color("wall"), axis=1)) > 0.2  # class colours, walls most common


def test_memory_holds_exact_sums_of_frame_evidence(sem_seq, default_map):
    """The memory's semantic channels = the exact integer sums of the per-frame deltas, each made from the
    frame's observation of the segmenter's logits (mapping/contributors.py), and E / S the fused distribution."""
    from panovocc_cli.classes import parse_vocab
    from panovocc_cli.io.mapstore import read_map_config
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.mapping.contributors import S_SCALE, quantize_semantic_delta
    from panovocc_cli.semantics.evidence import frame_semantic_delta
    from panovocc_cli.semantics.observation import observe
    from panovocc_cli.semantics.registry import build_segmenter
    from panovocc_cli.semantics.simulated import sequence_label_source

    out, _ = default_map
    mem, _, _ = load_memory(out)
    seq = Sequence(sem_seq)
    seg, vocab = build_segmenter("simulated", label_source=sequence_label_source(seq)), parse_vocab()
    acc, floats = {}, {}
    origin = np.asarray(read_map_config(out)["origin"])  # the memory keys voxels relative to the map's origin
    for i in range(N):
        obs = observe(seg.logits(seq.rgb(i), vocab, frame_id=i))
        T = seq.poses[i].copy()
        T[:3, 3] -= origin
        keys, ch = frame_semantic_delta(seq.depth(i), seq.rgb(i), obs, T, 0.08)
        d = quantize_semantic_delta(keys, ch)
        for r, k in enumerate(keys):
            a = acc.setdefault(int(k), {name: 0 for name in d.channels})
            for name in d.channels:
                a[name] = a[name] + d.channels[name][r]
            f = floats.setdefault(int(k), [0.0, 0.0])
            f[0] += ch["S"][r]
    keys = np.array(sorted(acc), np.int64)
    got = mem.gather(keys)
    for name in ("E", "S", "rgb_sum", "normal_sum", "count"):
        np.testing.assert_array_equal(got[name], np.stack([np.atleast_1d(acc[int(k)][name]) for k in keys]),
                                      err_msg=name)
    S = np.array([floats[int(k)][0] for k in keys])
    assert np.abs(got["S"][:, 0] / S_SCALE - S).max() <= N * 0.5 / 256 + 1e-9  # the weight to half a step a frame
    np.testing.assert_array_equal(got["E"].sum(1), got["S"][:, 0])
    assert np.all(got["count"][:, 0] > 0)


@pytest.mark.slow
def test_revise_and_resume_exact_with_semantics(sem_seq, default_map, tmp_path):
    direct, _ = default_map
    true = circle_poses(N)
    wrong = true.copy()
    rng = np.random.default_rng(5)
    for i in (1, 4):
        a = rng.normal(0, 0.1)
        c, s = np.cos(a), np.sin(a)
        wrong[i, :3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ wrong[i, :3, :3]
        wrong[i, :3, 3] += rng.normal(0, 0.15, 3)
    write_poses(tmp_path / "wrong.txt", wrong)
    rev = tmp_path / "rev"
    run_map(MapConfig(seq=str(sem_seq), out=str(rev), checkpoint_every=2, poses=str(tmp_path / "wrong.txt")),
            progress=False)
    assert (rev / "prediction.npz").read_bytes() != (direct / "prediction.npz").read_bytes()
    from panovocc_cli.mapping import Mapper

    with Mapper.load(rev) as m:  # the geometry's part, then the semantics'
        geo, sem = m._rpu.store.get(1).parts
        assert set(geo.channels) == {"A", "N", "F", "O"}
        assert set(sem.channels) == {"E", "S", "rgb_sum", "normal_sum", "count"}
    s = run_revise(rev, sem_seq / "poses.txt", progress=False)
    assert s["revised"] == 2
    assert _bytes(rev) == _bytes(direct)
    # killed after frame 3 (checkpoint at 2), resumed: the same bytes as the uninterrupted run
    part = tmp_path / "part"
    st = run_map(_cfg(sem_seq, part), progress=False, stop_after=3)
    assert st["stopped_at"] == 3 and load_memory(part)[1] == 2
    run_map(resume_out=part, progress=False)
    assert _bytes(part) == _bytes(direct)


@pytest.mark.slow
def test_one_class_and_unknown_word_vocabularies(sem_seq, default_map, tmp_path):
    _, s_def = default_map
    s = run_map(_cfg(sem_seq, tmp_path / "one", vocab="chair"), progress=False)
    g = read_grid(tmp_path / "one" / "prediction.npz")
    assert list(g.class_names) == ["empty", "chair"]
    occ = (g.labels != 0) & (g.labels != 255)
    assert set(np.unique(g.labels[occ]).tolist()) <= {1, 254}
    # every voxel with evidence (or within the transfer bound of one) is labelled: the same set as 12 classes
    assert s["classed"] == s_def["classed"] and s["occupied"] == s_def["occupied"]
    s = run_map(_cfg(sem_seq, tmp_path / "unk", vocab="spaceship,banana"), progress=False)
    g = read_grid(tmp_path / "unk" / "prediction.npz")
    assert list(g.class_names) == ["empty", "spaceship", "banana"]
    occ = (g.labels != 0) & (g.labels != 255)
    assert set(np.unique(g.labels[occ]).tolist()) <= {1, 2, 254} and s["occupied"] == s_def["occupied"]
    # a known word among unknown ones still finds its voxels
    run_map(_cfg(sem_seq, tmp_path / "mix", vocab="spaceship,wall"), progress=False)
    g = read_grid(tmp_path / "mix" / "prediction.npz")
    assert np.mean(g.labels[_clean_wall(g)] == 2) > 0.9


def test_relabel_from_ground_truth_closed_form():
    h = 0.08
    gt_lab = np.full((4, 3, 2), 255, np.uint8)
    gt_lab[0] = 0
    gt_lab[1, :, :] = 2  # wall
    gt_lab[2, 0, 0] = 254
    gt = Grid(gt_lab, np.array([0.04, 0.04, 0.04]), h, ["empty", "floor", "wall"])
    # prediction shifted by one voxel along x, one voxel beyond the truth's box
    p = np.full((4, 3, 2), 255, np.uint8)
    p[0, :, :] = 254  # x index 1 in the truth: wall
    p[1, 0, 0] = 7  # x index 2: truth 254 -> 254
    p[1, 1, 0] = 0  # free stays free
    p[3, :, :] = 3  # x index 4: outside the truth -> 254
    pred = Grid(p, np.array([0.12, 0.04, 0.04]), h, ["empty"] + [f"c{k}" for k in range(1, 8)])
    r = relabel_from_ground_truth(pred, gt)
    assert list(r.class_names) == ["empty", "floor", "wall"]
    assert np.all(r.labels[0] == 2) and r.labels[1, 0, 0] == 254 and r.labels[1, 1, 0] == 0
    assert np.all(r.labels[3] == 254) and r.labels[2, 0, 0] == 255


def _cli(capsys):
    from panovocc_cli.cli import main

    def run(*args):
        with pytest.raises(SystemExit) as e:
            main([str(a) for a in args])
        return e.value.code, capsys.readouterr()

    return run


@pytest.mark.slow
def test_cli_semantic_map_no_gsc_precomputed_segeval(sem_seq, tmp_path, capsys):
    run = _cli(capsys)
    o = tmp_path / "ng"
    code, io = run("map", sem_seq, o, "--quiet", "--vocab", "eval8", "--noise", "0.5", "--seed", "3", "--no-gsc",
                   "--ply-color", "rgb")
    assert code == 0 and "with a class" in io.out
    cfg = json.loads((o / "config.json").read_text())["semantic"]
    assert cfg["segmenter"] == "simulated" and cfg["use_gsc"] is False and cfg["noise"] == 0.5 and cfg["seed"] == 3
    assert cfg["vocab"] == ["ceiling", "floor", "wall", "window", "chair", "bed", "sofa", "table"]
    g = read_grid(o / "prediction.npz")
    assert len(g.class_names) == 9 and np.mean(g.labels[_clean_wall(g)] == 3) > 0.8
    code, io = run("revise", o, sem_seq / "poses.txt", "--quiet")
    assert code == 0 and "revised 0 of 6" in io.out
    code, io = run("map", "--resume", o, "--vocab", "chair", "--quiet")
    assert code == 2 and "--vocab" in io.err and len(io.err.strip().splitlines()) == 1
    # an empty vocabulary: exit 2, one line, nothing written
    code, io = run("map", sem_seq, tmp_path / "e", "--vocab", " , ", "--quiet")
    assert code == 2 and "vocabulary" in io.err and len(io.err.strip().splitlines()) == 1
    assert not (tmp_path / "e").exists()
    code, io = run("map", sem_seq, tmp_path / "e", "--segmenter", "oracle", "--quiet")
    assert code == 2 and not (tmp_path / "e").exists()
    code, io = run("map", sem_seq, tmp_path / "e", "--noise", "-1", "--quiet")
    assert code == 2 and not (tmp_path / "e").exists()
    # a precomputed segmenter: exact labels written as label PNGs over another vocabulary
    from panovocc_cli.io.sequence import Sequence
    from panovocc_cli.semantics.precomputed import write_precomputed_labels

    seq = Sequence(sem_seq)
    words = ["wall", "floor", "ceiling", "bed"]
    lut = np.array([words.index(c) if c in words else 255 for c in CLASS_NAMES], np.int64)
    for i in range(N):
        write_precomputed_labels(tmp_path / "pre", i, lut[seq.labels(i)], words)
    o = tmp_path / "pre_map"
    code, io = run("map", sem_seq, o, "--segmenter", f"precomputed:{tmp_path / 'pre'}", "--vocab", "wall,floor,bed",
                   "--quiet")
    assert code == 0
    g = read_grid(o / "prediction.npz")
    assert list(g.class_names) == ["empty", "wall", "floor", "bed"] and np.mean(g.labels[_clean_wall(g)] == 1) > 0.95
    assert json.loads((o / "config.json").read_text())["semantic"]["segmenter"] == f"precomputed:{tmp_path / 'pre'}"
    code, io = run("segeval", sem_seq, "--every", "2", "--quiet")
    assert code == 0 and "pooled over 3 frames" in io.out and "wall" in io.out
    code, io = run("segeval", sem_seq, "--noise", "0", "--classes", "wall,bed", "--quiet")
    assert code == 0 and "2D mIoU (wall,bed" in io.out
    miou = float(io.out.split("frames): ")[1].split("%")[0])
    assert miou > 90  # exact segmenter: only out-of-vocabulary confusions remain
    code, io = run("segeval", sem_seq, "--every", "0", "--quiet")
    assert code == 2


def test_cli_unlabelled_sequence_needs_a_segmenter(tmp_path, capsys):
    from room_sequence import write_room_sequence

    run = _cli(capsys)
    seq = tmp_path / "plain"
    write_room_sequence(seq, 3, 64, furniture=False)
    code, io = run("map", seq, tmp_path / "o", "--quiet")
    assert code == 2 and "--segmenter none" in io.err and not (tmp_path / "o").exists()
    code, io = run("map", seq, tmp_path / "o", "--segmenter", "simulated", "--quiet")
    assert code == 2 and "labels" in io.err and not (tmp_path / "o").exists()
    code, io = run("map", seq, tmp_path / "o", "--segmenter", "none", "--quiet")
    assert code == 0 and "with a class" not in io.out
    g = read_grid(tmp_path / "o" / "prediction.npz")
    assert list(g.class_names) == ["empty"] and set(np.unique(g.labels).tolist()) == {0, 254, 255}
    code, io = run("segeval", seq, "--quiet")
    assert code == 2 and "semantic/" in io.err


def test_the_export_a_block_at_a_time_equals_one_pass(default_map, monkeypatch):
    """The labelled export reads the occupied voxels' channels and runs GSC a cube of the key space at a time
    (issue 21: a building's export must not hold every channel of every voxel at once): with cubes of
    3 voxels (and their halo) it gives the same labels, bit for bit, as with the default, and its channels
    are read on demand as copies (never views that keep a whole channel group alive)."""
    import panovocc_cli.mapping.export as export
    import panovocc_cli.semantics.gsc as gsc
    from panovocc_cli.mapping import Mapper

    m = Mapper.load(default_map[0])
    try:
        one = m.export()
        assert one.labels is not None and (one.labels >= 0).sum() > 100
        monkeypatch.setattr(export, "BLOCK", 3)
        monkeypatch.setattr(export, "CHUNK", 13)
        monkeypatch.setattr(gsc, "EDGE_CHUNK", 5)
        small = m.export()
    finally:
        m.close()
    assert np.array_equal(one.labels, small.labels) and np.array_equal(one.occupied_keys, small.occupied_keys)
    assert np.array_equal(one.grid.labels, small.grid.labels)
    S = small.channels["S"]
    assert S.base is None or S.base.shape == S.shape  # a copy of the column, not a view of the group
    assert np.array_equal(S, one.channels["S"]) and "E" in small.channels and "nope" not in small.channels


def _tree(folder):
    """Every file under ``folder`` (relative path -> bytes): what a failed command must leave as it was."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_revise_exports_while_memory_npz_is_written_and_a_failure_on_either_thread(sem_seq, default_map, tmp_path,
                                                                                     monkeypatch, capsys):
    """``revise`` (issue 21) streams memory.npz on the writer thread while the calling thread exports the revised
    memory with GSC cubes of ``REVISE_GSC_BLOCK`` voxels, then writes prediction.npz and map.ply after the
    commit. A write that fails part-way on the writer thread: one line, exit 2, every file of the map as it
    was (no temporary left). An export that fails: the error comes out once the commit is made (as when the
    export followed the save), the grid and PLY as they were; a second revise writes them. The result, with
    cubes of 3 voxels (many cubes), is the bytes of a map made from the final poses."""
    from panovocc_cli.cli import main
    from panovocc_cli.mapping import Mapper, export, pipeline
    from panovocc_cli.mapping.memory import MemoryChunks

    direct, _ = default_map
    wrong = circle_poses(N)
    wrong[2, :3, 3] += 0.07
    write_poses(tmp_path / "wrong.txt", wrong)
    rev = tmp_path / "rev"
    run_map(MapConfig(seq=str(sem_seq), out=str(rev), checkpoint_every=2, poses=str(tmp_path / "wrong.txt")),
            progress=False)
    before = _tree(rev)

    real_chunks = MemoryChunks.chunks

    def fails_part_way(self, *a, **k):  # the temporary memory.npz is open when the disk fills
        for n, item in enumerate(real_chunks(self, *a, **k)):
            if n == 1:
                raise OSError(28, "No space left on device")
            yield item

    monkeypatch.setattr(MemoryChunks, "chunks", fails_part_way)
    monkeypatch.setattr(pipeline, "REVISE_GSC_BLOCK", 3)
    with pytest.raises(SystemExit) as e:
        main(["revise", str(rev), str(sem_seq / "poses.txt"), "--quiet"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and "No space" in err
    assert _tree(rev) == before
    monkeypatch.setattr(MemoryChunks, "chunks", real_chunks)

    def no_memory(*a, **k):
        raise MemoryError("export")

    real_export = Mapper.export
    monkeypatch.setattr(Mapper, "export", no_memory)
    with pytest.raises(MemoryError):
        run_revise(rev, sem_seq / "poses.txt", progress=False)
    after = _tree(rev)
    assert after["memory.npz"] == (direct / "memory.npz").read_bytes()  # committed: the save was waited for
    assert {n: after[n] for n in ("prediction.npz", "map.ply")} == {n: before[n] for n in ("prediction.npz", "map.ply")}
    assert not [n for n in after if n.rsplit("/", 1)[-1].startswith(".")]  # no temporary left

    blocks = []
    real_blocks = export.consolidate_blocks
    monkeypatch.setattr(Mapper, "export", real_export)
    monkeypatch.setattr(export, "consolidate_blocks", lambda *a, **k: blocks.append(k["block"]) or real_blocks(*a, **k))
    assert run_revise(rev, sem_seq / "poses.txt", progress=False)["revised"] == 0
    assert blocks == [3] and _bytes(rev) == _bytes(direct)
    assert (rev / "poses.txt").read_bytes() == (direct / "poses.txt").read_bytes()


@pytest.mark.slow
def test_revise_relabels_near_its_change_only_while_the_export_record_holds(sem_seq, default_map, tmp_path, monkeypatch):
    """revise labels again only the GSC cubes near the blocks it changed when deltas/export.json says
    prediction.npz is the loaded memory's export; the bytes equal a whole export's and a direct map's. A
    record that no longer holds (no record, a prediction.npz changed since) gives the whole export."""
    import shutil

    from panovocc_cli.io.grid import write_grid
    from panovocc_cli.mapping import export, pipeline

    direct, _ = default_map
    wrong = circle_poses(N)
    wrong[3, :3, 3] += 0.01  # a centimetre
    write_poses(tmp_path / "wrong.txt", wrong)
    rev = tmp_path / "rev"
    run_map(MapConfig(seq=str(sem_seq), out=str(rev), checkpoint_every=2, poses=str(tmp_path / "wrong.txt")),
            progress=False)
    record = rev / "deltas" / pipeline.EXPORT_RECORD
    assert set(json.loads(record.read_text())) == {"memory_sha256", "prediction_sha256", "settings_sha256"}
    wrong_map, whole = tmp_path / "wrong_map", tmp_path / "whole"
    shutil.copytree(rev, wrong_map)
    shutil.copytree(rev, whole)
    (whole / "deltas" / pipeline.EXPORT_RECORD).unlink()  # as a map made before the record
    redo = []
    real = export.consolidate_blocks
    monkeypatch.setattr(export, "consolidate_blocks", lambda *a, **k: redo.append(k["region"]) or real(*a, **k))
    s = run_revise(rev, sem_seq / "poses.txt", progress=False)
    assert s["revised"] == 1 and s["incremental_export"] and redo[-1] is not None
    s = run_revise(whole, sem_seq / "poses.txt", progress=False)
    assert not s["incremental_export"] and redo[-1] is None
    assert _bytes(rev) == _bytes(whole) == _bytes(direct)
    # a prediction.npz changed since the record (one voxel): the whole export, which writes the right one
    g = read_grid(rev / "prediction.npz")
    lab = g.labels.copy()
    lab[np.unravel_index(np.flatnonzero((lab >= 1) & (lab < 254))[0], lab.shape)] = 254
    write_grid(rev / "prediction.npz", Grid(lab, g.origin, g.voxel_size, g.class_names))
    s = run_revise(rev, tmp_path / "wrong.txt", progress=False)
    assert not s["incremental_export"] and _bytes(rev) == _bytes(wrong_map)
    # the record holds again: revised back incrementally, the direct map's bytes
    s = run_revise(rev, sem_seq / "poses.txt", progress=False)
    assert s["incremental_export"] and _bytes(rev) == _bytes(direct)
