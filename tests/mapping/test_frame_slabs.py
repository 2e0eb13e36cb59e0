"""A frame box splatted, carved and extracted a slab of x-planes at a time (``psvf.update.SLAB_VOXELS``, the
per-frame working set bounded by the slab, not the box: docs/mapping.md "Memory layout") gives the same delta,
bit for bit, as the whole box at once, for every kernel."""

import dataclasses

import numpy as np
import pytest
from box_room import box_depth, turned_pose

from panovocc_cli.mapping.params import GeometryParams
from panovocc_cli.mapping.psvf import update


def _parts(monkeypatch, slab, depth, T, p):
    monkeypatch.setattr(update, "SLAB_VOXELS", slab)
    calls = []
    real = update._extract

    def counting(A, *a):
        calls.append(A.shape)
        return real(A, *a)

    monkeypatch.setattr(update, "_extract", counting)
    return update.geometry_parts(depth, T, p), calls


@pytest.mark.parametrize("kernel,extent,offsets", [("psvf", "surfel", True), ("psvf", "surfel", False),
                                                   ("psvf", "box", False), ("psvf", "centre", True),
                                                   ("point", "surfel", False)])
def test_slabs_give_the_whole_box_delta(monkeypatch, kernel, extent, offsets):
    W = 128
    T = turned_pose()
    rng = np.random.default_rng(3)
    depth = (box_depth(W, T).astype(np.float64) + rng.normal(0, 0.004, (W // 2, W))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.01] = 0.0
    p = dataclasses.replace(GeometryParams(), stride=2, kernel=kernel, extent=extent, offsets=offsets)
    whole, one = _parts(monkeypatch, 1 << 40, depth, T, p)
    assert len(one) == 1  # the whole box in one slab
    nx = one[0][0]
    for slab in (1, 7 * one[0][1] * one[0][2], one[0][0] * one[0][1] * one[0][2] // 3):
        parts, calls = _parts(monkeypatch, slab, depth, T, p)
        assert len(calls) > 1 and sum(c[0] for c in calls) == nx  # x-planes in slabs, each once
        assert max(c[0] for c in calls) <= max(1, slab // (one[0][1] * one[0][2]))
        assert len(parts) == len(whole)
        for a, b in zip(parts, whole):
            np.testing.assert_array_equal(a.keys, b.keys)
            assert sorted(a.channels) == sorted(b.channels)
            for name in b.channels:
                # the geometry's A N F O rows are int32 when A fits (it always does here), other parts int64
                assert a.channels[name].dtype == b.channels[name].dtype == (np.int32 if name in "ANFO" else np.int64)
                np.testing.assert_array_equal(a.channels[name], b.channels[name])
    g = whole[0]
    assert len(g) > 1000 and g.channels["F"].any() and g.channels["N"].any() and g.channels["A"].any()


def test_rows_are_int32_when_A_fits_else_int64():
    """``_delta_rows`` writes A N F O as int32 when every A of the frame fits, and as int64 (the same values)
    when one does not: a value is never wrapped."""
    k = np.arange(5, dtype=np.int64)
    nfo = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 0, 0]], np.uint8)
    for big, dtype in ((2 ** 31 - 1, np.int32), (2 ** 31, np.int64), (-2 ** 31 - 1, np.int64)):
        a = np.array([1, 2, big, 4, 5], np.int64)
        parts = [(k[:2], a[:2], nfo[:2]), (k[2:2], a[2:2], nfo[2:2]), (k[2:], a[2:], nfo[2:])]
        keys, rows = update._delta_rows(parts)
        assert rows.dtype == dtype and parts == []
        np.testing.assert_array_equal(keys, k)
        np.testing.assert_array_equal(rows, np.column_stack([a, nfo.astype(np.int64)]))


def test_int32_rows_add_and_replace_as_int64():
    """A memory fed a frame's int32 geometry rows (add, subtract, and a revision's replace against a kept
    int64 delta) equals one fed the same values as int64, bit for bit."""
    from panovocc_cli.mapping.memory import Delta, VoxelMemory

    W = 128
    T = turned_pose()
    depth = box_depth(W, T).astype(np.float32)
    p = dataclasses.replace(GeometryParams(), stride=2)
    T2 = T.copy()
    T2[:3, 3] += [0.013, -0.007, 0.004]
    d1 = update.geometry_parts(depth, T, p)[0]
    d2 = update.geometry_parts(depth, T2, p)[0]
    assert d1.channels["A"].dtype == d2.channels["A"].dtype == np.int32

    def wide(d):
        return Delta(d.keys, {k: v.astype(np.int64) for k, v in d.channels.items()})

    def state(m):
        return m._geo[:m.n_blocks], m._block_keys[:m.n_blocks]

    a, b = VoxelMemory(p.voxel_size), VoxelMemory(p.voxel_size)
    a.add(d1)
    b.add(wide(d1))
    a.replace(wide(d1), d2)  # the kept delta read back from the log is int64, the new one int32
    b.replace(wide(d1), wide(d2))
    a.add(d2, -1)
    a.add(d1)
    b.add(wide(d2), -1)
    b.add(wide(d1))
    ga, ka = state(a)
    gb, kb = state(b)
    np.testing.assert_array_equal(ka, kb)
    np.testing.assert_array_equal(ga, gb)
    assert ga.any()
