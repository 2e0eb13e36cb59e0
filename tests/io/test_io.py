"""Round-trips of every shared file format, and clear errors for bad files."""

import json

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.poses import look_at
from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import read_grid, write_grid
from panovocc_cli.io.images import read_depth
from panovocc_cli.io.poses import read_poses, write_poses, write_tum
from panovocc_cli.io.sequence import Sequence, SequenceMeta, write_frame, write_meta, write_sequence_poses


def _grid():
    rng = np.random.default_rng(1)
    lab = rng.integers(0, 4, size=(5, 6, 7)).astype(np.uint8)
    lab[0, 0, 0] = 255
    return Grid(lab, origin=np.array([0.04, -0.04, 1.24]), voxel_size=0.08, class_names=["empty", "wall", "floor", "chair"])


def test_grid_roundtrip_and_deterministic_bytes(tmp_path):
    g = _grid()
    write_grid(tmp_path / "a.npz", g)
    write_grid(tmp_path / "b.npz", g)
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    r = read_grid(tmp_path / "a.npz")
    assert np.array_equal(r.labels, g.labels) and r.class_names == g.class_names
    assert np.allclose(r.origin, g.origin) and r.voxel_size == 0.08
    with np.load(tmp_path / "a.npz", allow_pickle=False) as z:
        assert z["class_names"].dtype.kind == "U"


def test_grid_rejects_bad_files(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(PanovoccError, match="junk.npz"):
        read_grid(tmp_path / "junk.npz")
    g = _grid()
    g.origin = np.zeros(3)
    with pytest.raises(PanovoccError, match="lattice"):
        write_grid(tmp_path / "c.npz", g)
    assert not (tmp_path / "c.npz").exists()
    g = _grid()
    g.labels[1, 1, 1] = 9
    with pytest.raises(PanovoccError, match="class_names"):
        write_grid(tmp_path / "d.npz", g)


def test_poses_nice_slam_and_tum(tmp_path):
    T = np.stack([look_at([i, 0.0, 1.5], [1.0, 0.2 * i, 0.05]) for i in range(3)])
    write_poses(tmp_path / "traj.txt", T)
    assert np.array_equal(read_poses(tmp_path / "traj.txt"), T)
    assert len((tmp_path / "traj.txt").read_text().splitlines()[0].split()) == 16
    write_tum(tmp_path / "traj.tum", T)
    assert np.allclose(read_poses(tmp_path / "traj.tum"), T, atol=1e-9)


@pytest.mark.parametrize("content,match", [
    ("1 " * 15 + "\n", "15 numbers"),
    (" ".join(["2"] * 16) + "\n", "line 1"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n", "line 2"),
    ("a b c d e f g h i j k l m n o p\n", "not a list of numbers"),
])
def test_bad_trajectories(tmp_path, content, match):
    p = tmp_path / "traj.txt"
    p.write_text(content)
    with pytest.raises(PanovoccError, match=match):
        read_poses(p)


def test_sequence_roundtrip(tmp_path):
    W, H = 16, 8
    seq = tmp_path / "seq"
    meta = SequenceMeta(width=W, height=H, frames=2, class_names=["unlabeled", "wall"])
    write_meta(seq, meta)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 6.0, size=(H, W)).astype(np.float32)
    depth[0, 0] = 0
    for i in range(2):
        write_frame(seq, i, rng.integers(0, 255, (H, W, 3), dtype=np.uint8), depth, np.ones((H, W), int))
    write_sequence_poses(seq, np.stack([np.eye(4)] * 2))
    s = Sequence(seq)
    assert len(s) == 2 and s.rgb(1).shape == (H, W, 3)
    assert np.allclose(s.depth(0), depth, atol=0.5e-3) and s.depth(0)[0, 0] == 0
    assert s.labels(0).max() == 1
    assert json.loads((seq / "meta.json").read_text())["camera"] == "erp"
    (seq / "depth" / "000001.png").write_bytes(b"\x89PNG garbage")
    with pytest.raises(PanovoccError, match="000001.png"):
        s.depth(1)


def test_float_exr_depth(tmp_path):
    from panovocc_cli.io.images import write_exr
    d = np.full((4, 8), 2.5, np.float32)
    write_exr(tmp_path / "ok.exr", d)
    assert np.array_equal(read_depth(tmp_path / "ok.exr", 1000.0, (4, 8)), d)
    d[0, 0] = -1
    write_exr(tmp_path / "neg.exr", d)
    with pytest.raises(PanovoccError, match="negative"):
        read_depth(tmp_path / "neg.exr", 1000.0)
    d[0, 0] = np.nan
    write_exr(tmp_path / "nan.exr", d)
    with pytest.raises(PanovoccError, match="NaN"):
        read_depth(tmp_path / "nan.exr", 1000.0)


def test_atomic_outputs_get_normal_permissions(tmp_path):
    import os
    import stat
    from panovocc_cli.io.atomic import atomic_dir, write_text
    old = os.umask(0o022)
    try:
        write_text(tmp_path / "a.txt", "x")
        with atomic_dir(tmp_path / "d") as d:
            (d / "f").write_text("y")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o755


def test_delta_file_sparse_channel_rows_round_trip(tmp_path):
    """A channel zero on most rows is stored as its non-zero rows (plus their indices) and read back
    whole; dense, all-zero and empty channels round-trip too, and equal deltas give equal bytes."""
    import numpy as np

    from panovocc_cli.io.mapstore import read_delta, write_delta

    keys = np.arange(0, 3000, 3, dtype=np.int64)
    n = len(keys)
    sparse = np.zeros((n, 4), np.int64)
    sparse[[0, 5, n - 1]] = [[1, -2, 3, 70000], [0, 9, 0, 0], [-(2 ** 40), 0, 0, 1]]
    ch = {"sparse": sparse, "dense": np.arange(2 * n).reshape(n, 2), "zero": np.zeros((n, 1), np.int64)}
    write_delta(tmp_path / "a.npz", [(keys, ch)], np.eye(4))
    with np.load(tmp_path / "a.npz") as z:  # 3 of the 1000 rows; int64 values as 8 byte planes
        assert z["shape_sparse"].tolist() == [3, 4] and z["ch_sparse"].shape == (8, 12)
        assert "rows_dense" not in z.files and z["ch_dense"].dtype == np.uint8
    [(k2, ch2)], T = read_delta(tmp_path / "a.npz")
    assert np.array_equal(k2, keys) and np.array_equal(T, np.eye(4))
    for name, arr in ch.items():
        assert ch2[name].dtype == np.int64 and np.array_equal(ch2[name], arr)
    write_delta(tmp_path / "b.npz", [(keys, ch)], np.eye(4))
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    write_delta(tmp_path / "e.npz", [(keys[:0], {"sparse": sparse[:0]})], np.eye(4))
    assert read_delta(tmp_path / "e.npz")[0][0][1]["sparse"].shape == (0, 4)
    # two contributors' parts, each over its own keys, come back apart and in order
    k_sem = keys[::7] + 1
    sem = {"E": np.arange(3 * len(k_sem)).reshape(-1, 3) - 5}
    write_delta(tmp_path / "p.npz", [(keys, ch), (k_sem, sem)], 2 * np.eye(4))
    parts, T = read_delta(tmp_path / "p.npz")
    assert len(parts) == 2 and np.array_equal(T, 2 * np.eye(4))
    assert np.array_equal(parts[0][0], keys) and sorted(parts[0][1]) == sorted(ch)
    assert np.array_equal(parts[1][0], k_sem) and np.array_equal(parts[1][1]["E"], sem["E"])


def test_memory_file_round_trip_sparse_channels(tmp_path):
    """memory.npz stores keys as differences and mostly-zero channels as their non-zero rows; read_memory
    gives back the arrays VoxelMemory.to_arrays wrote, bit for bit."""
    import numpy as np

    from panovocc_cli.io.mapstore import read_memory, write_memory
    from panovocc_cli.mapping.memory import ChannelSpec, Delta, VoxelMemory

    mem = VoxelMemory(0.08, (ChannelSpec("A", 1, "fixed"), ChannelSpec("E", 3, "fixed")))
    keys = np.arange(10, 40000, 11, dtype=np.int64)
    E = np.zeros((len(keys), 3), np.int64)
    E[::50] = [[1, 2 ** 40, -3]]
    mem.add(Delta(keys, {"A": np.arange(len(keys)) + 1, "E": E}))
    arrays = mem.to_arrays()
    write_memory(tmp_path, arrays, 3, np.eye(4)[None].repeat(3, 0))
    with np.load(tmp_path / "memory.npz") as z:
        assert "rows_E" in z.files and z["shape_E"].tolist() == [len(keys[::50]), 3]
    back, done, poses, ids = read_memory(tmp_path)
    assert done == 3 and poses.shape == (3, 4, 4) and ids is None
    for k, v in arrays.items():
        assert np.array_equal(back[k], v), k
        if k.startswith("ch_") or k == "keys":
            assert back[k].dtype == np.int64


def test_delta_record_factored_channels_and_observation_round_trip():
    """A record stores a channel that factors (``channel = factor * m / denominator``) as m, a wide mostly-zero
    channel as its non-zero entries, key gaps in int16 with the large ones apart: all read back exactly; a
    factor hint that does not hold leaves the channel as it is."""
    from panovocc_cli.io.mapstore import decode_record, encode_delta
    from panovocc_cli.semantics.observation import observe

    rng = np.random.default_rng(0)
    n = 300
    keys = np.sort(rng.choice(2 ** 40, n, replace=False)).astype(np.int64)
    keys[:100] = np.arange(100) + keys[0]  # runs of small gaps, then large ones
    keys = np.unique(keys)
    n = len(keys)
    s = rng.integers(0, 500, (n, 1))
    d = np.zeros((n, 12), np.int64)
    d[np.arange(n), rng.integers(0, 12, n)] = 64
    count = rng.integers(1, 9, (n, 1))
    ch = {"E": s * d, "S": 64 * s, "count": count, "rgb_sum": count * rng.integers(0, 256, (n, 3)),
          "bad": count * 3 + 1}
    factors = {"E": ("S", 64), "rgb_sum": ("count", 1), "bad": ("count", 1)}
    obs = observe(rng.normal(size=(6, 12, 12)).astype(np.float32))
    payload = encode_delta([(keys, ch, factors)], 2 * np.eye(4), obs.to_arrays())
    rec = decode_record(payload)
    (k2, ch2), = rec.parts
    np.testing.assert_array_equal(k2, keys)
    for name in ch:
        np.testing.assert_array_equal(ch2[name], ch[name], err_msg=name)
    np.testing.assert_array_equal(rec.T_world_cam, 2 * np.eye(4))
    from panovocc_cli.semantics.observation import SemanticObservation

    back = SemanticObservation.from_arrays(rec.observation)
    np.testing.assert_array_equal(back.classes, obs.classes)
    np.testing.assert_array_equal(back.q, obs.q)
    from panovocc_cli.io.mapstore import decode_arrays, payload_body
    stored = decode_arrays(payload)
    assert "fac_E" in stored and "fac_rgb_sum" in stored and "fac_bad" not in stored  # the hint that fails
    assert stored["keys_diff"].dtype == np.int16
    plain = encode_delta([(keys, ch)], 2 * np.eye(4))
    assert len(payload_body(encode_delta([(keys, ch, factors)], 2 * np.eye(4)))) < len(payload_body(plain))
    # no factors and no observation: as before
    rec = decode_record(plain)
    assert rec.observation is None
    for name in ch:
        np.testing.assert_array_equal(rec.parts[0][1][name], ch[name])


def _payload_view(a) -> bool:
    """Whether array ``a`` is a view of a bytes object (a decoded payload's body)."""
    while isinstance(a, np.ndarray) and a.base is not None:
        a = a.base
    return isinstance(a, (bytes, bytearray, memoryview))


def test_a_decoded_record_holds_no_view_of_its_payload():
    """Nothing a decoded record gives keeps its payload's body alive: a resumed run's replay keeps every frame's
    pose, a RAM store every frame's observation, and views of the body (1.2 MB a frame at 512x256) once made a
    killed 1,000-frame run of the house resume at 1.5 GB for a 30 MB memory (11.5 GB for the building)."""
    from panovocc_cli.io.mapstore import decode_arrays, decode_record, encode_delta
    from panovocc_cli.semantics.observation import observe

    rng = np.random.default_rng(1)
    keys = np.sort(rng.choice(2 ** 30, 200, replace=False)).astype(np.int64)
    ch = {"A": rng.integers(-5, 5, (200, 1)), "count": rng.integers(1, 9, (200, 1))}
    obs = observe(rng.normal(size=(6, 12, 12)).astype(np.float32))
    payload = encode_delta([(keys, ch)], 2 * np.eye(4), obs.to_arrays())
    assert _payload_view(decode_arrays(payload)["T_world_cam"])  # what the record is decoded from: views
    rec = decode_record(payload)
    arrays = [rec.T_world_cam, *rec.observation.values()] + [a for k, c in rec.parts for a in (k, *c.values())]
    assert rec.observation and not any(_payload_view(a) for a in arrays)


def test_a_greyscale_image_where_colour_is_expected_is_refused(tmp_path, capsys):
    """An RGB frame that is greyscale (8- or 16-bit grey PNG, one-component JPEG: e.g. a label or mask image
    put in rgb/) is refused on one line naming it, before any work (the frame check) and when read; colour
    images are read as before."""
    import cv2

    from cli_helpers import run_cli
    from panovocc_cli.io.images import check_image_header, read_rgb
    from room_sequence import write_room_sequence

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (32, 64, 3), np.uint8)
    grey = rgb[..., 0]
    cv2.imwrite(str(tmp_path / "c.png"), rgb)
    cv2.imwrite(str(tmp_path / "c.jpg"), rgb)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    cv2.imwrite(str(tmp_path / "g16.png"), grey.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "g.jpg"), grey)
    assert np.array_equal(read_rgb(tmp_path / "c.png"), rgb[..., ::-1])
    assert read_rgb(tmp_path / "c.jpg").shape == (32, 64, 3)
    for name in ("g.png", "g16.png", "g.jpg"):
        for call in (lambda p: read_rgb(p), lambda p: check_image_header(p, "rgb", (32, 64))):
            with pytest.raises(PanovoccError, match="greyscale") as e:
                call(tmp_path / name)
            assert name in str(e.value) and "\n" not in str(e.value)
    seq = tmp_path / "seq"
    write_room_sequence(seq, 2, 64)
    cv2.imwrite(str(seq / "rgb" / "000001.png"), cv2.cvtColor(cv2.imread(str(seq / "rgb" / "000001.png")),
                                                              cv2.COLOR_BGR2GRAY))
    code, _, err = run_cli(capsys, ["map", seq, tmp_path / "m", "--segmenter", "none", "--quiet"])
    assert code == 2 and "000001.png" in err and "greyscale" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "m").exists()


def test_read_first_pose_forms(tmp_path):
    """``--first-pose FILE``: a 4x4 matrix, a NICE-SLAM file (its first line is frame 0), a TUM file (the pose
    whose timestamp matches frame 0), all through the one pose reader."""
    from panovocc_cli.io.poses import read_first_pose

    T = np.stack([look_at([i + 100.0, -20.0, 1.5], [1.0, 0.2 * i, 0.05]) for i in range(3)])
    (tmp_path / "m.txt").write_text("# T_world_cam of frame 0\n" + "".join(
        " ".join(repr(float(x)) for x in row) + "\n" for row in T[0]))
    assert np.array_equal(read_first_pose(tmp_path / "m.txt"), T[0])
    write_poses(tmp_path / "one.txt", T[:1])
    assert np.array_equal(read_first_pose(tmp_path / "one.txt"), T[0])
    write_poses(tmp_path / "all.txt", T)
    assert np.array_equal(read_first_pose(tmp_path / "all.txt"), T[0])
    write_tum(tmp_path / "t.tum", T[::-1], timestamps=np.array([2.0, 1.0, 0.0]))  # any order: matched by stamp
    assert np.allclose(read_first_pose(tmp_path / "t.tum"), T[0], atol=1e-9)


@pytest.mark.parametrize("content,match", [
    ("", "empty"),
    ("# only a comment\n", "empty"),
    ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", "4x4 matrix: 3 lines"),
    ("1 0 0 0\n0 2 0 0\n0 0 1 0\n0 0 0 1\n", "not rigid"),
    ("1 0 0\n", "3 numbers"),
    ("2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1\n", "not rigid"),  # a scale is not a rigid pose
    ("5 0 0 0 0 0 0 1\n", "no pose within"),  # TUM, its one stamp far from frame 0's
])
def test_read_first_pose_refuses(tmp_path, content, match):
    from panovocc_cli.io.poses import read_first_pose

    p = tmp_path / "first.txt"
    p.write_text(content)
    with pytest.raises(PanovoccError, match=match) as e:
        read_first_pose(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(PanovoccError, match="not found"):
        read_first_pose(tmp_path / "missing.txt")


def test_common_divisor_of_a_channel_stops_reading_once_it_is_one(monkeypatch):
    """The common divisor a channel is stored divided by (``mapstore.common_divisor``) equals numpy's
    gcd over every value, and is found from the first rows when they already have none (a memory's
    channel of 16.7 M rows: one block, not the whole array)."""
    from panovocc_cli.io import mapstore

    rng = np.random.default_rng(4)
    cases = [np.zeros((0, 3), np.int32), np.zeros((7, 1), np.int16), 6 * rng.integers(-9, 9, (5000, 3)),
             np.concatenate([64 * rng.integers(1, 9, (300000, 1)), [[32]], [[-48]]]).astype(np.int32),
             rng.integers(-2 ** 40, 2 ** 40, (20000, 2)), np.array([[np.iinfo(np.int32).min], [4]], np.int32)]
    for a in cases:
        want = int(np.gcd.reduce(np.abs(a.astype(np.int64)), axis=None)) if a.size else 0
        assert mapstore.common_divisor(a) == want
    seen = []
    real = np.gcd.reduce
    monkeypatch.setattr(mapstore, "_gcd_reduce", lambda b: (seen.append(b.size), real(b))[1])
    assert mapstore.common_divisor(rng.integers(0, 1000, (1_000_000, 4))) == 1
    assert sum(seen) < 100_000


def _npz_arrays(rng):
    """Entries of every kind write_npz meets: C- and F-ordered arrays, a strided view, 0-d values, strings,
    booleans, an empty array, and streamed entries of many pieces (one of them larger than the queue)."""
    from panovocc_cli.io.npz import StreamedArray

    big = rng.integers(-2 ** 40, 2 ** 40, size=(300, 700))
    ramp = np.arange(3_000_000, dtype=np.int64) // 7  # compressible, 24 MB: several pieces
    return {"c": big, "f": np.asfortranarray(big[:, :50]), "strided": big[::3, 1::2], "scalar": np.float64(0.08),
            "names": np.array(["A", "E", "normal_sum"]), "mask": big[:40] > 0, "empty": np.zeros((0, 4), np.int32),
            "ramp": ramp, "streamed": StreamedArray(np.int64, ramp.shape, lambda: (ramp[a:a + 77_777] for a in
                                                                                 range(0, len(ramp), 77_777))),
            "planes": StreamedArray(np.uint8, (5, 1000), lambda: (np.full(1000, b, np.uint8) for b in range(5)))}


@pytest.mark.parametrize("limit", [1 << 25, 1000])
def test_npz_written_on_a_second_thread_has_the_same_bytes(tmp_path, monkeypatch, limit):
    """``write_npz(threaded=True)`` (memory.npz: entries compressed on a writer thread while the next ones
    are produced) writes the same bytes as the serial writer, whatever the queue's bound, and reads back."""
    from panovocc_cli.io import npz

    arrays = _npz_arrays(np.random.default_rng(3))
    npz.write_npz(tmp_path / "serial.npz", arrays, compresslevel=1)
    monkeypatch.setattr(npz, "PIPE_BYTES", limit)
    npz.write_npz(tmp_path / "threaded.npz", arrays, compresslevel=1, threaded=True)
    assert (tmp_path / "threaded.npz").read_bytes() == (tmp_path / "serial.npz").read_bytes()
    with np.load(tmp_path / "threaded.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["f"], arrays["f"])
        np.testing.assert_array_equal(z["streamed"], arrays["ramp"])
        assert z["f"].flags.f_contiguous and list(z["names"]) == ["A", "E", "normal_sum"]


def test_a_fast_npz_is_deflated_by_isal_to_bytes_that_depend_on_the_content_only(tmp_path, monkeypatch):
    """``write_npz(fast=True)`` (memory.npz): entries deflated by ISA-L (a zip np.load and zipfile read, with
    valid CRCs), smaller than zlib level 1's on compressible data; the same bytes serial or threaded and
    whatever pieces a streamed entry comes in (ISA-L's output depends on its input's calls: io.npz._FixedFeed),
    which fails when igzip is fed the pieces as given; ``load_npz`` reads fast and zlib archives alike."""
    import zipfile

    from isal import isal_zlib

    from panovocc_cli.io import npz

    rng = np.random.default_rng(5)
    arrays = _npz_arrays(rng)
    # a memory channel's kind of data: mostly zeros (igzip's bytes depend on its calls on such data)
    ramp = arrays["ramp"] = np.where(rng.random(3_000_000) < 0.05, rng.integers(1, 1000, 3_000_000), 0)
    monkeypatch.setattr(npz, "FAST_FEED", 1 << 16)  # many calls a test-sized entry

    def with_pieces(step):
        return {**arrays, "streamed": npz.StreamedArray(np.int64, ramp.shape, lambda: (
            ramp[a:a + step] for a in range(0, len(ramp), step)))}

    arrays = with_pieces(len(ramp))  # one piece
    npz.write_npz(tmp_path / "fast.npz", arrays, fast=True)
    npz.write_npz(tmp_path / "threaded.npz", with_pieces(12_345), fast=True, threaded=True)
    npz.write_npz(tmp_path / "pieces.npz", with_pieces(999_999), fast=True)
    npz.write_npz(tmp_path / "zlib.npz", arrays, compresslevel=1)
    fast = (tmp_path / "fast.npz").read_bytes()
    assert (tmp_path / "threaded.npz").read_bytes() == fast and (tmp_path / "pieces.npz").read_bytes() == fast
    assert fast != (tmp_path / "zlib.npz").read_bytes()
    with zipfile.ZipFile(tmp_path / "fast.npz") as zf:
        assert zf.testzip() is None and all(i.compress_type == zipfile.ZIP_DEFLATED for i in zf.infolist())
        fast_ramp = zf.getinfo("ramp.npy").compress_size
    with zipfile.ZipFile(tmp_path / "zlib.npz") as zf:
        assert fast_ramp < zf.getinfo("ramp.npy").compress_size
    for name in ("fast.npz", "zlib.npz"):
        with np.load(tmp_path / name, allow_pickle=False) as z, npz.load_npz(tmp_path / name) as y:
            for k in arrays:
                want = ramp if k == "streamed" else (np.stack([np.full(1000, b, np.uint8) for b in range(5)])
                                                     if k == "planes" else arrays[k])
                np.testing.assert_array_equal(z[k], want)
                np.testing.assert_array_equal(y[k], want)
    # the same entries handed to igzip as they come: other bytes for other pieces
    real = npz._FixedFeed
    monkeypatch.setattr(npz, "_FixedFeed", lambda inner: inner)
    npz.write_npz(tmp_path / "raw1.npz", with_pieces(12_345), fast=True)
    npz.write_npz(tmp_path / "raw2.npz", with_pieces(999_999), fast=True)
    assert (tmp_path / "raw1.npz").read_bytes() != (tmp_path / "raw2.npz").read_bytes()
    assert real is not None and isal_zlib.DEFLATED == zipfile.ZIP_DEFLATED


def test_a_threaded_npz_write_that_fails_leaves_nothing(tmp_path, monkeypatch):
    """A failure while an entry is produced (the caller's thread) or written (the writer thread: disk full)
    is raised (an OSError as io.atomic's one line), the writer thread stops, and no file is left."""
    import threading
    import zipfile

    from panovocc_cli.io import npz

    def broken():
        yield np.zeros(10, np.int64)
        raise RuntimeError("produce failed")

    arrays = _npz_arrays(np.random.default_rng(4))
    with pytest.raises(RuntimeError, match="produce failed"):
        npz.write_npz(tmp_path / "a.npz", {**arrays, "p": npz.StreamedArray(np.int64, (20,), broken)}, threaded=True)
    assert not list(tmp_path.iterdir())
    real_open = zipfile.ZipFile.open

    def full_disk(self, info, mode="r", **kw):
        f = real_open(self, info, mode, **kw)
        if mode == "w" and info.filename == "ramp.npy":
            def fail(data):
                raise OSError(28, "No space left on device")
            f.write = fail
        return f

    monkeypatch.setattr(zipfile.ZipFile, "open", full_disk)
    with pytest.raises(PanovoccError, match="b.npz: cannot write .No space left on device"):
        npz.write_npz(tmp_path / "b.npz", arrays, threaded=True)
    assert not list(tmp_path.iterdir())
    assert not [t for t in threading.enumerate() if t.name == "write_npz"]


def test_read_poses_checks_every_pose_as_one_by_one(tmp_path):
    """read_trajectory checks its poses all at once and again one by one only where one is near a bound: the
    same poses and, for a bad file, the same first error as checking line by line (a pose that is not rigid
    before a ragged line is named first; a pose within the tolerance but off by more than a tenth of it, or a
    camera right at MAX_POSITION_M, passes as before)."""
    from panovocc_cli.config import MAX_POSITION_M, RIGID_TOL
    from panovocc_cli.geometry.poses import check_rigid, quat_to_rot
    from panovocc_cli.io.poses import read_poses

    rng = np.random.default_rng(3)
    T = np.tile(np.eye(4), (6, 1, 1))
    for i in range(6):
        q = rng.standard_normal(4)
        T[i, :3, :3] = quat_to_rot(q)
        T[i, :3, 3] = rng.uniform(-50, 50, 3)
    T[2, :3, :3] *= 1 + 0.4 * RIGID_TOL  # orthonormal within the tolerance, not within a tenth of it
    T[3, :3, 3] = [MAX_POSITION_M, 0.0, -MAX_POSITION_M]
    lines = ["".join(" ".join(repr(float(x)) for x in t.reshape(-1)) + "\n" for t in T)]
    p = tmp_path / "ok.txt"
    p.write_text("".join(lines))
    got = read_poses(p)
    assert np.array_equal(got, np.stack([check_rigid(t) for t in T]))

    bad = T.copy()
    bad[1, 0, 0] += 10 * RIGID_TOL  # line 2 not rigid
    text = "".join(" ".join(repr(float(x)) for x in t.reshape(-1)) + "\n" for t in bad).splitlines(keepends=True)
    text[4] = "1 2 3\n"  # and line 5 ragged: line 2 is named, as a line-by-line read names it
    p.write_text("".join(text))
    with pytest.raises(PanovoccError, match="line 2: not rigid"):
        read_poses(p)
    text[1] = " ".join(repr(float(x)) for x in T[1].reshape(-1)) + "\n"  # line 2 fixed: line 5's error now
    p.write_text("".join(text))
    with pytest.raises(PanovoccError, match="line 5: 3 numbers"):
        read_poses(p)
    far = T.copy()
    far[4, 1, 3] = MAX_POSITION_M * 1.01
    p.write_text("".join(" ".join(repr(float(x)) for x in t.reshape(-1)) + "\n" for t in far))
    with pytest.raises(PanovoccError, match="line 5: camera position"):
        read_poses(p)
