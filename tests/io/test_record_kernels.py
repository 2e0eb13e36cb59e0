"""The compiled passes of the delta record (io/record_kernels.py) against the numpy formulations they replace,
including values at the ends of int64 (products that wrap, INT64_MIN // -1, |INT64_MIN|), and the records they
make and read byte for byte (docs/mapping.md, "Building revise, fifth pass")."""

import numpy as np
import pytest

from panovocc_cli.io import mapstore, record_kernels as rk
from panovocc_cli.mapping.memory import Delta, FrameDelta
from panovocc_cli.mapping.rpu import encode_record

I64 = np.iinfo(np.int64)


def _np_factor(x, f, den):
    num = x * np.int64(den)
    safe = np.where(f != 0, f, 1)
    with np.errstate(over="ignore"):
        m = np.where(f != 0, num // safe, 0)
    return np.array_equal(m * f, num), m


def _factor_cases(rng):
    n = 300
    f = rng.integers(0, 9, (n, 1))
    yield rng.integers(-50, 50, (n, 12)) * f, f, 64  # holds: x = f m
    yield rng.integers(-50, 50, (n, 3)) * f // 2, f, 1  # holds or not, by row
    x = rng.integers(-50, 50, (n, 3)) * f
    x[7, 1] += 1  # one value that does not factor
    yield x, f, 1
    x = rng.integers(-50, 50, (n, 3)) * f
    x[np.flatnonzero(f[:, 0] == 0)[:1], 0] = 5  # non-zero where the factor is 0
    yield x, f, 1
    f = rng.integers(-3, 4, (n, 1))  # negative factors: floor division
    yield rng.integers(-50, 50, (n, 2)) * f, f, 3
    yield np.array([[I64.min], [I64.max], [I64.min], [3]]), np.array([[-1], [-1], [1], [2]]), 1  # INT64_MIN // -1
    yield np.array([[I64.max // 3 + 5], [4]]), np.array([[1], [2]]), 64  # x den wraps
    yield np.zeros((0, 4), np.int64), np.zeros((0, 1), np.int64), 7


def test_factor_rows_equals_numpy():
    rng = np.random.default_rng(0)
    for x, f, den in _factor_cases(rng):
        x, f = np.asarray(x, np.int64), np.asarray(f, np.int64)
        ok_np, m_np = _np_factor(x, f, den)
        ok, m = rk.factor_rows(np.ascontiguousarray(x), np.ascontiguousarray(f[:, 0]), np.int64(den))
        assert ok == ok_np
        if ok:
            assert m.dtype == np.int64 and np.array_equal(m, m_np)


def test_nonzero_rows_equals_numpy():
    rng = np.random.default_rng(1)
    for shape, p in [((1000, 1), 0.3), ((500, 12), 0.05), ((0, 3), 0.5), ((40, 4), 0.0), ((40, 2), 1.0)]:
        a = np.where(rng.random(shape) < p, rng.integers(-5, 6, shape), 0).astype(np.int64)
        a[::17] = 0
        got = rk.nonzero_rows(a)
        assert got.dtype == np.int64 and np.array_equal(got, np.flatnonzero(a.any(axis=1)))
    col = np.arange(-3, 9).reshape(4, 3)[:, 1:2]  # a column view (not contiguous)
    assert np.array_equal(rk.nonzero_rows(np.ascontiguousarray(col)), np.flatnonzero(col.any(axis=1)))


def _np_gaps(keys):
    g = np.diff(keys)
    jump = np.abs(g) > mapstore._GAP_MAX
    return np.where(jump, mapstore._GAP_JUMP, g).astype(np.int16), g[jump]


def test_key_gaps_round_trip_and_equal_numpy():
    rng = np.random.default_rng(2)
    cases = [np.unique(rng.integers(-10**12, 10**12, 5000)), np.cumsum(rng.integers(1, 40, 3000)) - 77,
             np.array([], np.int64), np.array([5], np.int64),
             np.array([0, 32767, 65535, 65536, 65536 + 32768], np.int64),  # gaps at and past int16
             np.array([I64.max, I64.min, 0, -3], np.int64)]  # wrapping gaps, |INT64_MIN| (not sorted: as numpy)
    for keys in cases:
        keys = np.asarray(keys, np.int64)
        gaps, jumps = rk.key_gaps(keys, mapstore._GAP_MAX, mapstore._GAP_JUMP)
        g_np, j_np = _np_gaps(keys)
        assert gaps.dtype == g_np.dtype and gaps.shape == g_np.shape and np.array_equal(gaps, g_np)
        assert jumps.dtype == j_np.dtype and np.array_equal(jumps, j_np)
        ok, back = rk.keys_from_gaps(keys[:1], gaps, jumps, mapstore._GAP_JUMP)
        g = gaps.astype(np.int64)  # the numpy decoding
        g[g == mapstore._GAP_JUMP] = jumps
        assert ok and np.array_equal(back, np.cumsum(np.concatenate([keys[:1], g])))
        if not len(keys) or keys[0] != I64.max:  # a gap of |INT64_MIN| is stored as 0 by either formulation: the last case only
            assert np.array_equal(back, keys)
    ok, _ = rk.keys_from_gaps(np.array([1]), np.array([mapstore._GAP_JUMP, 3], np.int16), np.zeros(0, np.int64),
                              mapstore._GAP_JUMP)
    assert not ok  # a jump mark without its jump: damaged
    ok, _ = rk.keys_from_gaps(np.array([1]), np.array([2, 3], np.int16), np.array([5]), mapstore._GAP_JUMP)
    assert not ok  # a jump without its mark


def test_scatter_rows_and_planes_equal_numpy():
    rng = np.random.default_rng(3)
    n = 1000
    rows = np.sort(rng.choice(n, 200, replace=False))
    vals = rng.integers(-10**15, 10**15, (200, 3))
    gaps = np.diff(rows, prepend=0)
    ok, full = rk.scatter_rows(n, gaps.astype(np.int64), vals)
    want = np.zeros((n, 3), np.int64)
    want[rows] = vals
    assert ok and np.array_equal(full, want)
    assert not rk.scatter_rows(5, np.array([2, 3], np.int64), np.ones((2, 1), np.int64))[0]  # row 5 of 5
    assert not rk.scatter_rows(5, np.array([-1], np.int64), np.ones((1, 1), np.int64))[0]
    for dt in (np.int16, np.int32, np.int64):
        a = rng.integers(np.iinfo(dt).min, np.iinfo(dt).max, 777, dtype=dt, endpoint=True)
        a[:2] = np.iinfo(dt).min, np.iinfo(dt).max
        planes = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")).view(np.uint8).reshape(-1, a.itemsize).T)
        got = rk.from_planes(planes)
        assert got.dtype == np.int64 and np.array_equal(got, a.astype(np.int64))


def _old_encode_arrays(parts, T, observation=None):
    """delta_arrays as it was before the compiled passes (the numpy formulation)."""
    arrays = {"T_world_cam": np.asarray(T, np.float64)}
    for i, part in enumerate(parts):
        keys, channels = part[0], part[1]
        pre = mapstore._part_prefix(i)
        keys = np.asarray(keys, np.int64)
        arrays[f"{pre}keys_diff"], arrays[f"{pre}keys_jumps"] = _np_gaps(keys)
        arrays[f"{pre}keys_first"] = keys[:1]
        mapstore._encode_channels(arrays, pre, len(keys), channels, part[2] if len(part) > 2 else None)
    for name, a in (observation or {}).items():
        arrays[f"obs_{name}"] = np.asarray(a)
    return arrays


def test_records_round_trip_with_sparse_dense_factored_channels():
    """A record of a geometry-like part (sparse and dense channels, key jumps) and a semantic-like part
    (factored channels, a wide mostly-zero channel, large values needing int64) reads back exactly, and its
    keys are encoded as the numpy formulation encodes them."""
    rng = np.random.default_rng(4)
    n = 5000
    keys = np.unique(np.concatenate([rng.integers(0, 60000, n), rng.integers(10**9, 10**9 + 10**6, 50)]))
    n = len(keys)
    geo = np.zeros((n, 4), np.int64)
    geo[rng.random(n) < 0.2, 0] = rng.integers(1, 1 << 20, int((rng.random(n) < 0.2).sum()))[:1]
    geo[:, 3] = 1
    geo[rng.random(n) < 0.1, 1] = 1
    geo[rng.random(n) < 0.7, 2] = -1
    m = 800
    sk = np.unique(rng.choice(keys, m, replace=False))
    m = len(sk)
    count = rng.integers(0, 5, (m, 1))
    E = np.where(rng.random((m, 12)) < 0.2, rng.integers(1, 60, (m, 12)), 0) * count * 64 // 64
    rgb = rng.integers(0, 256, (m, 3)) * count
    big = rng.integers(0, 3, (m, 1)) * (1 << 40)  # needs int64
    parts = [Delta(keys, {"A": geo[:, 0:1], "N": geo[:, 1:2], "F": geo[:, 2:3], "O": geo[:, 3:4]}),
             Delta(sk, {"E": E, "count": count, "rgb_sum": rgb, "S": big},
                   factors={"E": ("count", 64), "rgb_sum": ("count", 1)})]
    T = np.eye(4)
    payload = encode_record(FrameDelta(tuple(parts)), T)
    rec = mapstore.decode_record(payload)
    for p, (k, ch) in zip(parts, rec.parts):
        assert np.array_equal(k, p.keys)
        for name, v in p.channels.items():
            assert ch[name].dtype == np.int64 and np.array_equal(ch[name], v), name
    old = _old_encode_arrays([(p.keys, p.channels, p.factors) for p in parts], T)
    new = mapstore.delta_arrays([(p.keys, p.channels, p.factors) for p in parts], T)
    assert sorted(old) == sorted(new)
    for k in old:
        assert old[k].dtype == new[k].dtype and np.array_equal(old[k], new[k]), k
    assert mapstore.encode_arrays(old) == payload


def test_damaged_key_jumps_are_refused():
    payload = encode_record(FrameDelta((Delta(np.array([0, 100000, 100001]), {"A": np.ones((3, 1), np.int64)}),)),
                            np.eye(4))
    z = dict(mapstore.decode_arrays(payload))
    z["keys_jumps"] = np.zeros(0, np.int64)
    with pytest.raises(Exception, match="cannot read delta"):
        mapstore.decode_record(mapstore.encode_arrays(z))


def test_byte_planes_both_ways_equal_numpy():
    """to_planes gives _shuffled's numpy planes for 2-, 4- and 8-byte integers (extremes included), and
    StoredRows (a memory file's channel, read a slice at a time) reads them back as the whole decoding does."""
    rng = np.random.default_rng(5)
    for dt in (np.int16, np.int32, np.int64):
        a = rng.integers(np.iinfo(dt).min, np.iinfo(dt).max, (301, 3), dtype=dt, endpoint=True)
        a[0] = np.iinfo(dt).min, np.iinfo(dt).max, 0
        want = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")).reshape(-1).view(np.uint8)
                                    .reshape(-1, a.itemsize).T)
        got = rk.to_planes(a, a.itemsize)
        assert got.dtype == np.uint8 and np.array_equal(got, want)
        rows = mapstore.StoredRows(got, a.shape, True, 3)
        for sl in (slice(0, 301), slice(5, 77), slice(300, 301), slice(10, 10)):
            part = rows[sl]
            assert part.dtype == np.int64 and np.array_equal(part, a[sl].astype(np.int64) * 3)
    arrays = {}
    mapstore._shuffled(arrays, "ch_X", np.arange(-5, 7, dtype=np.int32).reshape(4, 3))
    assert arrays["shape_X"].tolist() == [4, 3] and arrays["ch_X"].shape == (4, 12)
    big_endian = np.arange(-5, 7, dtype=">i4").reshape(4, 3)  # not native: numpy's planes, the same bytes
    other = {}
    mapstore._shuffled(other, "ch_X", big_endian)
    assert np.array_equal(other["ch_X"], arrays["ch_X"])


def test_a_record_is_one_zstd_frame_of_its_table_and_raw_arrays():
    """encode_arrays feeds Zstandard one array at a time (no joined copy): the payload is one frame whose
    bytes are the table and the arrays' raw bytes, the same for equal arrays; a record written before
    (those bytes as one zlib stream) reads back to the same arrays."""
    import json
    import struct
    import zlib

    rng = np.random.default_rng(5)
    arrays = {"b": rng.integers(0, 3, 70_000).astype(np.uint8), "a": np.cumsum(rng.integers(0, 9, 50_000)),
              "c": rng.normal(size=(300, 4)), "d": np.zeros(0, np.int16), "e": np.array([7])}
    names = sorted(arrays)
    arrs = [np.ascontiguousarray(np.asarray(arrays[n])) for n in names]
    table = json.dumps([[n, a.dtype.str, list(a.shape)] for n, a in zip(names, arrs)], separators=(",", ":")).encode()
    joined = b"".join([struct.pack("<I", len(table)), table] + [a.tobytes() for a in arrs])
    payload = mapstore.encode_arrays(arrays)
    assert payload[:4] == mapstore.ZSTD_MAGIC and mapstore.payload_body(payload) == joined
    assert payload == mapstore.encode_arrays(dict(reversed(list(arrays.items()))))
    old = zlib.compress(joined, 1)
    assert mapstore.payload_body(old) == joined
    for n in names:
        assert np.array_equal(mapstore.decode_arrays(old)[n], arrays[n])
    back = mapstore.decode_arrays(payload)
    for n in names:
        assert np.array_equal(back[n], arrays[n]) and back[n].dtype == np.asarray(arrays[n]).dtype
