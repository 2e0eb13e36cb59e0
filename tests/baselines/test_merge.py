"""The paper's merge rule on hand-made inputs with known answers: dense grids (union + class voting), sparse
scored voxels (union + maximum confidence), the sparse-voxel file format, and ``panovocc baselines merge``."""

import json
import pickle

import numpy as np
import pytest

from panovocc_cli.baselines.merge import SparseVoxels, merge_dense, merge_sparse, merged_class_names
from panovocc_cli.errors import PanovoccError
from panovocc_cli.geometry.lattice import index_to_center
from panovocc_cli.grid import Grid
from panovocc_cli.io.grid import read_grid, write_grid
from panovocc_cli.io.sparse_voxels import read_sparse_voxels, write_sparse_voxels

H = 0.08


def grid(labels, index0, names):
    return Grid(np.asarray(labels, np.uint8).reshape(-1, 1, 1), index_to_center(np.array([index0, 0, 0]), H), H,
                ["empty"] + names)


def at(g: Grid, i: int) -> int:
    """Label of lattice voxel (i, 0, 0) of ``g`` (255 outside it)."""
    k = i - int(g.index0[0])
    return int(g.labels[k, 0, 0]) if 0 <= k < g.labels.shape[0] else 255


def name_at(g: Grid, i: int) -> str:
    v = at(g, i)
    return {0: "free", 254: "occupied", 255: "unknown"}.get(v, g.class_names[v] if v < len(g.class_names) else "?")


def test_dense_union_and_voting():
    """Voxel 0: wall, floor, wall -> wall (two votes). Voxel 1: free in one, unknown in another -> free.
    Voxel 2: occupied without class in one, chair in another -> chair (254 casts no vote). Voxel 3: only in the
    shifted third grid -> its class. Voxel 4: 254 alone -> 254. Voxel 5: free in one, occupied in another ->
    occupied (union). Class lists differ in order and spelling (tv-screen = tv)."""
    a = grid([1, 0, 254, 255, 254, 0], 0, ["wall", "chair"])
    b = grid([2, 255, 3, 255, 255, 1], 0, ["floor", "wall", "chair"])
    c = grid([255, 4, 255], 2, ["floor", "wall", "chair", "tv-screen"])  # voxels 2..4: -, tv, -
    c0 = grid([2], -1, ["floor", "wall"])  # voxel -1: wall, extends the union's box to the left
    m = merge_dense([a, b, c, c0])
    assert m.class_names == ["empty", "wall", "chair", "floor", "tv"]
    assert m.index0[0] == -1 and m.labels.shape == (7, 1, 1)
    assert [name_at(m, i) for i in range(-1, 6)] == ["wall", "wall", "free", "chair", "tv", "occupied", "floor"]


def test_dense_tie_goes_to_the_first_class_and_order_does_not_matter_otherwise():
    a = grid([1], 0, ["sofa"])
    b = grid([1], 0, ["bed"])
    assert name_at(merge_dense([a, b]), 0) == "sofa"  # a tie: the class first in the merged list
    assert name_at(merge_dense([b, a]), 0) == "bed"
    c = grid([1], 0, ["bed"])
    for order in ([a, b, c], [c, a, b], [b, c, a]):  # two votes beat one whatever the order
        assert name_at(merge_dense(order), 0) == "bed"


def test_dense_refuses_mixed_voxel_sizes_and_nothing():
    a = grid([1], 0, ["wall"])
    b = Grid(a.labels, index_to_center(np.zeros(3, np.int64), 0.05), 0.05, a.class_names)
    with pytest.raises(PanovoccError, match="voxel sizes"):
        merge_dense([a, b])
    with pytest.raises(PanovoccError, match="nothing to merge"):
        merge_dense([])


def test_sparse_maximum_confidence():
    """Voxel (0,0,0): chair 0.7 in the first input, table 0.9 in the second -> table. Voxel (2,0,0): listed once,
    no class -> 254. Voxel (1,0,0) is in the box but listed nowhere -> 0 (empty). Equal confidences: the earlier
    input wins."""
    s1 = SparseVoxels(np.array([[0, 0, 0], [2, 0, 0], [3, 0, 0]]), np.array([0, -1, 1]), np.array([0.7, 0.5, 0.6]),
                      H, ["chair", "table"])
    s2 = SparseVoxels(np.array([[0, 0, 0], [3, 0, 0]]), np.array([1, 0]), np.array([0.9, 0.6]), H, ["sofa", "table"])
    m = merge_sparse([s1, s2])
    assert m.class_names == ["empty", "chair", "table", "sofa"]
    assert [name_at(m, i) for i in range(4)] == ["table", "free", "occupied", "table"]
    m2 = merge_sparse([s2, s1])
    assert name_at(m2, 3) == "sofa"  # the tie at voxel 3 (0.6 each) goes to the first input


def test_merged_class_names_canonical():
    assert merged_class_names([["Wall", "lamp"], ["lighting", "empty", "TV-Screen"]]) == ["empty", "wall", "lighting",
                                                                                        "tv"]


def test_sparse_file_round_trip_and_bad_files(tmp_path):
    centres = np.array([[0.04, 0.04, 0.04], [0.17, 0.01, 0.0]])  # the second is inside voxel (2, 0, 0)
    write_sparse_voxels(tmp_path / "s.npz", centres, H, ["chair", "table"], scores=np.array([[0.2, 0.8], [0.6, 0.1]]))
    idx, lab, conf, h, names = read_sparse_voxels(tmp_path / "s.npz")
    assert idx.tolist() == [[0, 0, 0], [2, 0, 0]] and lab.tolist() == [1, 0] and conf.tolist() == [0.8, 0.6]
    assert h == H and names == ["chair", "table"]
    write_sparse_voxels(tmp_path / "l.npz", centres, H, ["chair"], labels=np.array([0, -1]),
                        confidence=np.array([0.5, 0.4]))
    assert read_sparse_voxels(tmp_path / "l.npz")[1].tolist() == [0, -1]
    write_sparse_voxels(tmp_path / "bad.npz", centres, H, ["chair"], labels=np.array([0, 3]),
                        confidence=np.array([0.5, 0.4]))
    with pytest.raises(PanovoccError, match="labels must be"):
        read_sparse_voxels(tmp_path / "bad.npz")
    np.savez(tmp_path / "nokeys.npz", centers=centres, voxel_size=H, class_names=np.array(["a"]))
    with pytest.raises(PanovoccError, match="neither scores"):
        read_sparse_voxels(tmp_path / "nokeys.npz")


def test_cli_merge_dense_pickle_and_sparse(tmp_path, cli):
    from panovocc_cli.io.replicaocc import write_replicaocc

    a = grid([1, 0, 254], 0, ["wall", "chair"])
    b = grid([2, 255, 2], 0, ["floor", "wall"])
    write_grid(tmp_path / "a.npz", a)
    write_replicaocc(tmp_path / "b.pkl", b)  # FreeOcc's Replica ids in the pickle, read back by name
    code, out, err = cli(["baselines", "merge", tmp_path / "m.npz", tmp_path / "a.npz", tmp_path / "b.pkl"])
    assert code == 0, err
    m = read_grid(tmp_path / "m.npz")
    assert [name_at(m, i) for i in range(3)] == ["wall", "free", "wall"]
    cfg = json.loads((tmp_path / "m.config.json").read_text())
    assert cfg["kind"] == "auto" and len(cfg["inputs"]) == 2
    before = (tmp_path / "m.npz").read_bytes()
    code, _, err = cli(["baselines", "merge", tmp_path / "m.npz", tmp_path / "a.npz"])
    assert code == 2 and "--overwrite" in err and (tmp_path / "m.npz").read_bytes() == before
    write_sparse_voxels(tmp_path / "s.npz", np.array([[0.04, 0.04, 0.04]]), H, ["sofa"], scores=np.array([[0.9]]))
    code, _, err = cli(["baselines", "merge", tmp_path / "x.npz", tmp_path / "a.npz", tmp_path / "s.npz"])
    assert code == 2 and "mixes sparse" in err and not (tmp_path / "x.npz").exists()
    code, _, err = cli(["baselines", "merge", tmp_path / "x.npz", tmp_path / "s.npz", "--kind", "dense"])
    assert code == 2 and "sparse" in err and not (tmp_path / "x.npz").exists()
    code, _, err = cli(["baselines", "merge", tmp_path / "y.npz", tmp_path / "s.npz", tmp_path / "s.npz"])
    assert code == 0 and name_at(read_grid(tmp_path / "y.npz"), 0) == "sofa"
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps(object()))
    code, _, err = cli(["baselines", "merge", tmp_path / "z.npz", tmp_path / "evil.pkl"])
    assert code == 2 and "evil.pkl" in err and not (tmp_path / "z.npz").exists()


def test_cli_merge_refuses_a_far_voxel_empty_sparse_inputs_and_empty_class_names(tmp_path, cli):
    """A sparse input with one voxel 1e7 m away would need petabytes of grid: one line before the merge.
    Sparse inputs that list no voxel at all are refused; one empty input beside others adds nothing.
    ``--class-names ''`` is an empty list, refused (not FreeOcc's list by default)."""
    from panovocc_cli.io.replicaocc import write_replicaocc

    write_sparse_voxels(tmp_path / "far.npz", np.array([[0.04, 0.04, 0.04], [1e7, 1e7, 1e7]]), H, ["sofa"],
                        scores=np.array([[0.9], [0.8]]))
    write_sparse_voxels(tmp_path / "none.npz", np.zeros((0, 3)), H, ["sofa"], scores=np.zeros((0, 1)))
    write_sparse_voxels(tmp_path / "one.npz", np.array([[0.12, 0.04, 0.04]]), H, ["chair"], scores=np.array([[0.7]]))
    write_replicaocc(tmp_path / "b.pkl", grid([2, 255, 2], 0, ["floor", "wall"]))
    for argv, expect in ((["far.npz"], "GiB of memory"), (["none.npz"], "no voxel"),
                         (["none.npz", "none.npz"], "no voxel"), (["b.pkl", "--class-names", ""], "no class names")):
        code, _, err = cli(["baselines", "merge", tmp_path / "m.npz", *[tmp_path / a if a.endswith(("z", "l")) else a
                                                                         for a in argv]])
        assert code == 2 and expect in err and len(err.strip().splitlines()) == 1, (argv, err)
        assert not (tmp_path / "m.npz").exists() and not (tmp_path / "m.config.json").exists()
    code, _, err = cli(["baselines", "merge", tmp_path / "m.npz", tmp_path / "none.npz", tmp_path / "one.npz"])
    assert code == 0, err
    m = read_grid(tmp_path / "m.npz")
    assert m.labels.shape == (1, 1, 1) and name_at(m, 1) == "chair"
