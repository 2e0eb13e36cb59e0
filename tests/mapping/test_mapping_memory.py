"""The hashed-block integer memory: exact reversibility, order independence, canonical bytes."""

import numpy as np
import pytest

from panovocc_cli.geometry.lattice import pack_keys
from panovocc_cli.mapping import memory
from panovocc_cli.mapping.memory import (FIXED_SCALE, ChannelSpec, Delta, FrameDelta, VoxelMemory, quantize)


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


def _small_storage(monkeypatch):
    """Start at 256 blocks (and rows) with ordinary zeros: forces table and storage growth by copying."""
    monkeypatch.setattr(memory, "RESERVE_BLOCKS", 256)
    monkeypatch.setattr(memory, "RESERVE_ROWS", 256)


def test_removing_everything_leaves_an_empty_memory(monkeypatch):
    _small_storage(monkeypatch)
    rng = np.random.default_rng(1)
    d = _random_delta(rng, n=20000, span=200)
    m = VoxelMemory(0.08)
    assert m._geo.shape[0] == 256
    m.add(d)
    assert m.n_blocks > 256 and m._geo.shape[0] > 256
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
    m.add(FrameDelta((d1, d2)))
    m2 = VoxelMemory.from_arrays(m.to_arrays())
    got = m2.gather(pack_keys(np.array([[-1, 2, 3]])))
    assert got["A"][0, 0] == FIXED_SCALE and got["E"][0, 0] == FIXED_SCALE // 4
    with pytest.raises(ValueError):
        m.add(Delta(k1[o1], {"E": np.zeros((2, 3), np.int64)}))  # wrong width


def _sums_by_key(deltas, name):
    allk = np.concatenate([d.keys for d in deltas])
    allv = np.concatenate([d.channels[name] for d in deltas])
    uk, inv = np.unique(allk, return_inverse=True)
    out = np.zeros((len(uk), allv.shape[1]), np.int64)
    np.add.at(out, inv, allv)
    return uk, out


def test_channels_sliced_from_one_rows_array_add_like_separate_arrays(monkeypatch):
    """add() reads a contributor's (n, m) rows in place when every channel is a column slice of it
    (any column order, widths > 1, columns left out, a strided base): same memory as copies."""
    _small_storage(monkeypatch)
    specs = [ChannelSpec("A", 1, "fixed"), ChannelSpec("E", 3, "int"), ChannelSpec("F", 1), ChannelSpec("O", 1)]
    rng = np.random.default_rng(3)
    deltas_view, deltas_copy = [], []
    for n_frame in range(4):
        keys = np.unique(pack_keys(rng.integers(-90, 90, size=(6000, 3))))
        rows = rng.integers(-3, 1000, size=(len(keys), 7))
        if n_frame == 3:  # a base whose columns are not adjacent in memory
            rows = np.ascontiguousarray(np.repeat(rows, 2, axis=1))[:, ::2]
        ch = {"O": rows[:, 0:1], "E": rows[:, 1:4], "A": rows[:, 5:6]}  # column 4 and 6 belong to no channel
        if n_frame == 1:
            ch["F"] = rows[:, 6:7]
        deltas_view.append(Delta(keys, ch))
        deltas_copy.append(Delta(keys, {k: v.copy() for k, v in ch.items()}))
    vals, cols = VoxelMemory(0.08, specs)._values(deltas_view[0])
    assert vals is deltas_view[0].channels["O"].base and cols.tolist() == [5, 1, 2, 3, -1, 0, -1]
    a, b = VoxelMemory(0.08, specs), VoxelMemory(0.08, specs)
    for dv, dc in zip(deltas_view, deltas_copy):
        a.add(dv)
        b.add(dc)
    a.add(deltas_view[2], -1)
    b.add(deltas_copy[2], -1)
    ta, tb = a.to_arrays(), b.to_arrays()
    for k in ta:
        np.testing.assert_array_equal(ta[k], tb[k])
    kept = [d for i, d in enumerate(deltas_copy) if i != 2]
    for name in ("A", "E", "O"):
        uk, want = _sums_by_key(kept, name)
        np.testing.assert_array_equal(a.gather(uk)[name], want)


def test_empty_delta_and_all_zero_depth_frame():
    """A frame with no valid depth (a dropped sensor frame) gives an empty delta, not a crash."""
    from panovocc_cli.mapping.contributors import geometry_delta
    from panovocc_cli.mapping.params import GeometryParams

    d = Delta(np.zeros(0, np.int64), {"A": np.zeros(0, np.int64), "E": np.zeros((0, 3), np.int64)})
    assert d.channels["A"].shape == (0, 1) and d.channels["E"].shape == (0, 3)
    delta = geometry_delta(np.zeros((32, 64), np.float32), np.eye(4), GeometryParams(stride=1))
    assert len(delta) == 0
    mem = VoxelMemory(0.08)
    mem.add(delta)
    assert len(mem) == 0


def _semantic_specs(C=4):
    from panovocc_cli.mapping.contributors import semantic_channels

    return memory.GEOMETRY_CHANNELS + semantic_channels(C)


def test_geometry_is_16_bytes_a_voxel_and_semantics_only_where_evidence_fell():
    rng = np.random.default_rng(5)
    geo = _random_delta(rng, n=40000, span=120)
    sem_keys = geo.keys[::10]  # a tenth of the voxels hold semantic evidence
    m = VoxelMemory(0.08, _semantic_specs())
    m.add(FrameDelta((geo, Delta(sem_keys, {"E": rng.integers(1, 9, (len(sem_keys), 4)),
                                             "count": np.ones((len(sem_keys), 1), np.int64)}))))
    b = m.nbytes()
    assert b["dense"] == m.allocated_voxels * 16  # A N F O as int32
    assert m.n_rows == len(sem_keys) and b["rows"] == len(sem_keys) * m.sparse_width * 4
    # rows are not taken by a delta whose semantic values are all zero
    m.add(Delta(geo.keys, {"S": np.zeros((len(geo.keys), 1), np.int64)}))
    assert m.n_rows == len(sem_keys)
    got = m.gather(sem_keys)
    assert np.all(got["count"] == 1) and np.all(m.gather(geo.keys[1::10])["E"] == 0)


def test_sums_past_int32_widen_and_past_int64_are_refused():
    from panovocc_cli.errors import PanovoccError

    m = VoxelMemory(0.08, _semantic_specs(2))
    k = pack_keys(np.array([[3, -4, 5], [100, 0, -7]]))
    big = np.int64(2 ** 31 - 10)
    m.add(Delta(k, {"A": np.array([[big], [1]]), "E": np.array([[big, 1], [0, 2]])}))
    assert m._geo.dtype == np.int32 and m._rows.dtype == np.int32
    m.add(Delta(k, {"A": np.array([[20], [1]]), "E": np.array([[20, 0], [0, 0]])}))  # 2^31 + 10: widened, exact
    assert m._geo.dtype == np.int64 and m._rows.dtype == np.int64
    got = m.gather(k)
    assert got["A"][:, 0].tolist() == [2 ** 31 + 10, 2] and got["E"][0].tolist() == [2 ** 31 + 10, 1]
    m.add(Delta(k, {"A": np.array([[20], [1]])}), -1)
    assert m.gather(k)["A"][:, 0].tolist() == [2 ** 31 - 10, 1]
    near = np.int64(2 ** 62)
    m.add(Delta(k[:1], {"A": np.array([[near]])}))
    m.add(Delta(k[:1], {"A": np.array([[near - 2 ** 31]])}))
    before = m.gather(k)["A"].copy()
    with pytest.raises(PanovoccError, match="int64"):
        m.add(Delta(k[::-1], {"A": np.array([[5], [10]])}))  # row 1 would pass 2^63 - 1: refused, row 0 undone
    np.testing.assert_array_equal(m.gather(k)["A"], before)
    sem = Delta(k[1:], {"E": np.array([[1, 1]])})
    with pytest.raises(PanovoccError, match="int64"):  # the geometry part was added, then taken out again
        m.add(FrameDelta((Delta(k[1:], {"N": np.array([[7]])}), sem, Delta(k[:1], {"A": np.array([[10]])}))))
    np.testing.assert_array_equal(m.gather(k)["A"], before)
    assert m.gather(k)["N"].sum() == 0 and m.gather(k)["E"][1].tolist() == [0, 2]


def test_storage_types_do_not_change_the_saved_arrays(monkeypatch):
    """A memory that widened, grew by copying or reserved its storage saves the same arrays."""
    rng = np.random.default_rng(8)
    deltas = [_random_delta(rng, n=5000, span=90) for _ in range(3)]
    a = VoxelMemory(0.08)
    for d in deltas:
        a.add(d)
    _small_storage(monkeypatch)
    b = VoxelMemory(0.08)
    b._widen("dense")
    for d in reversed(deltas):
        b.add(d)
    ta, tb = a.to_arrays(), b.to_arrays()
    assert b._geo.dtype == np.int64 and a._geo.dtype == np.int32
    for key in ta:
        np.testing.assert_array_equal(ta[key], tb[key])


def test_memory_file_from_sparse_rows_has_the_same_bytes(tmp_path):
    """memory.npz written from the sparse group's rows equals the file of the dense arrays, byte for byte,
    and reads back (sparse or dense) to the same memory."""
    from panovocc_cli.io import mapstore

    rng = np.random.default_rng(9)
    geo = _random_delta(rng, n=30000, span=100)
    m = VoxelMemory(0.08, _semantic_specs(3))
    for step in (3, 17):  # one channel on few rows (stored as rows), counts on many (stored dense)
        sk = geo.keys[::step]
        m.add(Delta(sk, {"E": rng.integers(0, 4, (len(sk), 3)), "count": np.ones((len(sk), 1), np.int64)}))
    m.add(geo)
    for name, arrays in (("dense", m.to_arrays()), ("sparse", m.to_arrays(sparse=True))):
        (tmp_path / name).mkdir()
        mapstore.write_memory(tmp_path / name, arrays, 1, np.eye(4)[None])
    assert (tmp_path / "dense" / "memory.npz").read_bytes() == (tmp_path / "sparse" / "memory.npz").read_bytes()
    for sparse in (False, True):
        arrays = mapstore.read_memory(tmp_path / "sparse", sparse=sparse)[0]
        back = VoxelMemory.from_arrays(arrays).to_arrays()
        for key, want in m.to_arrays().items():
            np.testing.assert_array_equal(back[key], want)


def _streamable_memory(rng, wide: bool):
    """A memory with the cases the memory file's encoding tells apart: class distributions that are mostly
    zeros (stored as entries and mask), a channel with a common divisor, channels on few rows (stored as
    rows) and on most (stored whole), far-apart keys (a row gap past int16); ``wide``: geometry widened to
    int64 (a sum past int32)."""
    geo = _random_delta(rng, n=20000, span=50)
    geo.channels["N"] = 4 * geo.channels["N"]  # a common divisor of 4
    m = VoxelMemory(0.08, _semantic_specs(12))
    far = np.unique(pack_keys(rng.integers(-900, 900, size=(300, 3))))
    m.add(Delta(far, {"A": np.ones((len(far), 1), np.int64)}))
    for step in (3, 17):
        sk = geo.keys[::step]
        e = np.zeros((len(sk), 12), np.int64)
        e[np.arange(len(sk)), rng.integers(0, 12, len(sk))] = rng.integers(1, 90, len(sk))
        m.add(Delta(sk, {"E": e, "count": np.ones((len(sk), 1), np.int64)}))
    m.add(geo)
    if wide:
        m.add(Delta(geo.keys[:5], {"F": np.full((5, 1), 2 ** 33, np.int64)}))
    return m


@pytest.mark.parametrize("wide", [False, True])
def test_memory_file_streamed_in_key_ranges_has_the_same_bytes(tmp_path, wide):
    """memory.npz written as a stream (``VoxelMemory.chunked``: a few x-slabs of blocks at a time, a slab
    larger than a chunk a few x offsets at a time) equals the file written from whole arrays, byte for
    byte, whatever the chunk; every chunk holds at most the chunk's voxels when the slabs fit in it."""
    from panovocc_cli.io import mapstore

    rng = np.random.default_rng(21)
    m = _streamable_memory(rng, wide)
    assert (m._geo.dtype == np.int64) == wide
    (tmp_path / "whole").mkdir()
    mapstore.write_memory(tmp_path / "whole", m.to_arrays(sparse=True), 1, np.eye(4)[None])
    want = (tmp_path / "whole" / "memory.npz").read_bytes()
    with np.load(tmp_path / "whole" / "memory.npz") as z:  # the encodings the test means to cover
        assert {"nz_E", "gcd_N", "rows_E", "shape_A", "shape_E"} <= set(z.files)
    all_keys = m.to_arrays()["keys"]
    for chunk in (None, 4096, 512):
        for scanned in (True, False):  # scanned x-slab by x-slab, or slices of an export's key order
            if scanned:
                m._nonzero = None
            arrays = m.chunked(chunk)
            out = tmp_path / f"{chunk}-{scanned}"
            out.mkdir()
            mapstore.write_memory(out, arrays, 1, np.eye(4)[None])
            assert (out / "memory.npz").read_bytes() == want, (chunk, scanned)
            keys = [k for _, k, _ in m.chunked(chunk).chunks()]
            np.testing.assert_array_equal(np.concatenate(keys), all_keys)
            assert max(len(k) for k in keys) <= (chunk or memory.SAVE_CHUNK)
            if chunk == 4096 and scanned:
                assert len(keys) > 10
        m.nonzero()  # the scan's key order, cached for the next round
    m._nonzero = None
    np.testing.assert_array_equal(m.nonzero()[0], all_keys)
    # read for a load: channels kept in their stored form, decoded a slice of rows at a time, the same values
    lazy, eager = mapstore.read_memory(tmp_path / "whole", sparse=True)[0], mapstore.read_memory(tmp_path / "whole")[0]
    for k, v in eager.items():
        if k.startswith("ch_"):
            got = lazy[k].dense() if isinstance(lazy[k], mapstore.SparseRows) else np.asarray(lazy[k])
            np.testing.assert_array_equal(got, v)
    stored = [v for v in lazy.values() if isinstance(v, mapstore.StoredRows)]
    stored += [v.values for v in lazy.values() if isinstance(v, mapstore.SparseRows)]
    assert any(isinstance(v, mapstore.StoredRows) for v in stored)
    for v in stored:
        np.testing.assert_array_equal(v[3:40], np.asarray(v)[3:40])


def test_an_empty_memory_streams_to_the_same_file(tmp_path):
    from panovocc_cli.io import mapstore

    for specs in (memory.GEOMETRY_CHANNELS, _semantic_specs(3)):
        m = VoxelMemory(0.08, specs)
        for name, arrays in (("whole", m.to_arrays(sparse=True)), ("stream", m.chunked())):
            (tmp_path / name).mkdir(exist_ok=True)
            mapstore.write_memory(tmp_path / name, arrays, 0, np.zeros((0, 4, 4)))
        assert (tmp_path / "whole" / "memory.npz").read_bytes() == (tmp_path / "stream" / "memory.npz").read_bytes()


def test_a_memory_file_loads_in_chunks_of_rows_to_the_same_memory(monkeypatch):
    """``from_arrays`` adds a memory file's voxels ``LOAD_CHUNK`` rows at a time (a loaded building's
    (rows, channels) int64 matrix would be half a gigabyte of fresh pages), dense rows and sparse rows alike,
    channels stored as rows at the same voxels together, and rebuilds the same memory."""
    from panovocc_cli.io.mapstore import SparseRows
    from panovocc_cli.mapping import memory

    rng = np.random.default_rng(11)
    geo = _random_delta(rng, n=3000, span=40)
    m = VoxelMemory(0.08, _semantic_specs(3))
    sk = geo.keys[::5]
    m.add(Delta(sk, {"E": rng.integers(0, 4, (len(sk), 3)), "count": np.ones((len(sk), 1), np.int64)}))
    m.add(geo)
    want = m.to_arrays()
    sizes = []
    real = VoxelMemory.add
    together = []
    monkeypatch.setattr(VoxelMemory, "add", lambda self, d, sign=1: (sizes.append(len(d)), together.append(
        sorted(d.channels)), real(self, d, sign))[2])
    monkeypatch.setattr(memory, "LOAD_CHUNK", 64)
    for arrays in (want, m.to_arrays(sparse=True)):
        sizes.clear()
        together.clear()
        back = VoxelMemory.from_arrays(arrays).to_arrays()
        assert max(sizes) <= 64 and sum(sizes) >= len(want["keys"])
        for key, value in want.items():
            np.testing.assert_array_equal(back[key], value.dense() if isinstance(value, SparseRows) else value)
    # from rows (the second form): the semantic channels at the same voxels are added together, one pass
    assert any({"E", "count"} <= set(names) for names in together)


def _swapped(specs, kept, o, n, swap=None):
    """(memory of kept + o, then o subtracted and n added; the same memory swapped by ``replace`` (or
    ``swap(memory)``))."""
    want, got = VoxelMemory(0.08, specs), VoxelMemory(0.08, specs)
    for m in (want, got):
        m.add(kept)
        m.add(o)
    want.add(o, -1)
    want.add(n, +1)
    (swap or (lambda m: m.replace(o, n)))(got)
    return want, got


def test_replace_equals_subtract_then_add_in_one_pass(monkeypatch):
    """``replace(old, new)`` (a revision's swap of a frame's delta) gives the memory ``add(old, -1)`` then
    ``add(new, +1)`` gives, bit for bit and with the same allocated blocks and rows, adding each part once
    over the union of its keys less the kept voxels it does not change; parts of different channels, and
    differences past int64, take the two passes."""
    rng = np.random.default_rng(12)
    specs = _semantic_specs(3)

    def frame():
        geo = _random_delta(rng, n=4000, span=30)
        sk = geo.keys[::7]
        sem = Delta(sk, {"E": rng.integers(0, 5, (len(sk), 3)), "S": rng.integers(0, 9, (len(sk), 1)),
                         "count": np.ones((len(sk), 1), np.int64)})
        return FrameDelta((geo, sem))

    kept, old, new = frame(), frame(), frame()
    cases = [(old, new), (old, FrameDelta(new.parts[:1])), (FrameDelta(old.parts[1:]), new)]
    big = Delta(old.parts[0].keys[:3], {c: np.full((3, 1), 2 ** 62) for c in ("A", "N", "F", "O")})
    cases.append((FrameDelta((Delta(big.keys, {c: -v for c, v in big.channels.items()}),)), FrameDelta((big,))))
    # a small pose correction: most voxels keep their values (left out of the pass), a few change, a few
    # are new, one of them with zero values (still added: it allocates its block, as add(new, +1) does)
    g, sem = old.parts
    near_geo = {c: v.copy() for c, v in g.channels.items()}
    near_geo["F"][::10] += 1
    far = np.array([pack_keys(np.array([[200, 200, 200]]))[0], pack_keys(np.array([[300, 0, 0]]))[0]])
    keys = np.concatenate([g.keys, far])
    near_geo = {c: np.concatenate([v, np.zeros((2, v.shape[1]), np.int64)]) for c, v in near_geo.items()}
    near_geo["A"][-1] = 7
    cases.append((old, FrameDelta((Delta(keys, near_geo), Delta(sem.keys, {c: v.copy() for c, v in sem.channels.items()})))))
    for case, (o, n) in enumerate(cases):
        passes = []
        real = VoxelMemory._add_group

        def counted(m, o=o, n=n):
            monkeypatch.setattr(VoxelMemory, "_add_group",
                                lambda self, g, k, *a: (passes.append((g, len(k))), real(self, g, k, *a))[1])
            m.replace(o, n)
            monkeypatch.setattr(VoxelMemory, "_add_group", real)

        want, got = _swapped(specs, kept, o, n, counted)
        if case == 0:
            assert [g for g, _ in passes] == ["dense", "sparse"], passes  # one pass a group
        if case == len(cases) - 1:  # the unchanged voxels were left out; the new zero row was not
            assert passes == [("dense", len(g.keys[::10]) + 2)], passes
        a, b = want.to_arrays(), got.to_arrays()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
        assert (want.n_blocks, want.n_pages, want.n_rows) == (got.n_blocks, got.n_pages, got.n_rows)


def test_reading_a_kept_delta_waits_only_for_its_own_pending_write(tmp_path, monkeypatch):
    """``DeltaStore.get`` of a frame whose record is not the one being written does not wait for the writer
    thread (a revision reads the next frame's old delta while the last one's record is compressed); the
    frame in flight waits and reads its new delta."""
    import threading
    import time

    from panovocc_cli.io import mapstore
    from panovocc_cli.mapping.rpu import DeltaStore

    rng = np.random.default_rng(13)
    d0, d1, d2 = (_random_delta(rng, n=500, span=20) for _ in range(3))
    store = DeltaStore(tmp_path / "m")
    store.put(0, d0, np.eye(4))
    store.put(1, d1, np.eye(4))
    store.flush()
    release = threading.Event()
    real = mapstore.DeltaLog.append
    monkeypatch.setattr(mapstore.DeltaLog, "append", lambda self, *a: (release.wait(10), real(self, *a))[1])
    store.put(1, d2, 2 * np.eye(4))  # its record waits on the writer thread
    threading.Timer(1.5, release.set).start()
    t0 = time.perf_counter()
    got = store.get(0)
    assert time.perf_counter() - t0 < 1.0
    np.testing.assert_array_equal(got.parts[0].channels["F"], d0.channels["F"])
    got = store.get(1)  # the frame in flight: after its write
    assert time.perf_counter() - t0 >= 1.4
    np.testing.assert_array_equal(got.parts[0].channels["F"], d2.channels["F"])
    store.close()


def test_replace_reads_channels_as_views_of_any_layout():
    """The swap reads each side's channels without concatenating them when they are column views of one matrix
    (``memory._column_matrix``: the geometry kernel's (n, 4) A N F O, in another order than the channels'
    sorted names), and concatenates them otherwise (contiguous arrays, a mix, narrower integer types): every
    case gives the memory that subtract-then-add gives, including a key that leaves the memory, keys that
    enter it and sums past int32."""
    rng = np.random.default_rng(21)
    specs = _semantic_specs(3)
    kept = _random_delta(rng, n=3000, span=25)
    old = _random_delta(rng, n=3000, span=25)
    new = _random_delta(rng, n=3000, span=25)

    def views(d, order=("A", "N", "F", "O")):  # one (n, 4) matrix, channels its column views
        base = np.ascontiguousarray(np.concatenate([d.channels[c] for c in order], axis=1))
        return Delta(d.keys, {c: base[:, i:i + 1] for i, c in enumerate(order)})

    leaving = Delta(old.keys[:1], {c: np.full((1, 1), 5) for c in ("A", "N", "F", "O")})  # only in old: leaves
    big = Delta(new.keys[:2], {c: np.full((2, 1), 2 ** 40) for c in ("A", "N", "F", "O")})  # int64 sums
    mixed = {**views(new).channels, "F": np.ascontiguousarray(new.channels["F"])}
    small = {c: v.astype(np.int32) for c, v in old.channels.items() if np.abs(v).max() < 2 ** 31}
    assert small
    cases = [(old, views(new)), (views(old, ("O", "F", "N", "A")), new), (views(old), views(new)),
             (old, Delta(new.keys, mixed)), (leaving, big), (Delta(old.keys, {**old.channels, **small}), views(new))]
    for o, n in cases:
        want, got = _swapped(specs, kept, o, n)
        a, b = want.to_arrays(), got.to_arrays()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
        assert (want.n_blocks, want.n_rows) == (got.n_blocks, got.n_rows)
    names = sorted("ANFO")
    v = views(new)
    matrix, src = memory._column_matrix([v.channels[c] for c in names], len(v))
    assert matrix is v.channels["A"].base and src.tolist() == [0, 2, 1, 3]  # no copy: A F N O read from A N F O
    matrix, src = memory._column_matrix([mixed[c] for c in names], len(v))
    assert matrix.flags.c_contiguous and src.tolist() == [0, 1, 2, 3]  # a mix: concatenated
    np.testing.assert_array_equal(matrix, np.concatenate([new.channels[c] for c in names], axis=1))


def test_changed_blocks_are_the_blocks_an_add_reached():
    """After track_changes, changed_blocks() lists exactly the blocks (voxel index // 8) of the keys that adds
    and a replace reached since, in key order, on both sides of zero; before track_changes, one line."""
    from panovocc_cli.errors import PanovoccError

    rng = np.random.default_rng(3)
    m = VoxelMemory(0.08, memory.GEOMETRY_CHANNELS + (ChannelSpec("E", 1),))
    m.add(_random_delta(rng, 6000, 90, ("A", "N", "F", "O", "E")))
    with pytest.raises(PanovoccError, match="track_changes"):
        m.changed_blocks()
    m.track_changes()
    assert m.changed_blocks().shape == (0, 3)
    idx = rng.integers(-8, 9, size=(60, 3)) + np.array([40, -30, 5])  # a local change, blocks on both sides of 0
    keys = np.unique(pack_keys(idx))
    old = Delta(keys, {"A": np.zeros((len(keys), 1), np.int64), "N": np.ones((len(keys), 1), np.int64)})
    m.add(old)
    new = Delta(keys[::2], {"A": np.ones((len(keys[::2]), 1), np.int64), "N": np.ones((len(keys[::2]), 1), np.int64)})
    m.replace(old, new)
    want = np.unique(idx // 8, axis=0)
    got = m.changed_blocks()
    assert np.array_equal(got, want) and got.dtype == np.int64
