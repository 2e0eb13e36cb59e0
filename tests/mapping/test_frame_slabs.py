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
                assert a.channels[name].dtype == b.channels[name].dtype == np.int64
                np.testing.assert_array_equal(a.channels[name], b.channels[name])
    g = whole[0]
    assert len(g) > 1000 and g.channels["F"].any() and g.channels["N"].any() and g.channels["A"].any()
