"""The labelled export a region at a time (issue 21): an incremental export (only the GSC cubes whose halo
holds a changed voxel labelled again) equals a full one bit for bit; the point cloud written in slices has
the bytes of the one written at once."""

from types import SimpleNamespace

import numpy as np
import pytest

import panovocc_cli.mapping.export as export
from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.lattice import pack_keys, unpack_keys
from panovocc_cli.io.ply import write_ply_points
from panovocc_cli.mapping.export import export_memory, point_chunks, point_colors, previous_labels
from panovocc_cli.mapping.params import OccupancyParams
from panovocc_cli.semantics.gsc import GSCParams

VOCAB = ["wall", "floor", "chair", "table"]
KEY_RANGE_EDGE = 1 << 20


def _memory(seed=0):
    """Sorted keys and integer channels of a synthetic memory: two walls and a floor, 16 % free-space
    voxels, some occupied voxels without semantic evidence, class 'table' absent."""
    a = np.arange(0, 60)
    u, v = np.meshgrid(a, np.arange(0, 30), indexing="ij")
    parts = [np.stack([np.full(u.size, 31), u.ravel(), v.ravel()], 1),
             np.stack([u.ravel(), np.full(u.size, 16), v.ravel()], 1),
             np.stack([u.ravel(), v.ravel(), np.zeros(u.size, int)], 1)]
    keys = np.unique(pack_keys(np.concatenate(parts)))
    n = len(keys)
    rng = np.random.default_rng(seed)
    occ = rng.random(n) > 0.16
    ch = {"A": np.where(occ, rng.integers(1, 1 << 20, n), 0)[:, None],
          "N": np.where(occ, rng.integers(1, 40, n), 0)[:, None],
          "F": np.where(occ, 0, rng.integers(1, 9, n))[:, None],
          "O": rng.integers(40, 60, n)[:, None]}
    S = np.where(rng.random(n) < 0.25, 0, rng.integers(1, 5000, n))
    E = rng.dirichlet(np.ones(len(VOCAB)), n) * S[:, None]
    E[:, 3] = 0
    ch.update(E=E.astype(np.int64), S=S[:, None].astype(np.int64), normal_sum=rng.integers(-99, 99, (n, 3)),
              rgb_sum=rng.integers(0, 9000, (n, 3)), count=rng.integers(0, 40, (n, 1)))
    return keys, ch


SEM = SimpleNamespace(use_gsc=True, gsc=GSCParams())


def _export(keys, ch, **kw):
    return export_memory(keys, ch, 0.05, OccupancyParams(), VOCAB, SEM, origin_index=(1000, -7, 3), **kw)


@pytest.mark.parametrize("block", [8, 64])
def test_incremental_export_equals_a_full_one(monkeypatch, block):
    """Channels change at a few voxels (labels, evidence lost, a voxel that stops and one that starts being
    occupied): the export given the previous grid and the changed keys labels only the cubes near them and
    gives the full export's labels and grid bit for bit; with nothing changed it labels nothing again."""
    monkeypatch.setattr(export, "BLOCK", block)
    keys, ch = _memory()
    before = _export(keys, ch)
    rng = np.random.default_rng(1)
    corner = np.flatnonzero(np.all(unpack_keys(keys)[:, :2] < 12, axis=1))  # changes in one corner
    changed = rng.choice(corner, 6, replace=False)
    ch2 = {k: v.copy() for k, v in ch.items()}
    ch2["E"][changed[:3]] = ch2["E"][changed[:3], ::-1] * 3
    ch2["S"][changed[:3]] *= 3
    ch2["E"][changed[3]] = 0
    ch2["S"][changed[3]] = 0
    ch2["N"][changed[4]], ch2["A"][changed[4]], ch2["F"][changed[4]] = 0, 0, 5  # stops being occupied
    ch2["N"][changed[5]], ch2["A"][changed[5]], ch2["F"][changed[5]] = 30, 1 << 19, 0  # starts
    full = _export(keys, ch2)
    assert not np.array_equal(full.grid.labels, before.grid.labels)
    calls = []
    real = export.gsc_inputs
    monkeypatch.setattr(export, "gsc_inputs", lambda c, g, rows: calls.append(len(rows)) or real(c, g, rows))
    inc = _export(keys, ch2, previous=before.grid, changed_keys=keys[changed])
    assert np.array_equal(inc.labels, full.labels) and np.array_equal(inc.grid.labels, full.grid.labels)
    assert np.array_equal(inc.grid.origin, full.grid.origin) and inc.grid.class_names == full.grid.class_names
    redone = sum(calls)
    calls.clear()
    _export(keys, ch2)
    assert 0 < redone < sum(calls) / 2 if block == 8 else redone == sum(calls)  # 64: the map is one cube
    calls.clear()
    same = _export(keys, ch2, previous=full.grid, changed_keys=keys[:0])
    assert calls == [] and np.array_equal(same.grid.labels, full.grid.labels)
    with pytest.raises(PanovoccError, match="changed voxels"):
        _export(keys, ch2, previous=full.grid)


@pytest.mark.parametrize("chunk", [1, 7, 1000])
def test_gsc_inputs_made_a_chunk_at_a_time_are_the_whole_cubes(monkeypatch, chunk):
    """GSC's inputs made :data:`export.UNARY_ROWS` rows at a time equal, bit for bit, the unaries of every row of
    the cube at once (the one expression they were made by before), whatever the chunk (one row, a chunk that
    does not divide the rows, more than the rows): rows with S = 0, count = 0 and zero normals included."""
    from panovocc_cli.mapping.contributors import NORMAL_STEPS, S_SCALE
    from panovocc_cli.semantics.gsc import unaries

    keys, ch = _memory(3)
    ch["normal_sum"][::5] = 0
    g = np.random.default_rng(2).random(len(keys))
    rows = np.flatnonzero(np.random.default_rng(4).random(len(keys)) < 0.6)
    oc = export.OccupiedChannels(ch, np.arange(len(keys)))
    c = {k: v[rows] for k, v in ch.items()}
    want = unaries(c["E"] / S_SCALE, c["S"][:, 0] / S_SCALE, c["normal_sum"] / NORMAL_STEPS, c["rgb_sum"],
                   c["count"][:, 0])
    monkeypatch.setattr(export, "UNARY_ROWS", chunk)
    p, S, gg, normals, colors = export.gsc_inputs(oc, g, rows)
    assert (c["S"] == 0).any() and (c["count"] == 0).any() and np.isnan(colors).any()
    for got, exp in ((p, want[0]), (normals, want[1]), (colors, want[2])):
        assert got.dtype == exp.dtype and got.shape == exp.shape
        assert np.array_equal(got.view(np.uint32), exp.view(np.uint32))  # NaN payloads too
    assert np.array_equal(S, c["S"][:, 0] / S_SCALE) and np.array_equal(gg, g[rows])


def test_previous_labels_read_back_the_grid():
    keys, ch = _memory()
    ex = _export(keys, ch)
    assert np.array_equal(previous_labels(ex.grid, ex.occupied_keys, ex.origin_index), ex.labels)
    far = previous_labels(ex.grid, ex.occupied_keys + pack_keys(np.array([[500, 0, 0]]))[0]
                          - pack_keys(np.zeros((1, 3), np.int64))[0], ex.origin_index)
    assert (far == export.UNKNOWN_CLASS).all()  # outside the grid: not held as occupied


@pytest.mark.parametrize("color", ["class", "rgb", "height"])
def test_point_cloud_in_slices_has_the_same_bytes(tmp_path, monkeypatch, color):
    keys, ch = _memory()
    ex = _export(keys, ch)
    pts, cols = point_colors(ex, 0.05, color, VOCAB)
    write_ply_points(tmp_path / "whole.ply", pts, cols)
    monkeypatch.setattr(export, "CHUNK", 777)
    write_ply_points(tmp_path / "sliced.ply", point_chunks(ex, 0.05, color, VOCAB), count=len(pts))
    assert (tmp_path / "whole.ply").read_bytes() == (tmp_path / "sliced.ply").read_bytes()
    assert len(list(point_chunks(ex, 0.05, color, VOCAB))) == -(-len(pts) // 777)


def test_a_cube_is_labelled_again_exactly_when_its_halo_holds_a_changed_voxel():
    """The incremental export's choice of cubes against its definition (a changed key in the cube grown by
    the halo), changed keys anywhere, the lattice's edges included; the halo's own length is tested in
    tests/semantics/test_gsc_blocks.py (one voxel less gives other labels)."""
    from panovocc_cli.geometry.lattice import KEY_RANGE

    assert KEY_RANGE == KEY_RANGE_EDGE
    rng = np.random.default_rng(4)
    changed = rng.integers(-30, 30, (40, 3))
    changed[:2] = [[KEY_RANGE - 1, 0, 0], [0, 1 - KEY_RANGE, 5]]
    redo = export._touches(pack_keys(changed), 8, 12)
    for cube in np.stack(np.meshgrid(*[np.arange(-7, 7)] * 3, indexing="ij"), -1).reshape(-1, 3):
        lo, hi = cube * 8 - 12, cube * 8 + 20
        assert redo(cube, None) == bool(np.all((changed >= lo) & (changed < hi), axis=1).any())
    edge = np.array([(KEY_RANGE - 1) // 8, 0, 0])
    assert redo(edge, None) and not redo(edge - [4, 0, 0], None)


def test_memory_slabs_concatenate_to_nonzero():
    """VoxelMemory.nonzero_slabs: slabs of the key space in key order whose concatenation is nonzero()
    (keys and locations), whatever the slab size (one block x-index at least, or all in one)."""
    from panovocc_cli.mapping.memory import Delta, VoxelMemory

    rng = np.random.default_rng(7)
    idx = rng.integers(-300, 300, size=(30000, 3))
    idx[:50] = rng.integers(KEY_RANGE_EDGE - 20, KEY_RANGE_EDGE, size=(50, 3))  # far out, near the lattice's edge
    keys = np.unique(pack_keys(idx))
    ch = {c: rng.integers(0, 2 ** 20, size=(len(keys), 1)) for c in ("A", "N", "F", "O")}
    ch["A"][::3] = ch["N"][::3] = ch["F"][::3] = ch["O"][::3] = 0  # allocated but zero: not listed
    m = VoxelMemory(0.08)
    m.add(Delta(keys, ch))
    want_k, want = m.nonzero()
    for size in (1, 512 * 40, 1 << 30):
        slabs = list(m.nonzero_slabs(size))
        assert len(slabs) > (1 if size < 1 << 30 else 0)
        assert np.array_equal(np.concatenate([k for k, _ in slabs]), want_k)
        assert np.array_equal(np.concatenate([loc for _, loc in slabs]), want._loc)
    assert len(list(VoxelMemory(0.08).nonzero_slabs())) == 0
