"""The hashed-block integer memory: exact reversibility, order independence, canonical bytes."""

import numpy as np
import pytest

from panovocc_cli.geometry.lattice import pack_keys
from panovocc_cli.mapping.memory import (FIXED_SCALE, ChannelSpec, Delta, VoxelMemory, merge_deltas, quantize)


def _random_delta(rng, n=3000, span=60, channels=("A", "N", "F", "O")):
    idx = rng.integers(-span, span, size=(n, 3))
    keys = np.unique(pack_keys(idx))
    ch = {c: rng.integers(-5, 2 ** 20, size=(len(keys), 1)) for c in channels}
    return Delta(keys, ch)


def test_add_remove_is_bit_identical_and_order_free():
    rng = np.random.default_rng(0)
    deltas = [_random_delta(rng) for _ in range(5)]
    a = VoxelMemory(0.08)
    for d in deltas:
        a.add(d)
    before = a.to_arrays()
    a.add(deltas[2], -1)
    a.add(deltas[2], +1)
    after = a.to_arrays()
    for k in before:
        np.testing.assert_array_equal(before[k], after[k])
    b = VoxelMemory(0.08)
    for d in reversed(deltas):
        b.add(d)
    for k in before:
        np.testing.assert_array_equal(before[k], b.to_arrays()[k])
    # the memory is the sum of its deltas, checked a second way (dense accumulation by key)
    allk = np.concatenate([d.keys for d in deltas])
    allv = np.concatenate([d.channels["F"][:, 0] for d in deltas])
    uk, inv = np.unique(allk, return_inverse=True)
    sums = np.bincount(inv, weights=allv.astype(np.float64)).astype(np.int64)
    got = a.gather(uk)["F"][:, 0]
    np.testing.assert_array_equal(got, sums)


def test_removing_everything_leaves_an_empty_memory():
    rng = np.random.default_rng(1)
    d = _random_delta(rng, n=20000, span=200)  # many blocks: forces table and storage growth
    m = VoxelMemory(0.08)
    m.add(d)
    assert m.n_blocks > 256
    keys, ch = m.nonzero()
    np.testing.assert_array_equal(keys, d.keys[np.any(np.hstack(list(d.channels.values())) != 0, axis=1)])
    m.add(d, -1)
    assert len(m.nonzero()[0]) == 0


def test_generic_channels_and_merge():
    specs = [ChannelSpec("A", 1, "fixed"), ChannelSpec("E", 5, "fixed"), ChannelSpec("count", 1, "int")]
    m = VoxelMemory(0.05, specs)
    k1 = pack_keys(np.array([[0, 0, 0], [-1, 2, 3]]))
    k2 = pack_keys(np.array([[-1, 2, 3], [7, 7, 7]]))
    o1, o2 = np.argsort(k1), np.argsort(k2)
    d1 = Delta(k1[o1], {"A": quantize([[0.5], [1.0]], "fixed")[o1]})
    d2 = Delta(k2[o2], {"E": quantize(np.ones((2, 5)) * 0.25, "fixed"), "count": np.array([[1], [2]])})
    d = merge_deltas([d1, d2])
    assert len(d) == 3 and d.channels["E"].shape == (3, 5)
    m.add(d)
    m2 = VoxelMemory.from_arrays(m.to_arrays())
    got = m2.gather(pack_keys(np.array([[-1, 2, 3]])))
    assert got["A"][0, 0] == FIXED_SCALE and got["E"][0, 0] == FIXED_SCALE // 4
    with pytest.raises(ValueError):
        m.add(Delta(k1[o1], {"E": np.zeros((2, 3), np.int64)}))  # wrong width
