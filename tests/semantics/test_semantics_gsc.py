"""GSC: graph construction, affinity, anchored diffusion, nearest-evidence transfer."""


import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.semantics.gsc import (GSCParams, anchor_strength, consolidate, edge_affinity, gsc_diffuse,
                                        nearest_evidence_transfer, neighbour_edges, unaries)


def plane(nx, ny, z=0, axis_normal=2):
    a, b = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    cols = [a.ravel(), b.ravel()]
    cols.insert(axis_normal, np.full(a.size, z))
    return np.stack(cols, 1).astype(np.int64)


def test_neighbour_edges_match_brute_force():
    rng = np.random.default_rng(0)
    idx = np.unique(rng.integers(-4, 5, (300, 3)), axis=0)
    idx = idx[rng.permutation(len(idx))]
    i, j, a = neighbour_edges(idx)
    got = {(int(x), int(y), int(z)) for x, y, z in zip(i, j, a)}
    want = set()
    for p in range(len(idx)):
        for q in range(len(idx)):
            d = idx[q] - idx[p]
            if np.abs(d).sum() == 1 and d.max() == 1:
                want.add((p, q, int(np.argmax(d))))
    assert got == want and len(i) == len(want)


def test_duplicate_or_bad_indices():
    with pytest.raises(PanovoccError, match="repeat"):
        neighbour_edges(np.array([[0, 0, 0], [0, 0, 0]]))
    with pytest.raises(PanovoccError, match=r"\(n, 3\) integers"):
        neighbour_edges(np.zeros((3, 3)))


def test_affinity_terms():
    i, j, a = np.array([0, 0]), np.array([1, 2]), np.array([0, 2])  # edge along x, edge along z
    g = np.array([0.0, 0.5, 0.0])
    nz = np.array([[0, 0, 1.0]] * 3)
    col = np.array([[100, 100, 100], [100, 100, 100], [160, 100, 100.0]])
    p = GSCParams()
    w = edge_affinity(i, j, a, g, nz, col, p)
    assert w[0] == pytest.approx(np.exp(-0.5 / p.s_g), rel=1e-5)  # tangent edge: only k_g
    assert w[1] == pytest.approx(np.exp(-1.0 / p.s_t) * np.exp(-60 ** 2 / (2 * p.s_c ** 2)), rel=1e-4)
    # opposite normals do not connect; unknown normal/colour are neutral
    w = edge_affinity(i[:1], j[:1], a[:1], np.zeros(3), np.array([[0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0]]), col, p)
    assert w[0] == 0
    w = edge_affinity(i[:1], j[:1], a[:1], np.zeros(3), np.zeros((3, 3)), np.full((3, 3), np.nan), p)
    assert w[0] == pytest.approx(1.0)


@pytest.mark.parametrize("power", [2.0, 3.0, 1.5])
def test_affinity_equals_the_numpy_expressions_bit_for_bit(power):
    """The compiled gathers (gsc_kernels.edge_terms) give numpy's affinity to the bit: signed zeros, unknown
    normals (zero rows, also a single non-zero component) and colours (NaN), scores from 0 to tens."""
    from semantics_reference import affinity_numpy

    from panovocc_cli.semantics.gsc import _affinity, unit_rows

    rng = np.random.default_rng(int(power * 10))
    n, m = 5000, 40000
    i, j = rng.integers(0, n, m), rng.integers(0, n, m)
    axis = rng.integers(0, 3, m).astype(np.int8)
    g = (rng.normal(size=n) * rng.choice([0.0, 1e-3, 1.0, 30.0], n)).astype(np.float32)
    nrm = rng.normal(size=(n, 3))
    nrm[rng.random(n) < 0.1] = 0
    nrm[rng.random(n) < 0.05, 1:] = 0
    nrm[rng.random(n) < 0.05] = [0.0, -1.0, 0.0]  # dot products of -0.0 and exactly 0
    nh = unit_rows(nrm)
    col = (rng.random((n, 3)) * 255).astype(np.float32)
    col[rng.random(n) < 0.1] = np.nan
    p = GSCParams(normal_power=power)
    for it in (np.int32, np.int64):  # the two index types neighbour_edges hands out
        w = _affinity(i.astype(it), j.astype(it), axis, g, nh, col, p)
        ref = affinity_numpy(i, j, axis, g, nh, col, p)
        assert w.dtype == np.float32 and np.array_equal(w.view(np.uint32), ref.view(np.uint32))


@pytest.mark.parametrize("scale", [1.0, 1e-30])
def test_transition_matrix_equals_scipy_bit_for_bit(scale):
    """The compiled CSR (gsc_kernels.transition_csr) is scipy's matrix of the doubled edges to the bit: its row
    pointers, columns (sorted within a row), weights over float64 degrees, and numpy's row sums; edges of zero
    weight left out, rows with none empty; weights near float32's smallest."""
    from semantics_reference import transition_scipy

    from panovocc_cli.geometry.lattice import pack_keys
    from panovocc_cli.semantics.gsc import transition_matrix

    rng = np.random.default_rng(7)
    idx = np.unique(rng.integers(0, 25, (9000, 3)), axis=0)
    idx = idx[np.argsort(pack_keys(idx))]
    i, j, _ = neighbour_edges(idx)
    w = (rng.random(i.size) * scale).astype(np.float32)
    w[rng.random(i.size) < 0.2] = 0
    got, ref = transition_matrix(len(idx), i, j, w), transition_scipy(len(idx), i, j, w)
    for a, b in zip(got, ref):
        assert a.dtype == b.dtype and np.array_equal(a.view(np.uint8), b.view(np.uint8))


def test_anchor_strength():
    p = np.array([[1.0, 0.0], [0.5, 0.5], [1.0, 0.0]])
    rho = anchor_strength(p, np.array([2.0, 5.0, 0.0]), S0=2.0)
    np.testing.assert_allclose(rho, [0.5, 0.0, 0.0], atol=1e-6)


def test_planar_patch_with_wrong_voxels_is_corrected():
    rng = np.random.default_rng(1)
    idx = plane(20, 20)
    n, c = len(idx), 4
    p = np.tile([0.7, 0.1, 0.1, 0.1], (n, 1))
    wrong = rng.choice(n, 12, replace=False)
    p[wrong] = [0.1, 0.1, 0.7, 0.1]
    S = np.full(n, 3.0)
    normals = np.tile([0, 0, 1.0], (n, 1))
    colors = np.full((n, 3), 120.0)
    raw = consolidate(idx, p, S, np.zeros(n), normals, colors, use_gsc=False)
    out = consolidate(idx, p, S, np.zeros(n), normals, colors)
    assert (raw[wrong] == 2).all()
    assert (out == 0).all()


def two_walls(same_normals):
    a = plane(12, 12, 0, axis_normal=0)
    b = plane(12, 12, 1, axis_normal=0)
    idx = np.concatenate([a, b])
    n = len(idx)
    p = np.concatenate([np.tile([0.99, 0.01], (len(a), 1)), np.tile([0.4, 0.6], (len(b), 1))])
    S = np.concatenate([np.full(len(a), 50.0), np.full(len(b), 0.5)])
    nb = [1.0, 0, 0] if same_normals else [-1.0, 0, 0]
    normals = np.concatenate([np.tile([1.0, 0, 0], (len(a), 1)), np.tile(nb, (len(b), 1))])
    return idx, p, S, np.zeros(n), normals, np.full((n, 3), 100.0), len(a)


@pytest.mark.parametrize("same_normals", [True, False])
def test_parallel_walls_one_voxel_apart_do_not_bleed(same_normals):
    idx, p, S, g, normals, colors, na = two_walls(same_normals)
    out = consolidate(idx, p, S, g, normals, colors)
    assert (out[:na] == 0).all() and (out[na:] == 1).all()
    # control: without the normal terms the confident wall does bleed into the weak one
    loose = GSCParams(normal_power=0.0, s_t=1e9)
    assert (consolidate(idx, p, S, g, normals, colors, params=loose)[na:] == 0).mean() > 0.5


def test_no_evidence_voxels_filled_within_bound_only():
    idx = np.stack([np.arange(12), np.zeros(12, int), np.zeros(12, int)], 1)
    p = np.zeros((12, 3))
    p[:4] = [0.1, 0.8, 0.1]
    S = np.zeros(12)
    S[:4] = 2.0
    normals = np.tile([0, 0, 1.0], (12, 1))
    colors = np.full((12, 3), np.nan)
    for use_gsc in (True, False):
        out = consolidate(idx, p, S, np.zeros(12), normals, colors, use_gsc=use_gsc,
                          params=GSCParams(max_dist_vox=2.0))
        np.testing.assert_array_equal(out, [1] * 6 + [-1] * 6)


def test_nearest_evidence_transfer_picks_the_nearest():
    idx = np.array([[0, 0, 0], [10, 0, 0], [3, 0, 0], [8, 0, 0], [5, 5, 5]])
    labels = np.array([4, 7, -5, -5, -5])
    has = np.array([True, True, False, False, False])
    out = nearest_evidence_transfer(idx, labels, has, max_dist_vox=3.0)
    np.testing.assert_array_equal(out, [4, 7, 4, 7, -1])
    np.testing.assert_array_equal(nearest_evidence_transfer(idx, labels, has, 0.0), [4, 7, -1, -1, -1])


def test_unaries():
    E = np.array([[2.0, 1.0], [0.0, 0.0]])
    p, nrm, col = unaries(E, np.array([3.0, 0.0]), np.array([[0, 0, 4.0], [0, 0, 0]]),
                          np.array([[30, 60, 90.0], [0, 0, 0]]), np.array([3, 0]))
    np.testing.assert_allclose(p, [[2 / 3, 1 / 3], [0, 0]], atol=1e-6)
    np.testing.assert_allclose(nrm, [[0, 0, 1], [0, 0, 0]])
    np.testing.assert_allclose(col[0], [10, 20, 30])
    assert np.isnan(col[1]).all()


def test_deterministic_and_order_independent():
    rng = np.random.default_rng(5)
    idx = np.unique(rng.integers(0, 15, (1500, 3)), axis=0)
    n = len(idx)
    p = rng.dirichlet(np.ones(5), n)
    S = rng.uniform(0, 3, n) * (rng.random(n) > 0.2)
    g = rng.normal(0, 0.3, n)
    nr = rng.normal(size=(n, 3))
    col = rng.uniform(0, 255, (n, 3))
    a = gsc_diffuse(idx, p, S, g, nr, col)
    b = gsc_diffuse(idx, p, S, g, nr, col)
    assert a.tobytes() == b.tobytes()
    perm = rng.permutation(n)
    c = gsc_diffuse(idx[perm], p[perm], S[perm], g[perm], nr[perm], col[perm])
    assert np.array_equal(c, a[perm])
    la = consolidate(idx, p, S, g, nr, col)
    assert np.array_equal(consolidate(idx[perm], p[perm], S[perm], g[perm], nr[perm], col[perm]), la[perm])


def test_a_slab_of_200k_voxels_consolidates():
    """200k voxels consolidate to valid labels (GSC speed is measured in docs/semantics.md, not tested)."""
    rng = np.random.default_rng(0)
    idx = plane(500, 400)
    n = len(idx)
    p = rng.dirichlet(np.ones(12), n).astype(np.float32)
    S = rng.uniform(0, 5, n).astype(np.float32) * (rng.random(n) > 0.1)
    out = consolidate(idx, p, S, np.zeros(n, np.float32), np.tile(np.float32([0, 0, 1]), (n, 1)),
                      rng.uniform(0, 255, (n, 3)).astype(np.float32))
    assert out.shape == (n,) and (out >= 0).all() and (out < 12).all()


def test_voxels_in_key_order_skip_the_sorted_copies_with_the_same_result():
    """gsc_diffuse and neighbour_edges work in lattice-key order; voxels given in that order (an export's)
    are used as they are instead of copied into it: the same distributions, bit for bit, as the same voxels
    given shuffled, and the edges' positions in 32 bits."""
    from panovocc_cli.geometry.lattice import pack_keys

    rng = np.random.default_rng(3)
    idx = np.unique(rng.integers(-6, 7, (900, 3)), axis=0)
    idx = idx[np.argsort(pack_keys(idx), kind="stable")]
    n, c = len(idx), 5
    p = rng.dirichlet(np.ones(c), n).astype(np.float32)
    S = np.where(rng.random(n) < 0.3, 0.0, rng.random(n) * 4).astype(np.float32)
    p[S == 0] = 0.0
    g, normals, colors = rng.random(n), rng.normal(size=(n, 3)), rng.random((n, 3)) * 255
    q = gsc_diffuse(idx, p, S, g, normals, colors)
    perm = rng.permutation(n)
    q_perm = gsc_diffuse(idx[perm], p[perm], S[perm], g[perm], normals[perm], colors[perm])
    assert np.array_equal(q[perm].view(np.uint32), q_perm.view(np.uint32))
    i, j, a = neighbour_edges(idx)
    assert i.dtype == j.dtype == np.int32 and a.dtype == np.int8 and len(i) > n // 2


def test_compiled_iterations_equal_the_scipy_product_bit_for_bit():
    """The diffusion's iterations run in one compiled pass a step (gsc_kernels.iterate); they give the same float32
    distributions, bit for bit, as the formulation they replaced (scipy's CSR product, then ``*= lam``,
    ``+= anchor``, ``*= inv``, copied into the live rows), with rows of no edges, dead rows and zero weights."""
    import scipy.sparse as sp

    from panovocc_cli.semantics.gsc import iterate_scipy
    from panovocc_cli.semantics.gsc_kernels import iterate as _iterate

    rng = np.random.default_rng(7)
    n, c = 3000, 12
    i, j = rng.integers(0, n, 20000), rng.integers(0, n, 20000)
    w = np.where(rng.random(20000) < 0.05, 0.0, rng.random(20000)).astype(np.float32)
    W = sp.csr_matrix((w, (i, j)), shape=(n, n))  # duplicates summed, rows without entries, explicit zeros
    W.data = (W.data / np.float32(7.0)).astype(np.float32)
    p = rng.dirichlet(np.ones(c), n).astype(np.float32)
    anchor = (rng.random((n, c)) * 3).astype(np.float32)
    inv = np.where(rng.random(n) < 0.1, 0.0, rng.random(n)).astype(np.float32)
    live = rng.random(n) < 0.9
    lam = np.float32(8.0)
    ref = iterate_scipy(W.indptr, W.indices, W.data, p.copy(), anchor, inv, live, lam, 20)
    out = _iterate(W.indptr, W.indices, W.data, p.copy(), anchor, inv, live, lam, 20)
    assert out.dtype == np.float32
    assert np.array_equal(out.view(np.uint32), ref.view(np.uint32))
    assert not np.array_equal(out, p)  # it did diffuse
    assert np.array_equal(_iterate(W.indptr, W.indices, W.data, p.copy(), anchor, inv, live, lam, 0), p)
