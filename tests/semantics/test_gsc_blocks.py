"""GSC a cube of the key space at a time (issue 21): the same labels, bit for bit, as the whole map at once,
whatever the cube size; the nearest-evidence transfer's tie rule; the incremental relabelling."""

import numpy as np
import pytest

import panovocc_cli.semantics.gsc as gsc
from panovocc_cli.geometry.lattice import KEY_RANGE, pack_keys, unpack_keys
from panovocc_cli.semantics.gsc import (GSCParams, block_halo, consolidate, consolidate_blocks, key_blocks,
                                        nearest_evidence_transfer, transfer_offsets)


def _planes(offset=(0, 0, 0)):
    """Walls on the faces of 8-voxel cubes (x = 7 | 8, y = 16 | 15), a floor, a slanted strip and a corner:
    the voxels (sorted by key) and the whole-map labels' inputs, a class (3) absent from every voxel."""
    a = np.arange(-20, 30)
    u, v = np.meshgrid(a, np.arange(0, 24), indexing="ij")
    parts = [np.stack([np.full(u.size, x), u.ravel(), v.ravel()], 1) for x in (7, 8)]
    parts += [np.stack([u.ravel(), np.full(u.size, y), v.ravel()], 1) for y in (15, 16)]
    parts.append(np.stack([u.ravel(), v.ravel() - 4, np.zeros(u.size, int)], 1))  # floor z = 0
    t = np.arange(-20, 30)
    parts.append(np.stack([t, t // 2, 5 + t // 3], 1))  # a slanted strip
    idx = np.unique(np.concatenate(parts), axis=0).astype(np.int64) + np.asarray(offset, np.int64)
    keys = np.sort(pack_keys(idx))
    idx = unpack_keys(keys)
    n, c = len(idx), 5
    rng = np.random.default_rng(11)
    p = rng.dirichlet(np.ones(c), n).astype(np.float32)
    p[:, 3] = 0.0  # a class absent from the map
    p /= p.sum(1, keepdims=True)
    S = np.where(rng.random(n) < 0.35, 0.0, rng.uniform(0.1, 6.0, n)).astype(np.float32)
    p[S == 0] = 0.0
    g = rng.normal(0.3, 0.4, n)
    normals = np.where(rng.random((n, 1)) < 0.1, 0.0, rng.normal(size=(n, 3)))
    colors = np.where(rng.random((n, 1)) < 0.1, np.nan, rng.uniform(0, 255, (n, 3)))
    return keys, (p, S, g, normals, colors)


def _inputs(arrays):
    return lambda rows: tuple(a[rows] for a in arrays)


@pytest.mark.parametrize("offset", [(0, 0, 0), (KEY_RANGE - 60, -(KEY_RANGE - 30), 123_457)])
def test_blocks_equal_the_whole_map(offset):
    """Walls on cube faces, a class absent, far from the origin (near the lattice's edge): every cube size
    (one voxel's cube's neighbours in other cubes, 8 = the walls on the faces, one cube for all) gives the
    whole map's labels bit for bit, with GSC and without."""
    keys, arrays = _planes(offset)
    idx = unpack_keys(keys)
    for use_gsc in (True, False):
        whole = consolidate(idx, *arrays, use_gsc=use_gsc)
        assert (whole >= 0).sum() > 1000 and (whole == -1).any() and not (whole == 3).any()
        for block in (3, 8, 13, 64, 1 << 12):
            got = consolidate_blocks(keys, _inputs(arrays), use_gsc=use_gsc, block=block)
            assert np.array_equal(got, whole), (use_gsc, block, int((got != whole).sum()))


def test_a_tiny_map_is_one_block_and_an_empty_one_none():
    keys, arrays = _planes()
    keep = np.flatnonzero(np.all(np.abs(unpack_keys(keys) - [7, 3, 3]) <= 2, axis=1))
    keys, arrays = keys[keep], tuple(a[keep] for a in arrays)
    assert len(list(key_blocks(keys, gsc.BLOCK, 12))) == 1
    assert np.array_equal(consolidate_blocks(keys, _inputs(arrays)), consolidate(unpack_keys(keys), *arrays))
    assert consolidate_blocks(keys[:0], _inputs(arrays)).shape == (0,)


def test_the_halo_is_needed():
    """The halo is exactly long enough. A line of voxels x = -30..6 with evenly split evidence (an argmax
    tie), one strong class-1 voxel at x = -4, and a voxel without evidence and without neighbours at x = 8
    (the face of the cube x = 8..15): the push of x = -4 reaches x = 6 at the 10th iteration, and x = 8
    takes x = 6's label by the transfer (2 voxels). With the halo of block_halo (12) the cube labels x = 8
    with class 1 as the whole map does; with one voxel less, x = -4 falls outside and it gets class 0."""
    x = np.append(np.arange(-30, 7), 8)
    idx = np.stack([x, 0 * x, 0 * x], 1).astype(np.int64)
    keys = pack_keys(idx)
    n = len(idx)
    p = np.full((n, 2), 0.5, np.float32)
    S = np.full(n, 4.0, np.float32)
    p[x == -4] = [0.0, 1.0]
    S[x == -4] = 1000.0
    p[-1], S[-1] = 0.0, 0.0
    arrays = (p, S, np.zeros(n), np.zeros((n, 3)), np.full((n, 3), np.nan))
    whole = consolidate(idx, *arrays)
    assert whole[-1] == 1 and whole[x == 6] == 1 and whole[x == -15] == 0  # beyond 10 hops: the tie
    assert block_halo(True, GSCParams()) == 12 and block_halo(False, GSCParams()) == 2
    assert np.array_equal(consolidate_blocks(keys, _inputs(arrays), block=8), whole)
    real = gsc.block_halo
    try:
        gsc.block_halo = lambda use_gsc, params: real(use_gsc, params) - 1
        short = consolidate_blocks(keys, _inputs(arrays), block=8)
    finally:
        gsc.block_halo = real
    assert short[-1] == 0 and np.array_equal(short[:-1], whole[:-1])


def test_key_blocks_cover_every_key_once_with_its_halo():
    rng = np.random.default_rng(2)
    idx = np.unique(rng.integers(-40, 40, (3000, 3)), axis=0)
    keys = np.sort(pack_keys(idx))
    idx = unpack_keys(keys)
    for block, halo in ((5, 2), (16, 12), (200, 0)):
        seen = np.zeros(len(keys), int)
        for cube, rows, inner in key_blocks(keys, block, halo):
            box = np.all((idx >= cube * block - halo) & (idx < (cube + 1) * block + halo), axis=1)
            assert np.array_equal(rows, np.flatnonzero(box))
            assert np.array_equal(inner, np.all(idx[rows] // block == cube, axis=1))
            seen[rows[inner]] += 1
        assert (seen == 1).all()


def test_transfer_ties_go_to_the_smallest_key():
    """Equidistant voxels with evidence: the smallest key (x, then y, then z) gives the label, whatever the
    voxels' order and whichever other voxels are given; a nearer one always wins."""
    idx = np.array([[0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, -1], [5, 5, 5], [6, 6, 5], [4, 5, 5]])
    lab = np.array([-9, 1, 2, 3, 4, -9, 6, -9])
    has = np.array([False, True, True, True, True, False, True, False])
    out = nearest_evidence_transfer(idx, lab, has, 2.0)
    # (0,0,0): four sources at distance 1, smallest key (-1,0,0) -> 2; (5,5,5): (6,6,5) at sqrt 2 -> 6;
    # (4,5,5): (6,6,5) at sqrt 5 > 2 -> none
    assert out.tolist() == [2, 1, 2, 3, 4, 6, 6, -1]
    perm = np.random.default_rng(0).permutation(len(idx))
    assert np.array_equal(nearest_evidence_transfer(idx[perm], lab[perm], has[perm], 2.0), out[perm])
    keep = [0, 1, 3, 4]  # without (-1,0,0): the next smallest key among the equidistant, (0,0,-1)
    assert nearest_evidence_transfer(idx[keep], lab[keep], has[keep], 2.0).tolist() == [4, 1, 3, 4]
    o = transfer_offsets(2.0)
    d2 = (o * o).sum(1)
    assert len(o) == 32 and np.all(np.diff(d2) >= 0) and (d2 <= 4).all()
    assert len(transfer_offsets(1.0)) == 6 and len(transfer_offsets(0.0)) == 0


def test_transfer_at_the_lattice_edge_stays_inside():
    """A voxel without evidence on the lattice's last index: offsets beyond it are no voxels (no wrap to
    the other side of the key range)."""
    e = KEY_RANGE - 1
    idx = np.array([[e, 0, 0], [-e, 0, 0]])
    assert nearest_evidence_transfer(idx, np.array([-9, 7]), np.array([False, True]), 2.0).tolist() == [-1, 7]


def test_unique_pairs_equal_numpy_rows():
    """A slab's cubes (gsc._unique_pairs) are np.unique's rows, in the same order, from one int64 sort."""
    from panovocc_cli.semantics.gsc import _unique_pairs

    rng = np.random.default_rng(5)
    for lo, hi, n in ((-5, 5, 3000), (-2 ** 17, 2 ** 17, 50), (0, 1, 10), (3, 9, 1)):
        a, b = rng.integers(lo, hi, n), rng.integers(lo, hi, n)
        got = _unique_pairs(a, b)
        assert got.dtype == np.int64 and np.array_equal(got, np.unique(np.stack([a, b], 1), axis=0))
    assert _unique_pairs(np.zeros(0, np.int64), np.zeros(0, np.int64)).shape == (0, 2)
