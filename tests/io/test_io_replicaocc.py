"""FreeOcc / ReplicaOcc ``global_occ_package/<scene>.pkl`` both ways: the dense form FreeOcc's loader reads,
the flat form, round trips, and bad files (one PanovoccError line each)."""

import io
import pickle

import numpy as np
import pytest

from panovocc_cli.errors import PanovoccError
from panovocc_cli.grid import Grid
from panovocc_cli.io.replicaocc import (REPLICA_NAMES, SafeUnpickler, grid_to_replicaocc, read_replicaocc,
                                        write_replicaocc)

H = 0.08


def freeocc_load(path, voxel_size=0.08):
    """What FreeOcc's load_full_scene_occ does with the file (read from their code; plain pickle.load)."""
    with open(path, "rb") as f:
        pkg = pickle.load(f)
    pts = np.asarray(pkg["global_pts"], dtype=np.float32)
    return {
        "scene_dim": np.asarray(pkg["scene_dim"], dtype=np.int32),
        "occ_labels": np.asarray(pkg["global_labels"]),
        "occ_points": pts,
        "occ_mask": np.asarray(pkg["global_mask"], dtype=bool),
        "scene_origin": np.array([pts[..., 0].min(), pts[..., 1].min(), pts[..., 2].min()], dtype=np.float32),
        "scene_size": voxel_size * np.asarray(pkg["scene_dim"], dtype=np.int32).astype(np.float32),
    }


def freeocc_scene(dtype=np.uint8, shape=(9, 7, 5), i0=(-20, 13, -2), seed=0):
    """A scene in FreeOcc's dense form: Replica ids (1..101), 0 free, 255 unknown; no voxel size stored."""
    rng = np.random.default_rng(seed)
    ids = [0, 0, 0, 255, 93, 40, 31, 20, 7, 76, 80, 97, 101, 1]  # wall floor ceiling chair bed sofa table window ...
    labels = rng.choice(ids, size=shape).astype(dtype)
    ijk = np.stack(np.meshgrid(*(np.arange(s) for s in shape), indexing="ij"), axis=-1)
    pts = ((ijk + np.asarray(i0) + 0.5) * H).astype(np.float32)
    return {"scene_dim": np.asarray(shape), "global_labels": labels, "global_pts": pts,
            "global_mask": labels != 255, "valid_img_paths": ["results/frame000000.jpg"]}


def names_of(grid):
    """Per-voxel class names (empty / unknown as '' / '?'), to compare grids whatever their ids."""
    table = np.array(list(grid.class_names) + [""] * (254 - len(grid.class_names)) + ["<254>", "?"], dtype=object)
    table[0] = ""
    return table[grid.labels]


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
@pytest.mark.parametrize("dtype", [np.uint8, np.int64])
def test_dense_freeocc_file_reads_and_writes_back(tmp_path, protocol, dtype):
    d = freeocc_scene(dtype)
    with open(tmp_path / "scene.pkl", "wb") as f:
        pickle.dump(d, f, protocol=protocol)
    g, shift = read_replicaocc(tmp_path / "scene.pkl", None)  # no names given, none in the file: Replica's
    assert not shift.any() and g.voxel_size == H and g.labels.shape == (9, 7, 5)
    assert np.array_equal(g.labels, d["global_labels"].astype(np.uint8))  # ids kept, index for index
    assert np.allclose(g.origin, d["global_pts"].reshape(-1, 3).min(axis=0), atol=1e-6)  # FreeOcc's origin
    assert g.class_names[93] == "wall" and g.class_names[40] == "floor" and g.class_names[87] == "tv"
    assert len(g.class_names) == 102 and g.class_names[1:] == [n if n not in ("tv-screen", "lamp") else
                                                                {"tv-screen": "tv", "lamp": "lighting"}[n]
                                                                for n in REPLICA_NAMES]
    # ... and back: FreeOcc's loader gets the same arrays
    write_replicaocc(tmp_path / "back.pkl", g)
    a, b = freeocc_load(tmp_path / "scene.pkl"), freeocc_load(tmp_path / "back.pkl")
    assert np.array_equal(a["occ_labels"], b["occ_labels"]) and b["occ_labels"].dtype == np.uint8
    assert np.array_equal(a["scene_dim"], b["scene_dim"]) and np.array_equal(a["occ_mask"], b["occ_mask"])
    assert np.allclose(a["occ_points"], b["occ_points"], atol=1e-6)
    assert np.allclose(a["scene_origin"], b["scene_origin"], atol=1e-6)


def test_grid_to_freeocc_and_back(tmp_path):
    rng = np.random.default_rng(1)
    names = ["empty", "sofa", "wall", "tv", "gizmo", "lighting", "floor"]  # our order, not FreeOcc's
    lab = rng.choice([0, 1, 2, 3, 4, 5, 6, 254, 255], size=(6, 5, 4)).astype(np.uint8)
    g = Grid(lab, (np.array([3, -4, 0]) + 0.5) * H, H, names)
    data, unmatched = grid_to_replicaocc(g)
    assert unmatched == ["gizmo"]
    lut = {0: 0, 1: 76, 2: 93, 3: 87, 4: 254, 5: 47, 6: 40, 254: 254, 255: 255}
    assert np.array_equal(data["global_labels"], np.vectorize(lut.get)(lab))
    assert data["global_pts"].shape == (6, 5, 4, 3) and data["global_pts"].dtype == np.float32
    assert np.allclose(data["global_pts"][2, 1, 3], (np.array([3 + 2, -4 + 1, 0 + 3]) + 0.5) * H)
    assert np.array_equal(data["global_mask"], lab != 255) and data["scene_dim"].tolist() == [6, 5, 4]
    write_replicaocc(tmp_path / "g.pkl", g)
    write_replicaocc(tmp_path / "g2.pkl", g)
    assert (tmp_path / "g.pkl").read_bytes() == (tmp_path / "g2.pkl").read_bytes()  # deterministic
    back, _ = read_replicaocc(tmp_path / "g.pkl", None)
    expect = names_of(g)
    expect[expect == "gizmo"] = "<254>"  # no Replica id: occupied, no class
    assert np.array_equal(names_of(back), expect) and np.allclose(back.origin, g.origin)
    # the grid's own ids travel losslessly
    write_replicaocc(tmp_path / "own.pkl", g, ids="own")
    own, _ = read_replicaocc(tmp_path / "own.pkl", None)
    assert np.array_equal(own.labels, g.labels) and own.class_names == g.class_names
    # a prediction: unknown is written as free (FreeOcc counts every label > 0 as occupied)
    data, _ = grid_to_replicaocc(g, prediction=True)
    assert not (data["global_labels"] == 255).any() and np.all(data["global_labels"][lab == 255] == 0)


def flat_dict():
    """The flat form: a 4x3x2 scene listed as centres (Python lists), ids 1..3 into the user's names."""
    rng = np.random.default_rng(0)
    ijk = np.stack(np.meshgrid(np.arange(4), np.arange(3), np.arange(2), indexing="ij"), -1).reshape(-1, 3)
    i0 = np.array([-12, 5, -1])
    labels = rng.choice([0, 1, 2, 3, 255], size=len(ijk))
    return {"global_labels": labels.tolist(), "global_pts": ((ijk + i0 + 0.5) * H).tolist(), "scene_dim": [4, 3, 2]}, \
        ijk, labels


def test_flat_form_reads_lists_and_round_trips(tmp_path):
    d, ijk, labels = flat_dict()
    with open(tmp_path / "scene.pkl", "wb") as f:
        pickle.dump(d, f)
    g, shift = read_replicaocc(tmp_path / "scene.pkl", ["wall", "floor", "tv-screen"])
    assert g.class_names == ["empty", "wall", "floor", "tv"] and not shift.any()
    assert g.labels.shape == (4, 3, 2) and np.allclose(g.origin, (np.array([-12, 5, -1]) + 0.5) * H)
    assert np.array_equal(g.labels[tuple(ijk.T)], labels)
    g0, _ = read_replicaocc(tmp_path / "scene.pkl", ["free", "wall", "floor", "tv-screen"])  # names id 0 first
    assert np.array_equal(g0.labels, g.labels) and g0.class_names == g.class_names
    # only some voxels listed: the rest are unknown
    part = dict(d, global_labels=d["global_labels"][:-5], global_pts=d["global_pts"][:-5])
    with open(tmp_path / "part.pkl", "wb") as f:
        pickle.dump(part, f)
    gp, _ = read_replicaocc(tmp_path / "part.pkl", ["wall", "floor", "tv"])
    assert (gp.labels == 255).sum() >= 5


def write_pickle(path, obj, protocol=4):
    with open(path, "wb") as f:
        pickle.dump(obj, f, protocol=protocol)
    return path


def test_bad_files_one_clear_error(tmp_path):
    d = freeocc_scene()
    flat, _, _ = flat_dict()
    permuted = dict(d, global_pts=np.ascontiguousarray(d["global_pts"].transpose(1, 0, 2, 3)).reshape(9, 7, 5, 3))
    cases = {
        "voxel_abc": (dict(d, voxel_size="abc"), "voxel_size must be one number"),
        "voxel_neg": (dict(d, voxel_size=-0.08), "positive"),
        "pts_2": (dict(d, global_pts=d["global_pts"][..., :2]), "expected \\(X, Y, Z, 3\\)"),
        "labels_2d": (dict(d, global_labels=d["global_labels"][:, :, 0]), "expected \\(X, Y, Z, 3\\)"),
        "mask_shape": (dict(d, global_mask=np.ones((2, 2, 2), bool)), "global_mask must be"),
        "dim": (dict(d, scene_dim=[9, 7, 6]), "scene_dim is"),
        "dim_text": (dict(d, scene_dim="abc"), "scene_dim must be"),
        "labels_text": (dict(d, global_labels=np.full((9, 7, 5), "x")), "must be integers"),
        "labels_frac": (dict(d, global_labels=d["global_labels"] + 0.5), "must be integers"),
        "labels_big": (dict(d, global_labels=d["global_labels"].astype(np.int64) + 300), "has no class name"),
        "permuted": (permuted, "not laid out"),
        "off": (dict(flat, global_pts=(np.asarray(flat["global_pts"]) + 0.03).tolist()), "off the global lattice"),
        "flat_dim": (dict(flat, scene_dim=[2, 2, 2]), "scene_dim"),
        "keys": ({"global_labels": [1]}, "missing keys"),
        "list": ([1, 2, 3], "expected a pickled dict"),
        "empty": ({"global_labels": np.zeros((0,), np.uint8), "global_pts": np.zeros((0, 3))}, "no voxels"),
    }
    for name, (obj, msg) in cases.items():
        p = write_pickle(tmp_path / f"{name}.pkl", obj)
        with pytest.raises(PanovoccError, match=msg) as e:
            read_replicaocc(p, ["wall", "floor", "tv"] if name in ("off", "flat_dim") else None)
        assert "\n" not in str(e.value) and str(p) in str(e.value), name
    full = pickle.dumps(d, protocol=4)
    (tmp_path / "truncated.pkl").write_bytes(full[: len(full) // 2])
    (tmp_path / "garbage.pkl").write_bytes(b"\x00\xffnot a pickle" * 10)
    (tmp_path / "empty.pkl").write_bytes(b"")
    for name in ("truncated", "garbage", "empty"):
        with pytest.raises(PanovoccError, match="cannot read pickle"):
            read_replicaocc(tmp_path / f"{name}.pkl", None)
    with pytest.raises(PanovoccError, match="not found"):
        read_replicaocc(tmp_path / "missing.pkl", None)
    g, shift = read_replicaocc(tmp_path / "off.pkl", ["wall", "floor", "tv"], allow_shift=True)
    assert np.allclose(shift, -0.03)

    class Evil:
        def __reduce__(self):
            return (print, ("this must not run",))

    with pytest.raises(pickle.UnpicklingError, match="refusing"):
        SafeUnpickler(io.BytesIO(pickle.dumps({"global_labels": Evil()}))).load()
    write_pickle(tmp_path / "evil.pkl", {"global_labels": Evil()})
    with pytest.raises(PanovoccError, match="refusing to load builtins.print"):
        read_replicaocc(tmp_path / "evil.pkl", None)


def test_convert_refuses_an_empty_class_names_list(tmp_path, capsys):
    """``--class-names ''`` is an empty list: refused in one line, not read as "use FreeOcc's list"."""
    from cli_helpers import run_cli

    p = write_pickle(tmp_path / "s.pkl", freeocc_scene())
    code, _, err = run_cli(capsys, ["convert", "replicaocc", p, tmp_path / "g.npz", "--class-names", ""])
    assert code == 2 and "no class names" in err and len(err.strip().splitlines()) == 1, err
    assert sorted(x.name for x in tmp_path.iterdir()) == ["s.pkl"]
