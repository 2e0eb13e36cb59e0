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
    occupied): the export given the previous grid and the changed keys labels only the voxels near them and
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
    # voxels that stop or start being occupied are found from the two exports: unlisted (as a change by the
    # face-neighbour rules leaves them), the same labels. A voxel v far from the changes above is the only
    # evidence within the GSC's reach: its neighbours' labels come from it, and change when it stops or starts.
    idx = unpack_keys(keys)
    wall = (idx[:, 0] > 40) & (idx[:, 1] == 16) & (idx[:, 2] > 18)
    v = np.flatnonzero(wall & np.isin(keys, before.occupied_keys) & (ch["S"][:, 0] > 0))[0]
    patch = np.abs(idx - idx[v]).max(axis=1) <= 14
    base = {k: c.copy() for k, c in ch.items()}
    for k in ("E", "S"):
        base[k][patch & (np.arange(len(keys)) != v)] = 0
    off = {k: c.copy() for k, c in base.items()}
    off["N"][v], off["A"][v], off["F"][v] = 0, 0, 5  # v not occupied
    for a, b in ((base, off), (off, base)):  # v stops, v starts
        was, now = _export(keys, a), _export(keys, b)
        _, i, j = np.intersect1d(was.occupied_keys, now.occupied_keys, return_indices=True)
        assert (was.labels[i] != now.labels[j]).sum() > 3  # v's neighbours' labels
        got = _export(keys, b, previous=was.grid, changed_keys=keys[:0])
        assert np.array_equal(got.labels, now.labels) and np.array_equal(got.grid.labels, now.grid.labels)
    calls.clear()
    _export(keys, ch2)
    assert 0 < redone < (sum(calls) / 2 if block == 8 else sum(calls))  # 64: one cube, less than all of it
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


@pytest.mark.parametrize("halo", [12, 22, 3, 0])
def test_the_voxels_labelled_again_hold_every_voxel_a_change_can_reach(halo):
    """``relabel_region`` against its definition, voxel by voxel, changed keys and changed blocks, the
    lattice's edges included: every occupied voxel within ``halo`` of a changed voxel is labelled
    again (2), every voxel within ``halo`` of one labelled again is read (>= 1), and voxels far from every
    change are neither (the region is local). The halo's own length is tested in
    tests/semantics/test_gsc_blocks.py (one voxel less gives other labels)."""
    from panovocc_cli.geometry.lattice import KEY_RANGE

    assert KEY_RANGE == KEY_RANGE_EDGE
    rng = np.random.default_rng(halo)
    occ = np.unique(np.concatenate([rng.integers(-300, 300, (6000, 3)), rng.integers(KEY_RANGE - 60, KEY_RANGE, (800, 3)),
                                    rng.integers(-KEY_RANGE + 1, -KEY_RANGE + 40, (800, 3))]), axis=0)
    keys = pack_keys(occ)
    changed = np.concatenate([rng.integers(-20, 20, (5, 3)), [[KEY_RANGE - 1, KEY_RANGE - 3, KEY_RANGE - 9]]])
    blocks = np.array([[6, -5, 2], [(1 - KEY_RANGE) // 8, (1 - KEY_RANGE) // 8, (1 - KEY_RANGE) // 8]])
    region = export.relabel_region(keys, pack_keys(changed), blocks, halo)
    block_voxels = np.concatenate([b * 8 + np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)
                                   for b in blocks])
    src = np.concatenate([changed, block_voxels])
    dist = np.min(np.abs(occ[:, None, :] - src[None]).max(axis=2), axis=1)  # L-inf distance to a change
    assert (region[dist <= halo] == 2).all()
    relabel = occ[region == 2]
    near_relabel = np.min(np.abs(occ[:, None, :] - relabel[None]).max(axis=2), axis=1) <= halo
    assert (region[near_relabel] >= 1).all()
    assert (region[dist > 2 * halo + 32] == 0).all() and (region == 0).sum() > len(occ) / 2
    assert not export.relabel_region(keys, keys[:0], None, halo).any()


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
